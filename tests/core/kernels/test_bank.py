"""The compiled filter bank (mav_observer/core/kernels/bank.py): one filter's prediction and
updates against their definitions, the bank's start, weighting, pruning, merging and
re-seeding, the robust weight, the noise and the bias walk learnt, the mixture's estimate.

Runs are the Monte Carlo harness's (:class:`~bench.accuracy.bankruns.BankRuns`: the product's
kernels over many runs, its arrays), stepped through :mod:`kernel_calls` in a serial loop
(the harness's ``prange`` costs a thread wake-up per step, milliseconds on a busy machine):
one test checks that both step alike."""

from __future__ import annotations

import math

import kernel_calls as kc
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.accuracy.bankruns import BankRuns, FilterRuns, initial_covariance
from mav_observer import BearingSample, BiasObserver, ObserverConfig, VelocitySample
from mav_observer.core.config import BankParams, outlier_nis
from mav_observer.core.kernels import layout as L
from sim import scenarios
from sim.stream import perturb_bearings

GATE = outlier_nis(2)  # the robust threshold in three dimensions (13.816)


def _nees(err: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The position's normalised error squared per axis, per run."""
    return np.einsum("ri,rij,rj->r", err, np.linalg.inv(p[:, :3, :3]), err) / 3.0


def _orbit(duration_s: float, dt: float = 0.05, **kw: object):
    sc = scenarios.orbit(duration_s=duration_s, **kw)  # type: ignore[arg-type]
    t = np.arange(0.0, duration_s + 1e-9, dt)
    return t, sc.x(t), sc.v(t)


def _bearings(rng: np.random.Generator, xt: np.ndarray, runs: int, sigma: float) -> np.ndarray:
    """(runs, T, 3) noisy bearings of the true positions ``xt`` (T, 3) or (runs, T, 3)."""
    xt = np.broadcast_to(xt, (runs, *xt.shape[-2:]))
    y_true = (xt / np.linalg.norm(xt, axis=-1, keepdims=True)).reshape(-1, 3)
    return perturb_bearings(y_true, sigma, rng).reshape(runs, -1, 3)


def _run(
    prm: BankParams, y: np.ndarray, v: np.ndarray, r0, dt: float, walk_q0: float = 0.0, **kw
) -> kc.Runs:
    """Runs of the bank started at ``y[:, 0]`` (range guess ``r0``) and stepped through the
    rest of the bearings ``y`` (R, T, 3); ``v`` (T, 3) the velocity of every run; ``kw``:
    the walk held (``hold``, ``hold_nats``)."""
    runs = y.shape[0]
    bank = kc.Runs(prm, runs, 3)
    bank.start(y[:, 0], np.broadcast_to(np.asarray(r0, dtype=float), (runs,)))
    bank.bs[:, L.B_WALK_Q] = walk_q0  # the bias walk's level at the start (m^2/s^3)
    dx = 0.5 * (v[:-1] + v[1:]) * dt
    for k in range(1, y.shape[1]):
        bank.step(np.broadcast_to(dx[k - 1], (runs, 3)), dt, y[:, k], **kw)
    return bank


# -- one filter ------------------------------------------------------------------------------


def _spd(rng: np.random.Generator, d: int, scale: float = 1.0) -> np.ndarray:
    g = rng.normal(size=(d, d))
    return scale * (g @ g.T) + 0.1 * scale * np.eye(d)


def test_predict_is_the_exact_propagation_of_a_constant_bias() -> None:
    rng = np.random.default_rng(1)
    n, h = 3, 0.7
    s = rng.normal(size=2 * n)
    p = _spd(rng, 2 * n)
    dx = rng.normal(size=n)
    s2, p2 = kc.predict_filter(s, p, dx, h, 0.3, 0.02)
    np.testing.assert_allclose(s2[:n], s[:n] + dx + h * s[n:], rtol=1e-14)
    assert np.array_equal(s2[n:], s[n:])
    f = np.block([[np.eye(n), h * np.eye(n)], [np.zeros((n, n)), np.eye(n)]])
    q1 = np.array([[0.3 * h + 0.02 * h**3 / 3, 0.02 * h**2 / 2], [0.02 * h**2 / 2, 0.02 * h]])
    np.testing.assert_allclose(p2, f @ p @ f.T + np.kron(q1, np.eye(n)), rtol=1e-12)
    assert np.array_equal(p2, p2.T)


def _null_basis(d: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the plane orthogonal to ``d`` (numpy's SVD)."""
    return np.linalg.svd(d[None, :])[2][1:].T


def test_tracking_update_is_the_extended_kalman_update() -> None:
    """Against a direct EKF with the Jacobian of y = x/|x| in tangent coordinates (any
    orthonormal basis gives the same update): the state, covariance, NIS, log det S, and
    the noise statistic as the post-fit residual plus the remaining spread, e^T e +
    tr(H P+ H^T)."""
    rng = np.random.default_rng(2)
    n, sigma = 3, 0.01
    s = np.array([10.0, 4.0, 3.0, 0.5, -0.2, 0.1])
    p = _spd(rng, 6) + np.eye(6)
    y = s[:3] + np.array([0.3, -0.2, 0.1])
    y /= np.linalg.norm(y)
    s2, p2, nis, logdet, weight, stat = kc.update_filter(s, p, y, sigma**2, 0.0)
    r = np.linalg.norm(s[:3])
    e = _null_basis(s[:3] / r)
    h = np.hstack((e.T / r, np.zeros((2, n))))
    sm = h @ p @ h.T + sigma**2 * np.eye(2)
    k = p @ h.T @ np.linalg.inv(sm)
    z = e.T @ y
    np.testing.assert_allclose(s2, s + k @ z, rtol=1e-10)
    np.testing.assert_allclose(p2, p - k @ sm @ k.T, rtol=1e-9, atol=1e-12)
    assert nis == pytest.approx(z @ np.linalg.solve(sm, z), rel=1e-10)
    assert logdet == pytest.approx(np.linalg.slogdet(sm)[1], rel=1e-10)
    assert weight == 1.0
    post = z - h @ (s2 - s)
    assert stat == pytest.approx(post @ post + np.trace(h @ p2 @ h.T), rel=1e-8)


def test_acquisition_update_is_the_pseudo_linear_kalman_update() -> None:
    """The Riccati observer's form (``r_w > 0``): linear in the state, the bearing ``y``
    itself the direction, ``H = E_y^T / r_w`` and the measurement ``z = -H x`` (the
    position's part across the bearing, weighed at the range ``r_w``), whatever the
    estimate."""
    rng = np.random.default_rng(3)
    s = np.array([-5.0, 40.0, 3.0, 0.5, -0.2, 0.1])  # far off the bearing
    p = _spd(rng, 6) + np.eye(6)
    y = np.array([0.6, 0.0, 0.8])
    sig2, r_w = 1e-4, 25.0
    s2, p2, nis, logdet, weight, _ = kc.update_filter(s, p, y, sig2, r_w)
    e = _null_basis(y)
    h = np.hstack((e.T / r_w, np.zeros((2, 3))))
    sm = h @ p @ h.T + sig2 * np.eye(2)
    k = p @ h.T @ np.linalg.inv(sm)
    z = -h @ s
    np.testing.assert_allclose(s2, s + k @ z, rtol=1e-9)
    np.testing.assert_allclose(p2, p - k @ sm @ k.T, rtol=1e-9, atol=1e-12)
    assert nis == pytest.approx(z @ np.linalg.solve(sm, z), rel=1e-10)
    assert logdet == pytest.approx(np.linalg.slogdet(sm)[1], rel=1e-10)
    assert weight == 1.0
    np.testing.assert_allclose(np.cross(s2[:3], y), 0.0, atol=0.5)  # pulled onto the bearing


def test_acquisition_update_needs_no_estimate_to_converge() -> None:
    """The Riccati observer (acquisition form, the weight range r_w): noise-free bearings of
    the orbit, started at a range 100 times too long and a bias of 20 m/s the wrong way:
    within 1 mm and 1 mm/s after 60 s."""
    t, xt, v = _orbit(60.0)
    sc_a = scenarios.orbit().a_mps
    y = xt / np.linalg.norm(xt, axis=1, keepdims=True)
    r0 = 100.0 * float(np.linalg.norm(xt[0]))
    s = np.concatenate((r0 * y[0], [20.0, -20.0, 5.0]))
    p = kc.initial_covariance(y[0], r0, 3.0 * r0, 5.0, 1e-3)
    for k in range(1, len(t)):
        s, p = kc.predict_filter(s, p, 0.5 * (v[k - 1] + v[k]) * 0.05, 0.05, 0.0, 0.0)
        s, p, *_ = kc.update_filter(s, p, y[k], 1e-6, r0)
    assert np.linalg.norm(s[:3] - xt[-1]) < 1e-3
    assert np.linalg.norm(s[3:] - sc_a) < 1e-3


@pytest.mark.slow  # compiles the Monte Carlo harness
def test_the_harness_runs_the_same_kernels() -> None:
    """:class:`BankRuns` (its parallel loop) and the serial calls of the other tests step
    the same arrays alike, bit for bit; :class:`FilterRuns` and
    :func:`~bench.accuracy.bankruns.initial_covariance` are the one filter's kernels."""
    rng = np.random.default_rng(5)
    _, xt, v = _orbit(3.0)
    y = _bearings(rng, xt, 3, math.radians(1.0))
    prm = ObserverConfig().bank_params(0.05)
    r0 = np.array([5.0, 20.0, 80.0])
    harness = BankRuns(prm, 3, 3)
    harness.start(y[:, 0], r0)
    serial = _run(prm, y, v, r0, 0.05)
    for k in range(1, y.shape[1]):
        harness.step(np.broadcast_to(0.5 * (v[k - 1] + v[k]) * 0.05, (3, 3)), 0.05, y[:, k])
    for name in ("fs", "fp", "logw", "bs"):
        assert np.array_equal(getattr(harness, name), getattr(serial, name)), name
    for got, want in zip(harness.estimate(), serial.estimate(), strict=True):
        assert np.array_equal(got, want)
    p0 = initial_covariance(y[:, 0], r0, 0.4 * r0, 5.0, 0.01)
    filters = FilterRuns(r0[:, None] * y[:, 0], p0, np.array([0.0, 0.0, 20.0]), 0.01, 1e-4)
    for k in range(1, 4):
        filters.predict(np.full((3, 3), 0.05), 0.05)
        filters.update(y[:, k])
    for r in range(3):
        s = np.concatenate((r0[r] * y[r, 0], np.zeros(3)))
        p = kc.initial_covariance(y[r, 0], r0[r], 0.4 * r0[r], 5.0, 0.01)
        assert np.array_equal(p, p0[r])
        for k in range(1, 4):
            s, p = kc.predict_filter(s, p, np.full(3, 0.05), 0.05, 1e-4, 0.0)
            s, p, *_ = kc.update_filter(s, p, y[r, k], 1e-4, [0.0, 0.0, 20.0][r])
        assert np.array_equal(filters.s[r], s) and np.array_equal(filters.p[r], p)


def test_the_robust_update_moves_the_state_little_for_a_gross_error() -> None:
    """A converged filter and one bearing 20 deg off: the robust update moves the estimate
    less than one noise-sized bearing would; the plain update moves it far more; the NIS
    reported is the nominal one."""
    s = np.array([10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    p = 1e-4 * np.eye(6)
    sig2 = math.radians(0.5) ** 2
    ang, ang1 = math.radians(20.0), math.radians(0.5)
    y_bad = np.array([math.cos(ang), math.sin(ang), 0.0])
    y_ok = np.array([math.cos(ang1), math.sin(ang1), 0.0])
    robust = kc.update_filter(s, p, y_bad, sig2, 0.0, GATE)
    plain = kc.update_filter(s, p, y_bad, sig2, 0.0, math.inf)
    ok = kc.update_filter(s, p, y_ok, sig2, 0.0, GATE)
    move = {k: float(np.linalg.norm(r[0] - s)) for k, r in (("r", robust), ("p", plain), ("o", ok))}
    assert move["r"] < move["o"] < move["p"]
    assert robust[4] < 1e-3 and ok[4] == 1.0 and plain[4] == 1.0
    assert robust[2] == pytest.approx(plain[2]) and robust[2] > 100.0 * GATE
    # beyond the threshold the bearing counts with its variance scaled by (nis / gate)^2
    assert robust[4] == pytest.approx((GATE / robust[2]) ** 2)
    inflated = kc.update_filter(s, p, y_bad, sig2 / robust[4], 0.0, math.inf)
    np.testing.assert_allclose(robust[0], inflated[0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(robust[1], inflated[1], rtol=1e-9, atol=1e-15)


_finite = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(_finite, min_size=36, max_size=36),
    st.lists(_finite, min_size=3, max_size=3).filter(lambda v: sum(c * c for c in v) > 1e-3),
    st.lists(_finite, min_size=3, max_size=3),
    st.floats(min_value=1.0, max_value=500.0),
    st.floats(min_value=1e-7, max_value=1e-2),
    st.booleans(),
)
def test_an_update_keeps_the_covariance_symmetric_and_shrinks_it(
    m: list[float], u: list[float], off: list[float], range_m: float, sig2: float, tracking: bool
) -> None:
    """For any positive definite covariance, bearing and noise, tracking or acquisition, a
    gross error or not: the updated covariance is exactly symmetric, positive semi-definite
    and no larger than before (P - P+ positive semi-definite); NIS >= 0, weight in (0, 1]."""
    a_ = np.reshape(m, (6, 6))
    p = a_ @ a_.T + 0.01 * np.eye(6)
    d = np.array(u) / np.linalg.norm(u)
    y = d + np.array(off)
    y = y / np.linalg.norm(y) if np.linalg.norm(y) > 1e-6 else d
    s = np.concatenate((range_m * d, np.zeros(3)))
    _, p2, nis, _, weight, stat = kc.update_filter(s, p, y, sig2, 0.0 if tracking else range_m, 9.0)
    assert np.array_equal(p2, p2.T)
    tol = 1e-9 * np.abs(p).max()
    assert np.linalg.eigvalsh(p2).min() > -tol
    assert np.linalg.eigvalsh(p - p2).min() > -tol
    assert nis >= 0.0 and 0.0 < weight <= 1.0 and stat >= 0.0


def test_a_bearing_applied_to_a_position_alone_moves_it_across_the_bearing_only() -> None:
    """``position_update``: a position 1 m off across the bearing, uncertain by 1 m per axis,
    a bearing of 0.1 deg at 20 m: the position moves onto the bearing (the cross error falls
    from 1 m to under 5 cm), the along-bearing component and its variance hardly move; a
    gross error with a robust threshold barely pulls, without one it does."""
    x = np.array([20.0, 1.0, 0.0])  # the truth is [20, 0, 0]
    y = np.array([1.0, 0.0, 0.0])
    sig2 = math.radians(0.1) ** 2
    x2, p2 = kc.position_update(x, np.eye(3), y, sig2, math.inf)
    assert abs(x2[1]) < 0.05 and abs(x2[2]) < 1e-12
    assert abs(x2[0] - 20.0) < 0.06  # (only through the linearisation at the estimate)
    assert p2[1, 1] < 0.01 and p2[0, 0] > 0.99
    np.testing.assert_allclose(p2, p2.T)
    x_t, tight = np.array([20.0, 0.0, 0.0]), 0.01 * np.eye(3)
    far = np.array([math.cos(0.3), math.sin(0.3), 0.0])  # 17 deg off
    x3, _ = kc.position_update(x_t, tight, far, sig2, GATE)
    assert np.linalg.norm(x3 - x_t) < 0.05
    x4, _ = kc.position_update(x_t, tight, far, sig2, math.inf)
    assert np.linalg.norm(x4 - x_t) > 1.0


# -- the bank: start, estimate, prune, merge, re-seed ----------------------------------------


def test_the_bank_starts_on_the_bearing_spread_in_range_around_the_guess() -> None:
    """Seven hypotheses from r0 / span to r0 * span along the first bearing (evenly in log
    range), prior weights proportional to 1/sqrt(range), each with its range's spread along
    the bearing and ``r sigma`` across it, the bias's prior on ``a``; the Riccati observer
    at r0 with 3 r0 along the bearing."""
    y0 = np.array([0.0, 0.6, 0.8])
    prm = BankParams(sigma_rad=0.01, span=16.0, range_rel_std=0.4, bias_std_mps=5.0)
    b = BankRuns(prm, 1, 3)
    b.start(y0[None], np.array([20.0]))
    h = prm.hypotheses
    ranges = 20.0 * 16.0 ** np.linspace(-1.0, 1.0, h)
    np.testing.assert_allclose(b.fs[0, :h, :3], ranges[:, None] * y0, rtol=1e-12)
    assert np.all(b.fs[0, :h, 3:] == 0.0)
    w = np.exp(b.logw[0])
    np.testing.assert_allclose(w, ranges**-0.5 / np.sum(ranges**-0.5), rtol=1e-12)
    cross = np.eye(3) - np.outer(y0, y0)
    for k, r in enumerate(ranges):
        want = (0.4 * r) ** 2 * np.outer(y0, y0) + (r * 0.01) ** 2 * cross
        np.testing.assert_allclose(b.fp[0, k, :3, :3], want, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(b.fp[0, k, 3:, 3:], 25.0 * np.eye(3))
    np.testing.assert_allclose(b.fs[0, h, :3], 20.0 * y0)
    assert y0 @ b.fp[0, h, :3, :3] @ y0 == pytest.approx(60.0**2)
    assert b.bs[0, L.B_F] == h and b.bs[0, L.B_R0] == 20.0 and b.bs[0, L.B_RESEEDS] == 0


def test_the_mixture_estimate_includes_the_spread_of_the_hypotheses() -> None:
    y0 = np.array([[0.0, 0.6, 0.8]])
    prm = BankParams(sigma_rad=0.01, hypotheses=3, span=4.0, range_rel_std=0.1)
    b = BankRuns(prm, 1, 3)
    b.start(y0, np.array([10.0]))
    x, a, p = b.estimate()
    ranges = np.array([2.5, 10.0, 40.0])
    w = ranges**-0.5 / np.sum(ranges**-0.5)  # prior weights: the mean is the guess
    np.testing.assert_allclose(x[0], 10.0 * y0[0], rtol=1e-12)
    np.testing.assert_array_equal(a[0], 0.0)
    var_along = np.sum(w * ((0.1 * ranges) ** 2 + (ranges - 10.0) ** 2))
    assert y0[0] @ p[0, :3, :3] @ y0[0] == pytest.approx(var_along)
    np.testing.assert_allclose(np.diag(p[0])[3:], 25.0)
    np.testing.assert_array_equal(p[0], p[0].T)


def test_the_first_estimate_after_the_start_is_on_the_bearing_at_the_range_guess() -> None:
    """A bearing before any velocity: not started; once the velocity comes, the estimate is
    the bank's (its mixture mean: the guess along the bearing), not a stale one."""
    obs = BiasObserver(ObserverConfig(initial_range_m=20.0))
    obs.update_bearing(BearingSample(0.0, [0.6, 0.0, 0.8]))
    assert not obs.started and obs.hypotheses == 0
    obs.update_velocity(VelocitySample(0.0, [0.0, 0.0, 0.0]))
    est = obs.predict(0.0)
    assert obs.started and obs.hypotheses == 7
    assert est.range_m == pytest.approx(20.0, rel=1e-9)
    np.testing.assert_allclose(est.x_m, [12.0, 0.0, 16.0], rtol=1e-9)


def test_the_bank_converges_from_guesses_ten_times_off_and_its_covariance_is_honest() -> None:
    """Orbit, 1 deg noise, 120 s, 24 runs with range guesses 10x short, right and 10x long:
    every run within 5 % of range, the position's normalised error squared about its
    expected value, no re-seeding, and the hypotheses pruned and merged from 7."""
    rng = np.random.default_rng(3)
    sigma = math.radians(1.0)
    _, xt, v = _orbit(120.0)
    runs = 24
    y = _bearings(rng, xt, runs, sigma)
    r_true = float(np.linalg.norm(xt[0]))
    r0 = r_true * np.array([0.1, 1.0, 10.0] * (runs // 3))
    b = _run(BankParams(sigma_rad=sigma), y, v, r0, 0.05)
    x, _, p = b.estimate()
    err = x - xt[-1]
    assert np.all(np.linalg.norm(err, axis=1) < 0.05 * np.linalg.norm(xt[-1]))
    assert 0.5 < _nees(err, p).mean() < 2.0
    assert np.all(b.bs[:, L.B_RESEEDS] == 0)
    assert b.bs[:, L.B_F].sum() <= 3 * runs


def test_hypotheses_that_converged_to_one_estimate_are_merged_moments_matched() -> None:
    """Two hypotheses of a run a fraction of a sigma apart become one carrying both weights
    and the pair's mixture mean and covariance; the third, many sigma off, and the other
    run's hypotheses stay as they were."""
    y0 = np.array([[0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    prm = BankParams(sigma_rad=0.01, hypotheses=3, span=4.0, range_rel_std=0.1)
    runs = kc.Runs(prm, 2, 3)
    runs.start(y0, np.array([10.0, 10.0]))
    fs, fp, logw = runs.b.fs, runs.b.fp, runs.b.logw
    i, j = 0, 1  # run 0's heaviest (the shortest range) and the next, made close to it
    fs[0, j] = fs[0, i]
    fs[0, j, :3] += 0.1 * np.sqrt(np.diag(fp[0, i])[:3])
    fp[0, j] = fp[0, i]
    w = np.exp(logw[0])
    pair = [i, j]
    total = w[pair].sum()
    mean = (w[pair, None] * fs[0, pair]).sum(axis=0) / total
    d = fs[0, pair] - mean
    cov = sum(w[k] * (fp[0, k] + np.outer(d[m], d[m])) for m, k in enumerate(pair)) / total
    third = (fs[0, 2].copy(), fp[0, 2].copy(), w[2])
    other = (fs[1, :3].copy(), fp[1, :3].copy(), logw[1].copy())
    runs.merge()
    assert runs.alive.tolist() == [2, 3]
    np.testing.assert_allclose(fs[0, 0], mean, rtol=1e-12)
    np.testing.assert_allclose(fp[0, 0], cov, rtol=1e-10)
    assert math.exp(logw[0, 0]) == pytest.approx(total)
    assert np.array_equal(fs[0, 1], third[0]) and np.array_equal(fp[0, 1], third[1])
    assert math.exp(logw[0, 1]) == pytest.approx(third[2])  # (the weights sum to 1 per run)
    assert np.array_equal(fs[1, :3], other[0]) and np.array_equal(fp[1, :3], other[1])
    assert np.array_equal(logw[1], other[2])


def test_a_light_hypothesis_is_pruned_by_the_early_or_the_ordinary_threshold() -> None:
    """A hypothesis weighing 1e-6: kept in the run's first 20 s (the weights say little
    before the motion has told the ranges apart: ``prune_early`` 1e-9), dropped after them
    or once the run has been re-seeded (``prune`` 1e-4), its weight shared out."""
    y0 = np.array([[0.0, 0.6, 0.8]])
    prm = BankParams(sigma_rad=0.01, bias_std_mps=0.01)
    kept = {}
    cases = {"early": (1.0, 0), "late": (21.0, 0), "reseeded": (1.0, 1)}
    for case, (age, reseeds) in cases.items():
        b = kc.Runs(prm, 1, 3)
        b.start(y0, np.array([20.0]))
        w = np.full(7, (1.0 - 1e-6) / 6.0)
        w[6] = 1e-6
        b.logw[0] = np.log(w)
        b.bs[0, L.B_AGE_S], b.bs[0, L.B_RESEEDS] = age, reseeds
        b.step(np.zeros((1, 3)), 0.05, y0)  # (the bearing on every hypothesis: no evidence)
        kept[case] = int(b.bs[0, L.B_F])
        assert math.fsum(np.exp(b.logw[0, : kept[case]])) == pytest.approx(1.0)
    assert kept == {"early": 7, "late": 6, "reseeded": 6}


def test_an_inconsistent_bank_is_reseeded_from_the_riccati_observer() -> None:
    """Force every hypothesis onto a wrong, over-confident solution (range 5 times too
    long): its innovations give it away, the bank is seeded again around the Riccati
    observer, and the estimate ends within 5 % of range."""
    sigma = math.radians(0.5)
    t, xt, v = _orbit(90.0)
    y = (xt / np.linalg.norm(xt, axis=1)[:, None])[None]
    b = kc.Runs(BankParams(sigma_rad=sigma), 1, 3)
    r0 = float(np.linalg.norm(xt[0]))
    b.start(y[:, 0], np.array([r0]))
    h = int(b.bs[0, L.B_F])
    b.fs[0, :h, :3] = 5.0 * r0 * y[0, 0]
    b.fp[0, :h] *= 1e-6
    reseeded_at = None
    for k in range(1, len(t)):
        b.step((0.5 * (v[k - 1] + v[k]) * 0.05)[None], 0.05, y[:, k])
        if reseeded_at is None and b.bs[0, L.B_RESEEDS] > 0:
            reseeded_at = t[k]
            # a whole new bank, spread in range around the Riccati observer's estimate
            assert b.bs[0, L.B_F] == h
            ranges = np.linalg.norm(b.fs[0, :h, :3], axis=1)
            np.testing.assert_allclose(ranges[1:] / ranges[:-1], 16.0 ** (2.0 / (h - 1)))
            assert ranges[h // 2] == pytest.approx(np.linalg.norm(b.fs[0, h, :3]))
            np.testing.assert_allclose(b.fs[0, :h, :3] / ranges[:, None], np.tile(y[0, k], (h, 1)))
    assert reseeded_at is not None and reseeded_at < 30.0
    x, _, _ = b.estimate()
    assert np.linalg.norm(x[0] - xt[-1]) < 0.05 * np.linalg.norm(xt[-1])


def test_the_first_bearing_after_a_dropout_does_not_reseed_a_consistent_bank() -> None:
    """Orbit, 0.5 deg, 300 runs: 3 s without bearings every 20 s (the prediction over the
    gap in one step, exact for the constant-bias model). The bearing after each gap weighs
    in the innovations' running mean no more than a tenth of the window, so chance alone
    does not re-seed (with the gap's full weight about 1 % of the gaps did)."""
    rng = np.random.default_rng(11)
    sigma, dt = math.radians(0.5), 0.05
    t, xt, v = _orbit(70.0)
    runs = 300
    y = _bearings(rng, xt, runs, sigma)
    b = kc.Runs(BankParams(sigma_rad=sigma), runs, 3)
    b.start(y[:, 0], np.full(runs, float(np.linalg.norm(xt[0]))))
    t_b, acc = 0.0, np.zeros(3)
    gaps = 0
    for k in range(1, len(t)):
        acc += 0.5 * (v[k - 1] + v[k]) * dt
        if t[k] > 15.0 and (t[k] % 20.0) < 3.0:
            continue  # the dropout
        gaps += t[k] - t_b > 1.0
        b.step(np.broadcast_to(acc, (runs, 3)), t[k] - t_b, y[:, k])
        t_b, acc = t[k], np.zeros(3)
    assert gaps == 3
    assert int(b.bs[:, L.B_RESEEDS].sum()) == 0
    x, _, _ = b.estimate()
    assert np.all(np.linalg.norm(x - xt[-1], axis=1) < 0.02 * np.linalg.norm(xt[-1]))


# -- the noise learnt, the robust weight -----------------------------------------------------


@pytest.mark.parametrize("true_deg", [0.2, 2.0])
def test_the_bearing_noise_is_learnt_from_a_prior_four_times_off(true_deg: float) -> None:
    """Orbit, 120 s at 20 Hz, the prior 0.5 deg, the truth 0.2 or 2 deg: the noise in use is
    within 10 % of the truth in every run, and the estimate is consistent."""
    rng = np.random.default_rng(21)
    runs, sigma = 16, math.radians(true_deg)
    _, xt, v = _orbit(120.0)
    y = _bearings(rng, xt, runs, sigma)
    prm = BankParams(sigma_rad=math.radians(0.5), learn_noise=True, outlier_nis=GATE)
    b = _run(prm, y, v, float(np.linalg.norm(xt[0])), 0.05)
    learnt = np.degrees(np.sqrt(b.levels_in_use()[0]))
    assert np.all(np.abs(learnt / true_deg - 1.0) < 0.1), learnt
    x, _, p = b.estimate()
    assert 0.5 < _nees(x - xt[-1], p).mean() < 2.0


def test_told_noise_is_not_learnt() -> None:
    rng = np.random.default_rng(22)
    _, xt, v = _orbit(20.0)
    y = _bearings(rng, xt, 2, math.radians(2.0))
    prm = BankParams(sigma_rad=math.radians(0.5))
    b = _run(prm, y, v, float(np.linalg.norm(xt[0])), 0.05)
    np.testing.assert_allclose(b.levels_in_use()[0], math.radians(0.5) ** 2)
    learning = BankParams(sigma_rad=math.radians(0.5), learn_noise=True)
    b = _run(learning, y, v, float(np.linalg.norm(xt[0])), 0.05)
    assert np.all(b.levels_in_use()[0] > 2.0 * math.radians(0.5) ** 2)


def test_gross_bearing_errors_are_down_weighted_and_counted() -> None:
    """Orbit, 0.5 deg, 90 s, 8 runs; 10 % of the bearings replaced by ones 5 to 30 deg off.
    With the robust weight every run ends within 1 % of range, the outliers are counted and
    the noise learnt stays within 20 % of the clean noise; without it the same data ends
    several times further off."""
    rng = np.random.default_rng(23)
    runs, sigma = 8, math.radians(0.5)
    _, xt, v = _orbit(90.0)
    y = _bearings(rng, xt, runs, sigma)
    bad = rng.random(y.shape[:2]) < 0.1
    bad[:, :40] = False  # the first 2 s clean
    axis = rng.normal(size=y.shape)
    axis -= np.sum(axis * y, axis=-1, keepdims=True) * y
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    ang = np.radians(rng.uniform(5.0, 30.0, y.shape[:2]))[..., None]
    y = np.where(bad[..., None], np.cos(ang) * y + np.sin(ang) * axis, y)
    r0 = float(np.linalg.norm(xt[0]))
    errors = {}
    for name, gate in (("robust", GATE), ("plain", math.inf)):
        prm = BankParams(sigma_rad=sigma, learn_noise=True, outlier_nis=gate)
        b = _run(prm, y, v, r0, 0.05)
        x, _, _ = b.estimate()
        errors[name] = np.linalg.norm(x - xt[-1], axis=1) / np.linalg.norm(xt[-1])
        if name == "robust":
            outliers = b.bs[:, L.B_OUTLIERS]
            assert np.all(outliers >= 0.9 * bad.sum(axis=1))
            assert np.all(outliers <= 1.1 * bad.sum(axis=1) + 5)
            learnt = np.sqrt(b.levels_in_use()[0])
            assert np.all(np.abs(learnt / sigma - 1.0) < 0.2), np.degrees(learnt)
        else:
            assert np.all(b.bs[:, L.B_OUTLIERS] == 0)
    assert np.all(errors["robust"] < 0.01), errors["robust"]
    assert np.median(errors["plain"]) > 3.0 * np.median(errors["robust"])


def test_a_gross_error_among_the_first_bearings_prunes_no_hypothesis() -> None:
    """The bank just started, the second bearing 20 deg off: beyond the robust threshold a
    bearing is no evidence for one range over another (its loss is bounded), so all seven
    hypotheses survive, none of their weights changed by a factor e; with an unbounded loss
    the same bearing prunes the distant ones."""
    y0 = np.array([[0.6, 0.0, 0.8]])
    ang = math.radians(20.0)
    y_bad = np.array([[0.6 * math.cos(ang), math.sin(ang), 0.8 * math.cos(ang)]])
    kept = {}
    for name, gate in (("robust", GATE), ("plain", math.inf)):
        prm = BankParams(sigma_rad=math.radians(1.0), learn_noise=True, outlier_nis=gate)
        b = BankRuns(prm, 1, 3)
        b.start(y0, np.array([20.0]))
        logw0 = b.logw.copy()
        b.step(np.array([[0.1, 0.05, 0.0]]) * 0.05, 0.05, y_bad)
        kept[name] = int(b.bs[0, L.B_F])
        if name == "robust":
            assert kept[name] == prm.hypotheses
            assert np.all(np.abs(b.logw - logw0) < 1.0)
    assert kept["plain"] < 7


# -- the bias walk learnt ----------------------------------------------------------------------


def _walking_bias_run(
    q_true: float,
    seed: int,
    runs: int,
    duration_s: float = 240.0,
    outliers: float = 0.0,
    walk_q0: float = 0.0,
    hold: tuple[bool, float] | None = None,
    **prm_kw: float,
):
    """Orbit, 0.5 deg bearings (the noise learnt), a bias that is a random walk of intensity
    ``q_true`` (m^2/s^3) on top of the scenario's, the bank learning its walk (``hold``: the
    walk held as the latency learner holds it, ``(walk_hold, walk_hold_nats)``); returns the
    runs, their settings and the true positions (R, T, 3)."""
    rng = np.random.default_rng(seed)
    dt = 0.05
    t, xs, v = _orbit(duration_s)
    walk = np.cumsum(rng.normal(0.0, math.sqrt(q_true * dt), (runs, len(t), 3)), axis=1)
    xt = xs[None] + np.cumsum(walk * dt, axis=1)
    y = _bearings(rng, xt, runs, math.radians(0.5))
    gross = rng.random(y.shape[:2]) < outliers  # 10 deg off (a tracker's false lock)
    y[gross] = perturb_bearings(y[gross], math.radians(10.0), rng)
    prm = BankParams(
        sigma_rad=math.radians(1.0), learn_noise=True, outlier_nis=GATE, learn_walk=True, **prm_kw
    )
    r0 = float(np.linalg.norm(xs[0]))
    hold_kw = {} if hold is None else {"hold": hold[0], "hold_nats": hold[1]}
    return _run(prm, y, v, r0, dt, walk_q0, **hold_kw), prm, xt


def _walk(b: kc.Runs, prm: BankParams) -> np.ndarray:
    """The bias walk in use (m^2/s^3) per run."""
    return b.levels_in_use()[1]


def test_the_bias_walk_is_learnt_and_a_constant_bias_stays_constant() -> None:
    """A bias wandering at 0.01 m/s/sqrt(s): the walk learnt within a level (a factor 2 in
    m/s/sqrt(s)) in every run, the estimate consistent; a constant bias: nothing learnt,
    ``q_a`` exactly 0 as the paper's model."""
    b, prm, xt = _walking_bias_run(1e-4, 31, 4)
    learnt = np.sqrt(_walk(b, prm))
    assert np.all((learnt > 0.005) & (learnt < 0.02)), learnt
    x, _, p = b.estimate()
    assert 0.3 < _nees(x - xt[:, -1], p).mean() < 2.0
    b, prm, _ = _walking_bias_run(0.0, 32, 2)
    assert np.all(_walk(b, prm) == 0.0)


def test_the_bias_walk_waits_while_held_and_leaving_zero_takes_the_leave_bar() -> None:
    """The same wandering bias: held off (``walk_hold_nats`` inf), no probe runs and
    nothing is learnt; held with the default bar, which this bias clears, it is learnt; with
    a bar to leave 0 no lead reaches, the walk stays 0 though the probes run."""
    b, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, hold=(True, math.inf))
    assert np.all(_walk(b, prm) == 0.0) and not b.bs[:, L.B_WALK_ON].any()
    b, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, hold=(True, 60.0))
    assert np.all(_walk(b, prm) > 0.0), _walk(b, prm)
    b, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, walk_leave_nats=1e9)
    assert np.all(_walk(b, prm) == 0.0) and b.bs[:, L.B_WALK_ON].all()


def test_the_hold_guards_leaving_zero_only() -> None:
    """Held with a bar no lead reaches: from 0 the walk stays 0; from a level above 0 (a
    wandering bias already seen) it moves with the ordinary bar, up toward the truth."""
    never = (True, 1e9)
    b, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, hold=never)
    assert np.all(_walk(b, prm) == 0.0) and b.bs[:, L.B_WALK_ON].all()
    b, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, walk_q0=1e-6, hold=never)
    assert np.all(_walk(b, prm) >= 1.6e-5), _walk(b, prm)


def test_a_bias_that_wanders_leaves_zero_by_the_jump_where_the_ladder_would_crawl() -> None:
    """A bias wandering at 0.018 m/s/sqrt(s) (a 0.1 m/s Gauss-Markov error over 60 s), 70 s:
    from 0 the jump probe (``walk_jump``) leads and the walk leaves 0 to it in every run,
    the estimate consistent; without the jump the ladder from ``walk_min`` climbs a factor 4
    per move from levels the bearings can hardly tell from 0: every run still below the
    jump's level, and over-confident."""

    def run(**kw: float) -> tuple[np.ndarray, float]:
        b, prm, xt = _walking_bias_run(3.3e-4, 35, 4, duration_s=70.0, **kw)
        x, _, p = b.estimate()
        return _walk(b, prm), float(_nees(x - xt[:, -1], p).mean())

    jump = BankParams(sigma_rad=1.0).walk_jump
    q, nees = run()
    assert np.all(q >= jump) and nees < 2.0, (np.sqrt(q), nees)
    q, nees = run(walk_jump=0.0)
    assert np.all(q < 0.5 * jump) and nees > 3.0, (np.sqrt(q), nees)


def test_gross_bearing_errors_do_not_make_the_bias_walk() -> None:
    """10 % of bearings 10 deg off, a constant bias: they count for no probe (a filter with
    a wider covariance pays less for them), so nothing is learnt."""
    b, prm, xt = _walking_bias_run(0.0, 34, 2, duration_s=180.0, outliers=0.1)
    assert np.all(_walk(b, prm) == 0.0), np.sqrt(_walk(b, prm))
    x, _, _ = b.estimate()
    assert np.all(np.linalg.norm(x - xt[:, -1], axis=1) < 0.05 * np.linalg.norm(xt[:, -1], axis=1))


def test_a_told_bias_walk_is_used_as_told_and_the_probes_follow_the_bank() -> None:
    """``learn_walk`` off: ``q_a`` as told and no probe runs; on: the probes start as
    copies of the run's filter once it is alone, past the warm-up; the levels they try."""
    rng = np.random.default_rng(33)
    _, xt, v = _orbit(30.0)
    y = _bearings(rng, xt, 2, math.radians(0.5))
    r0 = float(np.linalg.norm(xt[0]))
    told = BankParams(sigma_rad=math.radians(0.5), q_a=3e-4)
    b = _run(told, y, v, r0, 0.05)
    np.testing.assert_allclose(_walk(b, told), 3e-4)
    hp = told.hypotheses
    assert not b.bs[:, L.B_WALK_ON].any() and not b.fs[:, hp + 1 :].any()
    learn = BankParams(sigma_rad=math.radians(0.5), learn_walk=True, walk_warmup_s=5.0)
    b = kc.Runs(learn, 2, 3)
    b.start(y[:, 0], np.full(2, r0))
    checked = 0
    for k in range(1, y.shape[1]):
        was_on = b.bs[:, L.B_WALK_ON].copy()
        b.step(np.broadcast_to(0.5 * (v[k - 1] + v[k]) * 0.05, (2, 3)), 0.05, y[:, k])
        for r in np.flatnonzero((b.bs[:, L.B_WALK_ON] > 0.0) & (was_on == 0.0)):
            assert b.bs[r, L.B_F] == 1 and b.bs[r, L.B_AGE_S] > 5.0
            for probe in (hp + 1, hp + 2):
                assert np.array_equal(b.fs[r, probe], b.fs[r, 0])
                assert np.array_equal(b.fp[r, probe], b.fp[r, 0])
            assert b.bs[r, L.B_WALK_LL_LO] == 0.0 and b.bs[r, L.B_WALK_LL_HI] == 0.0
            checked += 1
    assert checked == 2 and b.bs[:, L.B_WALK_ON].all()
    levels = kc.Runs(learn, 1, 3)
    assert levels.walk_levels(0.0) == pytest.approx((learn.walk_jump, learn.walk_min))
    assert levels.walk_levels(1e-4) == pytest.approx((2.5e-5, 4e-4))
    assert levels.walk_levels(1e-6) == pytest.approx((0.0, 4e-6))
    assert levels.walk_levels(0.5) == pytest.approx((0.125, 1.0))  # (walk_max)
    no_jump = kc.Runs(BankParams(sigma_rad=1.0, walk_jump=0.0), 1, 3)
    assert no_jump.walk_levels(0.0) == pytest.approx((0.0, learn.walk_min))


def test_the_walk_mixture_weighs_the_filter_and_its_probes_by_their_lead() -> None:
    """The estimate of a run whose probes run: its filter's mean; the covariance, the filter
    and its probes weighed by their lead (each with its offset from the filter's mean
    squared): a probe leading by far, its covariance and offset; no lead either way, the
    three a third each; no probe running, the filter's own."""
    b, _, _ = _walking_bias_run(3.3e-4, 36, 2, duration_s=60.0)
    assert np.all(b.bs[:, L.B_F] == 1) and np.all(b.bs[:, L.B_WALK_ON] == 1.0)
    hp = b.fs.shape[1] - 3
    s0, p0 = b.fs[:, 0].copy(), b.fp[:, 0].copy()
    d = b.fs[:, hp + 1 :] - s0[:, None]
    probe = b.fp[:, hp + 1 :] + d[..., :, None] * d[..., None, :]  # (R, 2, 6, 6)
    b.bs[:, L.B_WALK_LL_LO] = [-500.0, 0.0]
    b.bs[:, L.B_WALK_LL_HI] = [500.0, 0.0]
    x, a, p = b.estimate()
    assert np.array_equal(x, s0[:, :3]) and np.array_equal(a, s0[:, 3:])
    np.testing.assert_allclose(p[0], probe[0, 1], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(p[1], (p0[1] + probe[1, 0] + probe[1, 1]) / 3.0, rtol=1e-9)
    b.bs[:, L.B_WALK_ON] = 0.0
    assert np.array_equal(b.estimate()[2], p0)


def test_weighing_the_walk_levels_makes_a_wandering_bias_honest() -> None:
    """A bias wandering as a 0.1 m/s Gauss-Markov error over 60 s does short-term (0.018
    m/s/sqrt(s)), its walk learnt: over the last third of 4 minutes, sampled each second,
    the published covariance (the levels weighed) puts the position's normalised error
    squared per axis nearer 1 than the filter's own covariance."""
    rng = np.random.default_rng(37)
    runs, dt, duration = 12, 0.05, 240.0
    t, xs, v = _orbit(duration)
    walk = np.cumsum(rng.normal(0.0, math.sqrt(3.3e-4 * dt), (runs, len(t), 3)), axis=1)
    xt = xs[None] + np.cumsum(walk * dt, axis=1)
    y = _bearings(rng, xt, runs, math.radians(0.5))
    prm = BankParams(
        sigma_rad=math.radians(1.0), learn_noise=True, outlier_nis=GATE, learn_walk=True
    )
    b = kc.Runs(prm, runs, 3)
    b.start(y[:, 0], np.full(runs, float(np.linalg.norm(xs[0]))))
    own, mixed = [], []
    for k in range(1, len(t)):
        b.step(np.broadcast_to(0.5 * (v[k - 1] + v[k]) * dt, (runs, 3)), dt, y[:, k])
        if t[k] > 2.0 * duration / 3.0 and k % 20 == 0:
            x, _, p = b.estimate()
            err = x - xt[:, k]
            own.append(_nees(err, b.fp[:, 0]))
            mixed.append(_nees(err, p))
    nees_own, nees_mixed = float(np.mean(own)), float(np.mean(mixed))
    assert b.bs[:, L.B_WALK_ON].all() and np.all(_walk(b, prm) > 0.0)
    assert nees_mixed < nees_own, (nees_mixed, nees_own)
    assert abs(math.log(nees_mixed)) < abs(math.log(nees_own)), (nees_mixed, nees_own)


# -- the observer's settings on a hard stream -----------------------------------------------


def _hard_stream(seed: int, seconds: float):
    """``(h_s, v_mps, y, x_true)`` at 20 Hz: an orbit of 40 m around a target, a bias
    wandering 0.01 m/s per root second, bearings with 0.5 deg noise, 5 % of them 5-30 deg
    off, and the target jumping 60 m at two thirds of the span (a re-acquisition)."""
    rng = np.random.default_rng(seed)
    h = 0.05
    target = np.array([0.0, 0.0, 10.0])
    bias = np.zeros(3)
    w = 2.0 * math.pi / 40.0
    out = []
    for i in range(int(seconds / h)):
        t = i * h
        if abs(t - 2.0 * seconds / 3.0) < h / 2:
            target = target + np.array([60.0, 0.0, 0.0])
        pos = np.array([40.0 * math.cos(w * t), 40.0 * math.sin(w * t), -5.0 * math.sin(w * t)])
        vel = np.array(
            [-40.0 * w * math.sin(w * t), 40.0 * w * math.cos(w * t), -5.0 * w * math.cos(w * t)]
        )
        bias = bias + rng.normal(size=3) * 0.01 * math.sqrt(h)
        x = target - pos
        y = x / np.linalg.norm(x)
        sig = math.radians(0.5) if rng.uniform() > 0.05 else math.radians(rng.uniform(5.0, 30.0))
        y = y + rng.normal(size=3) * sig
        out.append((h, -vel - bias, y / np.linalg.norm(y), x))
    return out


def test_the_observers_bank_acquires_learns_and_reacquires_on_a_hard_stream() -> None:
    """The observer's settings (noise, walk learnt, robust): through acquisition (seven
    hypotheses pruned and merged to one), the bias walk learnt (its level moved), gross
    errors counted, and a re-acquisition after the target jumped 60 m, the estimate back on
    the target by the end."""
    prm = ObserverConfig().bank_params(0.05)
    assert prm.learn_walk and prm.learn_noise and math.isfinite(prm.outlier_nis)
    data = _hard_stream(3, 180.0)
    b = kc.Runs(prm, 1, 3)
    b.start(data[0][2][None], np.array([30.0]))
    filters, levels = set(), set()
    reseeded_at = None
    for k, (h, v, y, _) in enumerate(data[1:], start=1):
        b.step((v * h)[None], h, y[None])
        filters.add(int(b.bs[0, L.B_F]))
        levels.add(float(b.bs[0, L.B_WALK_Q]))
        if reseeded_at is None and b.bs[0, L.B_RESEEDS] > 0:
            reseeded_at = k * 0.05
    assert {1, 7} <= filters and len(filters) >= 3, filters
    assert len(levels) >= 2, levels
    assert reseeded_at is not None and 120.0 < reseeded_at < 150.0, reseeded_at
    assert b.bs[0, L.B_OUTLIERS] > 50
    x, _, _ = b.estimate()
    x_true = data[-1][3]
    assert np.linalg.norm(x[0] - x_true) < 0.05 * np.linalg.norm(x_true)


def test_a_gap_carried_over_moves_the_probes_with_the_filter() -> None:
    """``resume`` moves every filter of the bank by the displacement over the gap, the
    walk's probes too (one of them may become the filter later)."""
    obs = BiasObserver(ObserverConfig(bearing_latency_s=0.0))
    data = _hard_stream(4, 60.0)
    t = 0.0
    for h, v, y, _ in data:
        obs.update_velocity_values(t, v.tolist())
        obs.update_bearing_values(t, y.tolist())
        t += h
    st = obs._st
    hp = obs.config.hypotheses
    assert st.s[L.OFF_BS + L.B_F] == 1 and st.s[L.OFF_BS + L.B_WALK_ON] == 1.0
    before = st.fs.copy()
    dx = np.array([1.0, -2.0, 0.5])
    obs.resume(obs.committed_t_s + 5.0, dx.tolist(), [0.0, 0.0, 0.0])
    for row in (0, hp, hp + 1, hp + 2):
        np.testing.assert_allclose(st.fs[row, :3] - before[row, :3], dx, atol=1e-12)
        assert np.array_equal(st.fs[row, 3:], before[row, 3:])
