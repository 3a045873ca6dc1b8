"""The single-filter float path (mav_observer.single) against the numpy bank it repeats."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer import riccati, single
from mav_observer.config import ObserverConfig


def _random_filter(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = rng.normal(size=3) * rng.uniform(1.0, 100.0)
    a = rng.normal(size=3)
    m = rng.normal(size=(6, 6))
    return x, a, m @ m.T + 0.1 * np.eye(6)


@pytest.mark.parametrize("tracking", [True, False])
@pytest.mark.parametrize("outlier_nis", [math.inf, 9.0, 0.5])
def test_one_update_equals_the_batched_update(tracking: bool, outlier_nis: float) -> None:
    rng = np.random.default_rng(1)
    weights = []
    for trial in range(200):
        x, a, p = _random_filter(rng)
        y = x / np.linalg.norm(x) + rng.normal(size=3) * (0.01 if trial % 2 else 1.0)
        y /= np.linalg.norm(y)
        sig2 = rng.uniform(1e-6, 1e-2)
        r_w = rng.uniform(1.0, 50.0)
        ref = riccati.update_robust(
            x[None], a[None], p[None], y[None], sig2, tracking, r_w, r_w, outlier_nis
        )
        got = single.update_one(
            x.tolist(), a.tolist(), p.ravel().tolist(), y.tolist(), sig2, tracking, r_w, outlier_nis
        )
        want = (
            ref.x[0], ref.a[0], ref.p[0].ravel(), ref.nis[0], ref.logdet[0], ref.weight[0],
            ref.noise_stat[0],
        )  # fmt: skip
        for name, g, w in zip(
            ("x", "a", "p", "nis", "logdet", "weight", "stat"), got, want, strict=True
        ):
            assert np.allclose(g, w, rtol=1e-9, atol=1e-12), (trial, name, g, w)
        weights.append(got[5])
    if math.isfinite(outlier_nis):  # the robust branch was exercised
        assert min(weights) < 1.0


def test_one_prediction_equals_the_batched_prediction() -> None:
    rng = np.random.default_rng(2)
    for _ in range(200):
        x, a, p = _random_filter(rng)
        dx = rng.normal(size=3)
        h, q_x, q_a = rng.uniform(0.0, 0.5), rng.uniform(0.0, 1e-3), rng.uniform(0.0, 1e-2)
        want = riccati.predict(x[None], a[None], p[None], dx[None], h, q_x, q_a)
        got = single.predict_one(
            x.tolist(), a.tolist(), p.ravel().tolist(), dx.tolist(), h, q_x, q_a
        )
        for g, w in zip(got, want, strict=True):
            assert np.allclose(g, w[0].ravel(), rtol=1e-12, atol=1e-12)


def _stream(seed: int, seconds: float) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """``(h_s, v_mps, y)`` at 20 Hz: an orbit of 40 m around a target, a bias wandering
    0.01 m/s per root second, bearings with 0.5 deg noise, 5 % of them 5-30 deg off, and
    the target jumping 60 m at two thirds of the span (a re-acquisition)."""
    rng = np.random.default_rng(seed)
    h = 0.05
    target = np.array([0.0, 0.0, 10.0])
    bias = np.zeros(3)
    out = []
    for i in range(int(seconds / h)):
        t = i * h
        if abs(t - 2.0 * seconds / 3.0) < h / 2:
            target = target + np.array([60.0, 0.0, 0.0])
        w = 2.0 * math.pi / 40.0
        pos = np.array([40.0 * math.cos(w * t), 40.0 * math.sin(w * t), -5.0 * math.sin(w * t)])
        vel = np.array(
            [-40.0 * w * math.sin(w * t), 40.0 * w * math.cos(w * t), -5.0 * w * math.cos(w * t)]
        )
        bias = bias + rng.normal(size=3) * 0.01 * math.sqrt(h)
        x = target - pos
        y = x / np.linalg.norm(x)
        sig = math.radians(0.5) if rng.uniform() > 0.05 else math.radians(rng.uniform(5.0, 30.0))
        y = y + rng.normal(size=3) * sig
        out.append((h, -vel - bias, y / np.linalg.norm(y)))
    return out


def test_the_float_path_equals_the_bank_on_a_whole_stream() -> None:
    """Every estimate of a run on the float path equals the numpy bank's, and so do its
    weights, counts and learnt levels: through acquisition (seven hypotheses pruned and
    merged), the bias's random walk learnt (its level moved), the noise learnt, gross errors
    and a re-acquisition (re-seeded by the bank's own code on the converted run)."""
    prm = ObserverConfig().bank_params(0.05)
    assert prm.learn_walk and prm.learn_noise and math.isfinite(prm.outlier_nis)
    data = _stream(3, 180.0)
    y0 = data[0][2]
    ref = riccati.bank_start(y0[None], np.array([30.0]), prm)
    one = single.from_bank(riccati.copy_bank(ref))
    used = {"filters": set(), "levels": set(), "reseeds": 0}
    for h, v, y in data[1:]:
        riccati.bank_predict(ref, (v * h)[None], h, prm)
        riccati.bank_update(ref, y[None], h, prm)
        single.predict(one, (v * h).tolist(), h, prm, prm.q_x)
        if single.update(one, y.tolist(), h, prm):
            bank = single.to_bank(one)
            riccati.reseed(bank, np.array([True]), y[None], prm)
            one = single.from_bank(bank)
        got = single.to_bank(one)
        assert len(got.owner) == len(ref.owner)
        xr, ar, pr = riccati.bank_estimate(ref)
        xg, ag, pg = riccati.bank_estimate(got)
        assert np.allclose(xg, xr, rtol=1e-7, atol=1e-9)
        assert np.allclose(ag, ar, rtol=1e-7, atol=1e-9)
        assert np.allclose(pg, pr, rtol=1e-6, atol=1e-12)
        x1, a1, p1 = one.estimate()  # the float mixture, as the estimator publishes it
        assert np.allclose(x1, xr[0], rtol=1e-7, atol=1e-9)
        assert np.allclose(a1, ar[0], rtol=1e-7, atol=1e-9)
        assert np.allclose(np.reshape(p1, (6, 6)), pr[0], rtol=1e-6, atol=1e-12)
        assert np.allclose(got.logw, ref.logw, atol=1e-9)
        for name in ("walk_q", "walk_on", "reseeds", "outliers", "bearings"):
            assert np.array_equal(getattr(got, name), getattr(ref, name)), name
        for name in ("nis_avg", "noise_alpha", "noise_beta", "inlier_avg", "walk_ll"):
            assert np.allclose(getattr(got, name), getattr(ref, name), rtol=1e-7, atol=1e-9)
        used["filters"].add(len(ref.owner))
        used["levels"].add(float(ref.walk_q[0]))
        used["reseeds"] = int(ref.reseeds[0])
    # the stream exercised what it is meant to
    assert {1, 7} <= used["filters"] and len(used["filters"]) >= 3, used
    assert len(used["levels"]) >= 2, used
    assert used["reseeds"] >= 1
    assert int(ref.outliers[0]) > 50


def test_a_shift_moves_the_probes_too() -> None:
    prm = ObserverConfig().bank_params(0.05)
    data = _stream(4, 60.0)
    bank = riccati.bank_start(data[0][2][None], np.array([40.0]), prm)
    for h, v, y in data[1:]:
        riccati.bank_predict(bank, (v * h)[None], h, prm)
        riccati.bank_update(bank, y[None], h, prm)
    assert single.applies(bank) and len(bank.owner) == 1 and bank.walk_on[0] == 1.0
    one = single.from_bank(bank)
    before = one.copy()
    one.shift([1.0, -2.0, 0.5])
    for got, was in (
        (one.x[0], before.x[0]),
        (one.xp, before.xp),
        *zip(one.walk_x, before.walk_x, strict=True),
    ):
        assert np.allclose(np.subtract(got, was), [1.0, -2.0, 0.5])
    assert one.a == before.a


_finite = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(_finite, min_size=36, max_size=36),
    st.lists(_finite, min_size=3, max_size=3).filter(lambda v: sum(c * c for c in v) > 1e-3),
    st.floats(min_value=1.0, max_value=500.0),
    st.floats(min_value=1e-7, max_value=1e-2),
    st.booleans(),
)
def test_one_update_keeps_the_covariance_symmetric_and_shrinks_it(
    m: list[float], u: list[float], range_m: float, sig2: float, tracking: bool
) -> None:
    """For any positive definite covariance, bearing and noise: the updated covariance is
    exactly symmetric, positive definite, and no larger than before (P - P+ positive
    semi-definite), as a Kalman update must leave it."""
    a_ = np.reshape(m, (6, 6))
    p = a_ @ a_.T + 0.01 * np.eye(6)
    d = np.array(u) / np.linalg.norm(u)
    x = (range_m * d).tolist()
    y = d.tolist()
    _, _, p2, nis, _, weight, _ = single.update_one(
        x, [0.0, 0.0, 0.0], p.ravel().tolist(), y, sig2, tracking, range_m, 9.0
    )
    p2 = np.reshape(p2, (6, 6))
    assert np.array_equal(p2, p2.T)
    assert np.linalg.eigvalsh(p2).min() > -1e-9 * np.abs(p).max()
    assert np.linalg.eigvalsh(p - p2).min() > -1e-9 * np.abs(p).max()
    assert nis >= 0.0 and 0.0 < weight <= 1.0


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_the_float_mahalanobis_distance_is_numpys(seed: int) -> None:
    """The merge's distance on the floats (a Cholesky factorisation) equals numpy's solve to
    rounding, and says ``None`` for a matrix that is not positive definite."""
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(6, 6))
    a = m @ m.T + 1e-3 * np.eye(6)
    d = rng.normal(size=6)
    got = single.mahalanobis2(d.tolist(), a.ravel().tolist())
    assert got == pytest.approx(float(d @ np.linalg.solve(a, d)), rel=1e-8)
    # the merge's shortcuts are lower bounds: the position block's distance, |d|^2 / trace
    block = single.mahalanobis2(d[:3].tolist(), a[:3, :3].ravel().tolist(), 3)
    assert block is not None and block <= got * (1 + 1e-9)
    assert float(d @ d) / float(np.trace(a)) <= got * (1 + 1e-9)
    # stopped once past a bar: over the bar, and not over the whole distance
    part = single.mahalanobis2(d.tolist(), a.ravel().tolist(), over=0.5 * got)
    assert part is not None and 0.5 * got < part <= got * (1 + 1e-9)
    assert single.mahalanobis2(d.tolist(), a.ravel().tolist(), over=2.0 * got) == got
    a[0, 0] = -1.0
    assert single.mahalanobis2(d.tolist(), a.ravel().tolist()) is None
