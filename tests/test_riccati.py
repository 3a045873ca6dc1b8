"""The Riccati estimator's pure, batched maths (mav_observer/riccati.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer import riccati
from mav_observer.config import outlier_nis
from sim import scenarios
from sim.stream import perturb_bearings


def _unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    v = rng.normal(size=shape)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 6))
def test_tangent_basis_is_orthonormal_and_orthogonal_to_the_direction(seed: int, n: int) -> None:
    d = _unit(np.random.default_rng(seed), (5, n))
    d[0] = np.eye(n)[0]  # the reflection's own axis, both signs
    d[1] = -np.eye(n)[0]
    e = riccati.tangent_basis(d)
    assert e.shape == (5, n, n - 1)
    gram = np.swapaxes(e, -1, -2) @ e
    assert np.allclose(gram, np.eye(n - 1), atol=1e-12)
    assert np.allclose(np.einsum("bi,bij->bj", d, e), 0.0, atol=1e-12)


def test_predict_is_the_exact_propagation_of_a_constant_bias() -> None:
    rng = np.random.default_rng(1)
    n, h = 3, 0.7
    x, a = rng.normal(size=n), rng.normal(size=n)
    g = rng.normal(size=(2 * n, 2 * n))
    p = g @ g.T
    dx = rng.normal(size=n)
    x2, a2, p2 = riccati.predict(x, a, p, dx, h, 0.3, 0.02)
    assert np.allclose(x2, x + dx + h * a) and np.array_equal(a2, a)
    f = np.block([[np.eye(n), h * np.eye(n)], [np.zeros((n, n)), np.eye(n)]])
    q1 = np.array([[0.3 * h + 0.02 * h**3 / 3, 0.02 * h**2 / 2], [0.02 * h**2 / 2, 0.02 * h]])
    assert np.allclose(p2, f @ p @ f.T + np.kron(q1, np.eye(n)))
    # batched: the same numbers for each element
    xb, _, pb = riccati.predict(
        np.stack([x, x]), np.stack([a, a]), np.stack([p, p]), np.stack([dx, dx]), h, 0.3, 0.02
    )
    assert np.allclose(pb[1], p2) and np.allclose(xb[0], x2)


def test_tracking_update_is_the_extended_kalman_update() -> None:
    """Against a direct EKF with the Jacobian of y = x/|x| in the tangent coordinates."""
    rng = np.random.default_rng(2)
    n, sigma = 3, 0.01
    x = np.array([10.0, 4.0, 3.0])
    a = np.array([0.5, -0.2, 0.1])
    g = rng.normal(size=(6, 6))
    p = g @ g.T + np.eye(6)
    y = x + np.array([0.3, -0.2, 0.1])
    y /= np.linalg.norm(y)
    x2, a2, p2, nis, logdet = riccati.update(x, a, p, y, sigma, True, 0.0, math.inf)
    r = np.linalg.norm(x)
    e = riccati.tangent_basis(x / r)
    h = np.hstack((e.T / r, np.zeros((2, n))))
    s = h @ p @ h.T + sigma**2 * np.eye(2)
    k = p @ h.T @ np.linalg.inv(s)
    z = e.T @ y
    assert np.allclose(np.concatenate((x2, a2)), np.concatenate((x, a)) + k @ z)
    assert np.allclose(p2, p - k @ s @ k.T)
    assert nis == pytest.approx(z @ np.linalg.solve(s, z))
    assert logdet == pytest.approx(np.linalg.slogdet(s)[1])


def test_acquisition_update_needs_no_estimate_to_converge() -> None:
    """The Riccati observer (acquisition form): noise-free bearings of the orbit scenario,
    started at a range 100 times too long and a bias of 20 m/s the wrong way: within 1 mm
    after 60 s."""
    sc = scenarios.orbit(duration_s=60.0)
    t = np.arange(0.0, 60.0 + 1e-9, 0.05)
    xt, v = sc.x(t), sc.v(t)
    y = xt / np.linalg.norm(xt, axis=1, keepdims=True)
    r0 = 100.0 * float(np.linalg.norm(xt[0]))
    x, a = r0 * y[0], np.array([20.0, -20.0, 5.0])
    p = riccati.initial_covariance(y[0], r0, 3.0 * r0, 5.0, 1e-3)
    for k in range(1, len(t)):
        x, a, p = riccati.predict(x, a, p, 0.5 * (v[k - 1] + v[k]) * 0.05, 0.05, 0.0, 0.0)
        x, a, p, _, _ = riccati.update(x, a, p, y[k], 1e-3, False, r0, r0)
    assert np.linalg.norm(x - xt[-1]) < 1e-3
    assert np.linalg.norm(a - sc.a_mps) < 1e-3


def _bank_run(
    y: np.ndarray,
    v: np.ndarray,
    r0: np.ndarray,
    prm: riccati.BankParams,
    dt: float,
    walk_q0: float = 0.0,
) -> riccati.Bank:
    bank = riccati.bank_start(y[:, 0], r0, prm)
    bank.walk_q[:] = walk_q0  # the bias walk's level at the start (m^2/s^3)
    for k in range(1, y.shape[1]):
        riccati.bank_predict(bank, 0.5 * (v[:, k - 1] + v[:, k]) * dt, dt, prm)
        riccati.bank_update(bank, y[:, k], dt, prm)
    return bank


def test_bank_converges_from_guesses_ten_times_off_and_its_covariance_is_honest() -> None:
    """Orbit, 1 deg noise, 120 s, 24 runs with range guesses 10x short, right and 10x long:
    every run within 5 % of range, and the normalised error squared of the position is about
    its expected value n."""
    rng = np.random.default_rng(3)
    sc = scenarios.orbit(duration_s=120.0)
    dt, sigma = 0.05, math.radians(1.0)
    t = np.arange(0.0, 120.0 + 1e-9, dt)
    xt, v = sc.x(t), sc.v(t)
    runs = 24
    y = np.stack([perturb_bearings(xt / np.linalg.norm(xt, axis=1)[:, None], sigma, rng)
                  for _ in range(runs)])  # fmt: skip
    r_true = float(np.linalg.norm(xt[0]))
    r0 = r_true * np.array([0.1, 1.0, 10.0] * (runs // 3))
    prm = riccati.BankParams(sigma_rad=sigma)
    bank = _bank_run(y, np.broadcast_to(v, (runs, *v.shape)), r0, prm, dt)
    x, _, p = riccati.bank_estimate(bank)
    err = x - xt[-1]
    assert np.all(np.linalg.norm(err, axis=1) < 0.05 * np.linalg.norm(xt[-1]))
    nees = np.einsum("ri,rij,rj->r", err, np.linalg.inv(p[:, :3, :3]), err)
    assert 0.5 * 3 < nees.mean() < 2.0 * 3
    assert np.all(bank.reseeds == 0)
    assert len(bank.owner) <= 3 * runs  # pruned from 7 filters per run


def test_inconsistent_bank_is_reseeded_from_the_riccati_observer() -> None:
    """Force every filter of the bank onto a wrong, over-confident solution (range 5 times
    too long): its innovations give it away, the bank is seeded again around the Riccati
    observer, and the estimate ends within 5 % of range."""
    sc = scenarios.orbit(duration_s=90.0)
    dt, sigma = 0.05, math.radians(0.5)
    t = np.arange(0.0, 90.0 + 1e-9, dt)
    xt, v = sc.x(t), sc.v(t)
    y = (xt / np.linalg.norm(xt, axis=1)[:, None])[None]
    prm = riccati.BankParams(sigma_rad=sigma)
    r0 = np.array([float(np.linalg.norm(xt[0]))])
    bank = riccati.bank_start(y[:, 0], r0, prm)
    bank.x = 5.0 * bank.x / np.linalg.norm(bank.x, axis=1, keepdims=True) * r0[0]
    bank.p = bank.p * 1e-6
    reseeded_at = None
    for k in range(1, len(t)):
        riccati.bank_predict(bank, 0.5 * (v[k - 1] + v[k])[None] * dt, dt, prm)
        riccati.bank_update(bank, y[:, k], dt, prm)
        if reseeded_at is None and bank.reseeds[0] > 0:
            reseeded_at = t[k]
    assert reseeded_at is not None and reseeded_at < 30.0
    x, _, _ = riccati.bank_estimate(bank)
    assert np.linalg.norm(x[0] - xt[-1]) < 0.05 * np.linalg.norm(xt[-1])


def test_the_first_bearing_after_a_dropout_does_not_reseed_a_consistent_bank() -> None:
    """Orbit, 0.5 deg, 300 runs: 3 s without bearings every 20 s. The bearing after each gap
    weighs in the innovations' running mean no more than a tenth of the window, so chance
    alone does not re-seed (with the gap's full weight about 1 % of the gaps did)."""
    rng = np.random.default_rng(11)
    sc = scenarios.orbit(duration_s=70.0)
    dt, sigma = 0.05, math.radians(0.5)
    t = np.arange(0.0, 70.0 + 1e-9, dt)
    xt, v = sc.x(t), sc.v(t)
    runs = 300
    y_true = np.tile(xt / np.linalg.norm(xt, axis=1)[:, None], (runs, 1))
    y = perturb_bearings(y_true, sigma, rng).reshape(runs, -1, 3)
    prm = riccati.BankParams(sigma_rad=sigma)
    bank = riccati.bank_start(y[:, 0], np.full(runs, float(np.linalg.norm(xt[0]))), prm)
    t_b = 0.0
    for k in range(1, len(t)):
        riccati.bank_predict(bank, np.broadcast_to(0.5 * (v[k - 1] + v[k]) * dt, (runs, 3)),
                             dt, prm)  # fmt: skip
        if t[k] > 15.0 and (t[k] % 20.0) < 3.0:
            continue  # the dropout
        riccati.bank_update(bank, y[:, k], t[k] - t_b, prm)
        t_b = t[k]
    assert int(bank.reseeds.sum()) == 0
    x, _, _ = riccati.bank_estimate(bank)
    assert np.all(np.linalg.norm(x - xt[-1], axis=1) < 0.02 * np.linalg.norm(xt[-1]))


def test_mixture_estimate_includes_the_spread_of_the_hypotheses() -> None:
    y0 = np.array([[0.0, 0.6, 0.8]])
    prm = riccati.BankParams(sigma_rad=0.01, hypotheses=3, span=4.0, range_rel_std=0.1)
    bank = riccati.bank_start(y0, np.array([10.0]), prm)
    x, _, p = riccati.bank_estimate(bank)
    ranges = np.array([2.5, 10.0, 40.0])
    w = ranges**-0.5 / np.sum(ranges**-0.5)  # prior weights: the mean is the guess
    assert np.allclose(x[0], 10.0 * y0[0])
    var_along = np.sum(w * ((0.1 * ranges) ** 2 + (ranges - 10.0) ** 2))
    assert y0[0] @ p[0, :3, :3] @ y0[0] == pytest.approx(var_along)
    assert np.allclose(np.diag(p[0])[3:], 25.0)


def test_hypotheses_that_converged_to_one_estimate_are_merged_moments_matched() -> None:
    """Two filters of a run a fraction of a sigma apart become one carrying both weights and
    the pair's mixture mean and covariance; a third, many sigma off, and the other run's
    filters stay."""
    y0 = np.array([[0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    prm = riccati.BankParams(sigma_rad=0.01, hypotheses=3, span=4.0, range_rel_std=0.1)
    bank = riccati.bank_start(y0, np.array([10.0, 10.0]), prm)
    assert len(bank.owner) == 6
    i, j = np.flatnonzero(bank.owner == 0)[:2]  # run 0's two nearest ranges: made close
    bank.x[j] = bank.x[i] + 0.1 * np.sqrt(np.diag(bank.p[i])[:3])
    bank.a[j] = bank.a[i]
    bank.p[j] = bank.p[i]
    w = np.exp(bank.logw)
    s = np.concatenate((bank.x, bank.a), axis=-1)
    pair = [i, j]
    total = w[pair].sum()
    mean = (w[pair, None] * s[pair]).sum(axis=0) / total
    d = s[pair] - mean
    cov = sum(w[k] * (bank.p[k] + np.outer(d[n], d[n])) for n, k in enumerate(pair)) / total
    others = [k for k in range(6) if k not in pair]
    s_others = s[others]
    riccati._merge(bank, prm)
    assert len(bank.owner) == 5
    assert np.bincount(bank.owner).tolist() == [2, 3]
    s_after = np.concatenate((bank.x, bank.a), axis=-1)
    k = int(np.argmin(np.linalg.norm(s_after - mean, axis=1)))
    assert np.allclose(s_after[k], mean)
    assert np.allclose(bank.p[k], cov)
    w_after = np.exp(bank.logw)
    assert w_after[k] == pytest.approx(total)  # (the weights sum to 1 per run)
    assert all(np.any(np.all(np.isclose(s_after, row), axis=1)) for row in s_others)


def _orbit_bearings(
    rng: np.random.Generator, runs: int, duration_s: float, sigma: float, dt: float = 0.05
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sc = scenarios.orbit(duration_s=duration_s)
    t = np.arange(0.0, duration_s + 1e-9, dt)
    xt, v = sc.x(t), sc.v(t)
    y_true = np.tile(xt / np.linalg.norm(xt, axis=1)[:, None], (runs, 1))
    y = perturb_bearings(y_true, sigma, rng).reshape(runs, -1, 3)
    return xt, np.broadcast_to(v, (runs, *v.shape)), y


@pytest.mark.parametrize("true_deg", [0.2, 2.0])
def test_the_bearing_noise_is_learnt_from_a_prior_four_times_off(true_deg: float) -> None:
    """Orbit, 120 s at 20 Hz, the prior 0.5 deg, the truth 0.2 or 2 deg: after a minute the
    noise in use is within 10 % of the truth in every run, and the estimate is consistent
    (NEES per axis in [0.5, 2])."""
    rng = np.random.default_rng(21)
    runs, sigma = 16, math.radians(true_deg)
    xt, v, y = _orbit_bearings(rng, runs, 120.0, sigma)
    prm = riccati.BankParams(sigma_rad=math.radians(0.5), learn_noise=True, outlier_nis=13.816)
    bank = _bank_run(y, v, np.full(runs, float(np.linalg.norm(xt[0]))), prm, 0.05)
    learnt = np.degrees(np.sqrt(bank.noise_var_rad2(prm)))
    assert np.all(np.abs(learnt / true_deg - 1.0) < 0.1), learnt
    x, _, p = riccati.bank_estimate(bank)
    err = x - xt[-1]
    nees = np.einsum("ri,rij,rj->r", err, np.linalg.inv(p[:, :3, :3]), err) / 3
    assert 0.5 < nees.mean() < 2.0


def test_told_noise_is_not_learnt() -> None:
    rng = np.random.default_rng(22)
    xt, v, y = _orbit_bearings(rng, 2, 20.0, math.radians(2.0))
    prm = riccati.BankParams(sigma_rad=math.radians(0.5))
    bank = _bank_run(y, v, np.full(2, float(np.linalg.norm(xt[0]))), prm, 0.05)
    assert np.allclose(bank.noise_var_rad2(prm), math.radians(0.5) ** 2)


def test_gross_bearing_errors_are_down_weighted_and_counted() -> None:
    """Orbit, 0.5 deg, 90 s, 8 runs; 10 % of the bearings replaced by ones 5 to 30 deg off.
    With the robust weight every run ends within 1 % of range, the outliers are counted and
    the learnt noise stays within 20 % of the clean noise; without it the same data ends
    several times further off."""
    rng = np.random.default_rng(23)
    runs, sigma = 8, math.radians(0.5)
    xt, v, y = _orbit_bearings(rng, runs, 90.0, sigma)
    bad = rng.random(y.shape[:2]) < 0.1
    bad[:, :40] = False  # the first 2 s clean
    axis = rng.normal(size=y.shape)
    axis -= np.sum(axis * y, axis=-1, keepdims=True) * y
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    ang = np.radians(rng.uniform(5.0, 30.0, y.shape[:2]))[..., None]
    y_bad = np.cos(ang) * y + np.sin(ang) * axis
    y = np.where(bad[..., None], y_bad, y)
    r0 = np.full(runs, float(np.linalg.norm(xt[0])))
    errors = {}
    for name, gate in (("robust", 13.816), ("plain", math.inf)):
        prm = riccati.BankParams(sigma_rad=sigma, learn_noise=True, outlier_nis=gate)
        bank = _bank_run(y, v, r0, prm, 0.05)
        x, _, _ = riccati.bank_estimate(bank)
        errors[name] = np.linalg.norm(x - xt[-1], axis=1) / np.linalg.norm(xt[-1])
        if name == "robust":
            assert np.all(bank.outliers >= 0.9 * bad.sum(axis=1))
            assert np.all(bank.outliers <= 1.1 * bad.sum(axis=1) + 5)
            learnt = np.sqrt(bank.noise_var_rad2(prm))
            assert np.all(np.abs(learnt / sigma - 1.0) < 0.2), np.degrees(learnt)
    assert np.all(errors["robust"] < 0.01), errors["robust"]
    assert np.median(errors["plain"]) > 3.0 * np.median(errors["robust"])


def test_update_robust_moves_the_state_little_for_a_gross_error() -> None:
    """A converged filter and one bearing 20 deg off: the robust update moves the estimate
    less than one noise-sized bearing would; the plain update moves it far more."""
    x = np.array([[10.0, 0.0, 0.0]])
    a = np.zeros((1, 3))
    p = np.diag([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4])[None]
    sig2 = math.radians(0.5) ** 2
    ang = math.radians(20.0)
    y_bad = np.array([[math.cos(ang), math.sin(ang), 0.0]])
    ang1 = math.radians(0.5)
    y_ok = np.array([[math.cos(ang1), math.sin(ang1), 0.0]])
    robust = riccati.update_robust(x, a, p, y_bad, sig2, True, 1.0, 1.0, 13.816)
    plain = riccati.update_robust(x, a, p, y_bad, sig2, True, 1.0, 1.0, math.inf)
    ok = riccati.update_robust(x, a, p, y_ok, sig2, True, 1.0, 1.0, 13.816)
    move = {k: float(np.linalg.norm(r.x - x)) for k, r in (("r", robust), ("p", plain), ("o", ok))}
    assert move["r"] < move["o"] < move["p"]
    assert robust.weight[0] < 1e-3 and ok.weight[0] == 1.0
    assert plain.nis[0] == pytest.approx(robust.nis[0])  # the NIS is the nominal one


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_three_dimensional_update_written_out_equals_the_batched_products(seed: int) -> None:
    """A flat batch in three dimensions takes the update written out entry by entry (the
    harness's path); a batch with one more axis takes the batched matrix products. Both on
    the same filters (tracking and acquisition, a third of the bearings gross errors): every
    output equal to rounding, and the covariance exactly symmetric."""
    rng = np.random.default_rng(seed)
    f = 300
    m = rng.normal(size=(f, 6, 6))
    p = 0.01 * m @ m.transpose(0, 2, 1) + 1e-6 * np.eye(6)
    x = 50.0 * rng.normal(size=(f, 3))
    a = rng.normal(size=(f, 3))
    y = x + rng.normal(size=(f, 3)) * np.where(rng.random(f) < 0.3, 20.0, 0.5)[:, None]
    y /= np.linalg.norm(y, axis=1)[:, None]
    sig2 = rng.uniform(1e-5, 1e-3, size=f)
    tracking = rng.random(f) < 0.7
    r_w = np.where(tracking, 1.0, rng.uniform(5.0, 80.0, size=f))
    g = outlier_nis(2)
    flat = riccati.update_robust(x, a, p, y, sig2, tracking, r_w, r_w, g)
    col = (slice(None), None)
    batched = riccati.update_robust(
        x[col], a[col], p[col], y[col], sig2[col], tracking[col], r_w[col], r_w[col], g
    )
    assert 0 < int(np.sum(flat.weight < 1.0)) < f
    for name in ("x", "a", "p", "nis", "logdet", "weight", "noise_stat"):
        got, want = getattr(flat, name), getattr(batched, name)[:, 0]
        assert got.shape == want.shape, name
        scale = np.max(np.abs(want))
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * scale, err_msg=name)
    np.testing.assert_array_equal(flat.p, flat.p.transpose(0, 2, 1))


def test_a_gross_error_among_the_first_bearings_prunes_no_hypothesis() -> None:
    """The bank just started, the second bearing 20 deg off: beyond the robust threshold a
    bearing is no evidence for one range over another (its loss is bounded), so all seven
    hypotheses survive, none of their weights changed by a factor e; with an unbounded loss the same
    bearing prunes the distant ones (one such bearing early in a run left a filter tens of
    metres off for a minute, 4.3x the bound end to end)."""
    y0 = np.array([[0.6, 0.0, 0.8]])
    ang = math.radians(20.0)
    y_bad = np.array([[0.6 * math.cos(ang), math.sin(ang), 0.8 * math.cos(ang)]])
    kept = {}
    for name, gate in (("robust", 13.816), ("plain", math.inf)):
        prm = riccati.BankParams(sigma_rad=math.radians(1.0), learn_noise=True, outlier_nis=gate)
        bank = riccati.bank_start(y0, np.array([20.0]), prm)
        w0 = np.exp(bank.logw)
        riccati.bank_predict(bank, np.array([[0.1, 0.05, 0.0]]), 0.05, prm)
        riccati.bank_update(bank, y_bad, 0.05, prm)
        kept[name] = len(bank.owner)
        if name == "robust":
            assert kept[name] == prm.hypotheses
            assert np.all(np.abs(bank.logw - np.log(w0)) < 1.0)
    assert kept["plain"] < prm.hypotheses


def _walking_bias_run(
    q_true: float,
    seed: int,
    runs: int,
    duration_s: float = 240.0,
    dt: float = 0.05,
    outliers: float = 0.0,
    walk_q0: float = 0.0,
    **prm_kw: float | bool,
) -> tuple[riccati.Bank, riccati.BankParams, np.ndarray]:
    """Orbit, 0.5 deg bearings (the noise learnt), a bias that is a random walk of intensity
    ``q_true`` (m^2/s^3) on top of the scenario's: the bank learning its walk; returns the
    bank, its settings and the final true positions (R, 3)."""
    rng = np.random.default_rng(seed)
    sc = scenarios.orbit(duration_s=duration_s)
    t = np.arange(0.0, duration_s + 1e-9, dt)
    xs, v = sc.x(t), sc.v(t)
    walk = np.cumsum(rng.normal(0.0, math.sqrt(q_true * dt), (runs, len(t), 3)), axis=1)
    xt = xs[None] + np.cumsum(walk * dt, axis=1)
    y_true = xt / np.linalg.norm(xt, axis=-1, keepdims=True)
    y = perturb_bearings(y_true.reshape(-1, 3), math.radians(0.5), rng).reshape(runs, -1, 3)
    gross = rng.random(y.shape[:2]) < outliers  # 10 deg off (a tracker's false lock)
    y[gross] = perturb_bearings(y[gross], math.radians(10.0), rng)
    prm = riccati.BankParams(
        sigma_rad=math.radians(1.0),
        learn_noise=True,
        outlier_nis=13.816,
        learn_walk=True,
        **prm_kw,  # type: ignore[arg-type]
    )
    vv = np.broadcast_to(v, (runs, *v.shape))
    bank = _bank_run(y, vv, np.full(runs, float(np.linalg.norm(xs[0]))), prm, dt, walk_q0)
    return bank, prm, xt[:, -1]


def test_the_bias_walk_is_learnt_and_a_constant_bias_stays_constant() -> None:
    """A bias wandering at 0.01 m/s/sqrt(s): the walk learnt within a level (a factor 2 in
    m/s/sqrt(s)) in every run, the estimate consistent; a constant bias: nothing learnt,
    ``q_a`` exactly 0 as the paper's model."""
    bank, prm, xt = _walking_bias_run(1e-4, 31, 4)
    learnt = np.sqrt(bank.bias_walk(prm))
    assert np.all((learnt > 0.005) & (learnt < 0.02)), learnt
    x, _, p = riccati.bank_estimate(bank)
    err = x - xt
    nees = np.einsum("ri,rij,rj->r", err, np.linalg.inv(p[:, :3, :3]), err) / 3
    assert 0.3 < nees.mean() < 2.0, nees
    bank, prm, _ = _walking_bias_run(0.0, 32, 2)
    assert np.all(bank.bias_walk(prm) == 0.0)


def test_the_bias_walk_waits_while_held_and_leaving_zero_takes_the_leave_bar() -> None:
    """The same wandering bias: held off (``walk_hold_nats`` inf), no probe runs and
    nothing is learnt; held with the default bar, which this bias clears, it is learnt; with
    a bar to leave 0 no lead reaches, the walk stays 0."""
    off = {"walk_hold": True, "walk_hold_nats": math.inf}
    bank, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, **off)
    assert np.all(bank.bias_walk(prm) == 0.0) and not bank.walk_on.any()
    bank, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, walk_hold=True)
    assert np.all(bank.bias_walk(prm) > 0.0), bank.bias_walk(prm)
    bank, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, walk_leave_nats=1e9)
    assert np.all(bank.bias_walk(prm) == 0.0) and bank.walk_on.all()


def test_the_hold_guards_leaving_zero_only() -> None:
    """Held with a bar no lead reaches: from 0 the walk stays 0; from a level above 0 (a
    wandering bias already seen) it moves with the ordinary bar, up toward the truth."""
    never = {"walk_hold": True, "walk_hold_nats": 1e9}
    bank, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, **never)
    assert np.all(bank.bias_walk(prm) == 0.0) and bank.walk_on.all()
    bank, prm, _ = _walking_bias_run(1e-4, 31, 2, duration_s=120.0, walk_q0=1e-6, **never)
    assert np.all(bank.bias_walk(prm) >= 1.6e-5), bank.bias_walk(prm)


def test_a_bias_that_wanders_leaves_zero_by_the_jump_where_the_ladder_would_crawl() -> None:
    """A bias wandering at 0.018 m/s/sqrt(s) (the intensity of a 0.1 m/s Gauss-Markov error
    over 60 s), 70 s: from 0 the jump probe (``walk_jump``) leads and the walk leaves 0 to
    it in every run, the estimate consistent; without the jump the ladder from ``walk_min``
    climbs a factor 4 per move from levels the bearings can hardly tell from 0: every run
    still below the jump's level, and over-confident."""
    q_true = 3.3e-4

    def run(**kw: float) -> tuple[np.ndarray, float]:
        bank, prm, xt = _walking_bias_run(q_true, 35, 4, duration_s=70.0, **kw)
        x, _, p = riccati.bank_estimate(bank)
        err = x - xt
        nees = np.einsum("ri,rij,rj->r", err, np.linalg.inv(p[:, :3, :3]), err) / 3
        return bank.bias_walk(prm), float(nees.mean())

    jump = riccati.BankParams(sigma_rad=1.0).walk_jump
    q, nees = run()
    assert np.all(q >= jump) and nees < 2.0, (np.sqrt(q), nees)
    q, nees = run(walk_jump=0.0)
    assert np.all(q < 0.5 * jump) and nees > 3.0, (np.sqrt(q), nees)


def test_gross_bearing_errors_do_not_make_the_bias_walk() -> None:
    """10 % of bearings 10 deg off, a constant bias: they count for no probe (a filter with
    a wider covariance pays less for them), so nothing is learnt."""
    bank, prm, xt = _walking_bias_run(0.0, 34, 2, duration_s=180.0, outliers=0.1)
    assert np.all(bank.bias_walk(prm) == 0.0), np.sqrt(bank.bias_walk(prm))
    x, _, _ = riccati.bank_estimate(bank)
    assert np.all(np.linalg.norm(x - xt, axis=1) < 0.05 * np.linalg.norm(xt, axis=1))


def test_a_told_bias_walk_is_used_as_told_and_the_probes_follow_the_bank() -> None:
    """``learn_walk`` off: ``q_a`` as told and no probe runs (the same numbers as a bank
    that never had them); on: the probes are copies of the run's filter when they start."""
    rng = np.random.default_rng(33)
    xt, v, y = _orbit_bearings(rng, 2, 30.0, math.radians(0.5))
    r0 = np.full(2, float(np.linalg.norm(xt[0])))
    told = riccati.BankParams(sigma_rad=math.radians(0.5), q_a=3e-4)
    bank = _bank_run(y, v, r0, told, 0.05)
    assert np.allclose(bank.bias_walk(told), 3e-4)
    assert not bank.walk_on.any() and not bank.walk_x.any()
    learn = riccati.BankParams(sigma_rad=math.radians(0.5), learn_walk=True, walk_warmup_s=5.0)
    bank = riccati.bank_start(y[:, 0], r0, learn)
    for k in range(1, y.shape[1]):
        riccati.bank_predict(bank, 0.5 * (v[:, k - 1] + v[:, k]) * 0.05, 0.05, learn)
        riccati.bank_update(bank, y[:, k], 0.05, learn)
        started = bank.walk_on > 0.0
        if started.any() and not np.any(bank.walk_ll[started]):  # the bearing they start at
            for r in np.flatnonzero(started):
                i = int(np.flatnonzero(bank.owner == r)[0])
                assert np.array_equal(bank.walk_x[r, 0], bank.x[i])
                assert np.array_equal(bank.walk_p[r, 1], bank.p[i])
    assert bank.walk_on.all()
    assert np.allclose(riccati._walk_levels(np.array([0.0, 1e-4, 1e-6]), learn),
                       [[learn.walk_jump, learn.walk_min], [2.5e-5, 4e-4],
                        [0.0, 4e-6]])  # fmt: skip
    no_jump = replace(learn, walk_jump=0.0)
    assert np.allclose(riccati._walk_levels(np.array([0.0]), no_jump), [[0.0, no_jump.walk_min]])


def test_a_bearing_applied_to_a_position_alone_moves_it_across_the_bearing_only() -> None:
    """``position_update``: a position 1 m off across the bearing, uncertain by 1 m per axis,
    a bearing of 0.1 deg at 20 m: the position moves onto the bearing (the cross error falls
    from 1 m to under 5 cm), the along-bearing component and its variance do not move; a
    gross error with a robust threshold barely pulls."""
    x = np.array([20.0, 1.0, 0.0])  # the truth is [20, 0, 0]
    y = np.array([1.0, 0.0, 0.0])
    pxx = np.eye(3)
    sig2 = math.radians(0.1) ** 2
    x2, p2 = riccati.position_update(x, pxx, y, sig2, math.inf)
    assert abs(x2[1]) < 0.05 and abs(x2[2]) < 1e-12
    # (the along-bearing component moves only through the linearisation at the estimate)
    assert abs(x2[0] - 20.0) < 0.06
    assert p2[1, 1] < 0.01 and p2[0, 0] > 0.99
    np.testing.assert_allclose(p2, p2.T)
    # a position known to 10 cm and a bearing 17 deg off: the robust weight keeps it put,
    # the plain update does not
    x_t, tight = np.array([20.0, 0.0, 0.0]), 0.01 * np.eye(3)
    far = np.array([math.cos(0.3), math.sin(0.3), 0.0])
    x3, _ = riccati.position_update(x_t, tight, far, sig2, outlier_nis(2))
    assert np.linalg.norm(x3 - x_t) < 0.05
    x4, _ = riccati.position_update(x_t, tight, far, sig2, math.inf)
    assert np.linalg.norm(x4 - x_t) > 1.0


def test_the_walk_mixture_weighs_the_filter_and_its_probes_by_their_lead() -> None:
    """:func:`riccati.walk_mixture`: no probe running, the covariance is the filter's own
    (the same array); a probe leading by far, its covariance plus its offset from the
    filter's mean squared; no lead either way, the three weigh a third each; the estimate
    itself stays the filter's."""
    bank, _, _ = _walking_bias_run(3.3e-4, 36, 2, duration_s=60.0)
    assert np.all(bank.walk_on == 1.0)
    x, a, p = bank.x.copy(), bank.a.copy(), bank.p.copy()
    s0 = np.concatenate((x, a), axis=-1)
    sp = np.concatenate((bank.walk_x, bank.walk_a), axis=-1)
    d = sp - s0[:, None]
    probe = bank.walk_p + d[..., :, None] * d[..., None, :]  # (R, 2, 6, 6)
    bank.walk_ll[:] = [[-500.0, 500.0], [0.0, 0.0]]
    got = riccati.walk_mixture(bank, x, a, p)
    assert np.allclose(got[0], probe[0, 1], rtol=1e-9, atol=1e-15)
    assert np.allclose(got[1], (p[1] + probe[1, 0] + probe[1, 1]) / 3.0, rtol=1e-9)
    xe, ae, pe = riccati.bank_estimate(bank)
    assert np.array_equal(xe, x) and np.array_equal(ae, a) and np.allclose(pe, got)
    bank.walk_on[:] = 0.0
    assert riccati.walk_mixture(bank, x, a, p) is p


def test_weighing_the_walk_levels_makes_a_wandering_bias_honest() -> None:
    """A bias wandering as a 0.1 m/s Gauss-Markov error over 60 s does short-term (0.018
    m/s/sqrt(s)), its walk learnt: over the last third of 4 minutes, sampled each second, the
    published covariance (the levels weighed) puts the position's normalised error squared
    per axis nearer 1 than the filter's own covariance, which is over-confident with the
    level in use often one step below the truth."""
    rng = np.random.default_rng(37)
    runs, dt, duration = 12, 0.05, 240.0
    sc = scenarios.orbit(duration_s=duration)
    t = np.arange(0.0, duration + 1e-9, dt)
    xs, v = sc.x(t), sc.v(t)
    walk = np.cumsum(rng.normal(0.0, math.sqrt(3.3e-4 * dt), (runs, len(t), 3)), axis=1)
    xt = xs[None] + np.cumsum(walk * dt, axis=1)
    y_true = xt / np.linalg.norm(xt, axis=-1, keepdims=True)
    y = perturb_bearings(y_true.reshape(-1, 3), math.radians(0.5), rng).reshape(runs, -1, 3)
    prm = riccati.BankParams(
        sigma_rad=math.radians(1.0), learn_noise=True, outlier_nis=13.816, learn_walk=True
    )
    bank = riccati.bank_start(y[:, 0], np.full(runs, float(np.linalg.norm(xs[0]))), prm)
    own, mixed = [], []
    for k in range(1, len(t)):
        riccati.bank_predict(bank, (0.5 * (v[k - 1] + v[k]) * dt)[None].repeat(runs, 0), dt, prm)
        riccati.bank_update(bank, y[:, k], dt, prm)
        if t[k] > 2.0 * duration / 3.0 and k % 20 == 0:
            x, _, p = riccati.bank_estimate(bank)
            err = x - xt[:, k]
            for cov, out in ((bank.p, own), (p, mixed)):
                inv = np.linalg.inv(cov[:, :3, :3])
                out.append(np.einsum("ri,rij,rj->r", err, inv, err) / 3.0)
    nees_own, nees_mixed = float(np.mean(own)), float(np.mean(mixed))
    assert bank.walk_on.all() and np.all(bank.bias_walk(prm) > 0.0)
    assert nees_mixed < nees_own, (nees_mixed, nees_own)
    assert abs(math.log(nees_mixed)) < abs(math.log(nees_own)), (nees_mixed, nees_own)
