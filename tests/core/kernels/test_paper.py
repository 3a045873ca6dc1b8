"""The paper's observer's exact discrete steps (mav_observer/core/kernels/paper.py) against
independent integrations of its continuous equations, and the static hold."""

from __future__ import annotations

import math

import kernel_calls as kc
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer import BiasObserver, ObserverConfig
from sim.reference import _rhs


def _unit(rng: np.random.Generator, n: int = 3) -> np.ndarray:
    y = rng.normal(size=n)
    return y / np.linalg.norm(y)


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + np.eye(n)


def _rk4_first_filter(xh1, m, y, v, k, h, steps=4000):
    """``xh1' = v - k Pi_y xh1``, ``M' = I - k Pi_y M`` by fixed-step RK4."""
    pi = np.eye(len(y)) - np.outer(y, y)

    def f(x, mm):
        return v - k * pi @ x, np.eye(len(y)) - k * pi @ mm

    x, mm = xh1.copy(), m.copy()
    dt = h / steps
    for _ in range(steps):
        k1 = f(x, mm)
        k2 = f(x + 0.5 * dt * k1[0], mm + 0.5 * dt * k1[1])
        k3 = f(x + 0.5 * dt * k2[0], mm + 0.5 * dt * k2[1])
        k4 = f(x + dt * k3[0], mm + dt * k3[1])
        x = x + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        mm = mm + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return x, mm


def _rk4_paper_state(xh1, m, zs, y, v, k, ks, h, steps=2000):
    """The paper's state ``(xh1, M, zs)`` with ``y`` and ``v`` held, by RK4 of
    :func:`sim.reference._rhs` (independent of the kernels)."""
    dt = h / steps
    for _ in range(steps):
        k1 = _rhs(xh1, m, zs, y, v, k, ks)
        k2 = _rhs(xh1 + dt / 2 * k1[0], m + dt / 2 * k1[1], zs + dt / 2 * k1[2], y, v, k, ks)
        k3 = _rhs(xh1 + dt / 2 * k2[0], m + dt / 2 * k2[1], zs + dt / 2 * k2[2], y, v, k, ks)
        k4 = _rhs(xh1 + dt * k3[0], m + dt * k3[1], zs + dt * k3[2], y, v, k, ks)
        xh1 = xh1 + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        m = m + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        zs = zs + dt / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
    return xh1, m, zs


@pytest.mark.parametrize("n", [2, 3, 5])
def test_the_first_filter_step_is_exact_for_held_inputs(n: int) -> None:
    rng = np.random.default_rng(11 + n)
    y = _unit(rng, n)
    xh1, v = rng.normal(size=n) * 10, rng.normal(size=n)
    m = _spd(rng, n)
    got = kc.first_filter_step(xh1, m, y, v, 0.7, 1.3)
    ref = _rk4_first_filter(xh1, m, y, v, 0.7, 1.3)
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-10)


def test_the_first_filter_step_at_its_limits() -> None:
    """A vanishing gain is the prediction (``xh1 += h v``, ``M += h I``); a long step at a
    high gain leaves, across the bearing, the steady state ``Pi_y v / k`` and ``Pi_y / k``
    (``e^{-k h}`` underflows), along it the plain integral."""
    rng = np.random.default_rng(1)
    y, v = _unit(rng), rng.normal(size=3)
    xh1, m = rng.normal(size=3) * 10, _spd(rng, 3)
    x0, m0 = kc.first_filter_step(xh1, m, y, v, 1e-12, 2.5)
    np.testing.assert_allclose(x0, xh1 + 2.5 * v, rtol=1e-9)
    np.testing.assert_allclose(m0, m + 2.5 * np.eye(3), rtol=1e-9)
    k, h = 5.0, 1000.0
    x1, m1 = kc.first_filter_step(xh1, m, y, v, k, h)
    pi = np.eye(3) - np.outer(y, y)
    np.testing.assert_allclose(pi @ x1, pi @ v / k, atol=1e-12)
    assert y @ x1 == pytest.approx(y @ xh1 + h * (y @ v), rel=1e-12)
    np.testing.assert_allclose(pi @ m1 @ pi, pi / k, atol=1e-12)
    np.testing.assert_allclose(np.outer(y, y) @ m1, np.outer(y, y) @ (m + h * np.eye(3)))


def test_a_prediction_step_moves_the_estimate_with_v_plus_ahat() -> None:
    """Without a bearing: ``ahat`` unchanged, ``M += h I``, ``xhat = M ahat + xh1`` moves
    by ``h (v + ahat)``."""
    rng = np.random.default_rng(3)
    xh1, ahat, v = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    m = np.diag([2.0, 3.0, 4.0])
    x0 = kc.paper_estimate(xh1, m, ahat)
    np.testing.assert_allclose(x0, m @ ahat + xh1)
    xh1b, mb, ahatb = kc.substep(xh1, m, ahat, None, v, 0.5, 5.0, 7.0)
    assert np.array_equal(ahatb, ahat)
    np.testing.assert_allclose(mb, m + 7.0 * np.eye(3))
    np.testing.assert_allclose(kc.paper_estimate(xh1b, mb, ahatb), x0 + 7.0 * (v + ahat))


def test_the_paper_state_round_trips_through_the_configuration() -> None:
    """The configured ``(xh1, M, zs)`` become the observer's ``(xh1, M, ahat)``; the dual
    state ``zs = ahat + M^-1 xh1`` and ``xhat = M zs`` come back from it."""
    m = ((2.0, 0.3, 0.0), (0.3, 1.5, 0.2), (0.0, 0.2, 3.0))
    cfg = ObserverConfig.paper(xh1_0_m=(1.0, -2.0, 0.5), m_0_s=m, zs_0_mps=(0.3, 0.1, -0.4))
    xh1, mm, ahat = cfg.initial_state()
    np.testing.assert_allclose(kc.paper_zs(xh1, mm, ahat), [0.3, 0.1, -0.4], atol=1e-15)
    np.testing.assert_allclose(kc.paper_estimate(xh1, mm, ahat), mm @ [0.3, 0.1, -0.4])
    obs = BiasObserver(cfg)
    np.testing.assert_allclose(obs.zs_mps, [0.3, 0.1, -0.4], atol=1e-15)


def test_the_dual_stage_leaves_a_consistent_state_alone() -> None:
    """``zs`` along ``y*`` (``Pi_{y*} zs = 0``): nothing to correct, and ``xhat`` follows
    ``v + ahat = 0`` exactly (a fixed point at ``6 y``)."""
    y = np.array([0.0, 0.6, 0.8])
    m = np.eye(3) * 2.0
    xh1 = 4.0 * y
    ahat = 3.0 * y - xh1 / 2.0  # zs = 3 y, parallel to y* = y
    xh1b, mb, ahatb = kc.substep(xh1, m, ahat, y, -ahat, 0.5, 5.0, 0.01)
    np.testing.assert_allclose(ahatb, ahat, atol=1e-12)
    np.testing.assert_allclose(kc.paper_estimate(xh1b, mb, ahatb), 6.0 * y, atol=1e-12)


def test_the_bias_free_observer_leaves_ahat_at_zero() -> None:
    """Lemma 3.1 (``estimate_bias`` off): ``ahat`` stays 0 and the estimate is ``xh1``."""
    rng = np.random.default_rng(4)
    xh1, m = rng.normal(size=3) * 5, _spd(rng, 3)
    y, v = _unit(rng), rng.normal(size=3)
    xh1b, mb, ahatb = kc.substep(xh1, m, np.zeros(3), y, v, 0.5, 5.0, 0.3, estimate_bias=False)
    assert np.array_equal(ahatb, np.zeros(3))
    ref = kc.first_filter_step(xh1, m, y, v, 0.5, 0.3)
    assert np.array_equal(xh1b, ref[0]) and np.array_equal(mb, ref[1])


@settings(max_examples=60, deadline=None)
@given(
    log_h=st.floats(min_value=-4.0, max_value=math.log10(60.0)),
    k=st.floats(min_value=0.01, max_value=5.0),
    k_star=st.floats(min_value=0.01, max_value=5.0),
    seed=st.integers(min_value=0, max_value=2**32 - 1),
)
def test_any_step_is_stable(log_h: float, k: float, k_star: float, seed: int) -> None:
    """Steps from 1e-4 s to 60 s (k* h up to 300), in the sub-steps the observer takes:
    every number finite and bounded, ``M``'s growth within ``I t``."""
    rng = np.random.default_rng(seed)
    h = 10.0**log_h
    xh1, ahat = rng.normal(size=3) * 50, rng.normal(size=3) * 5
    m = np.eye(3)
    for _ in range(20):
        y, v = _unit(rng), rng.normal(size=3) * 5
        n_sub = kc.substep_count(k, k_star, h)
        for _ in range(n_sub):
            xh1, m, ahat = kc.substep(xh1, m, ahat, y, v, k, k_star, h / n_sub)
        assert np.all(np.isfinite(xh1)) and np.all(np.isfinite(m)) and np.all(np.isfinite(ahat))
    assert np.linalg.norm(m, 2) <= 1.0 + 20 * h + 1e-9
    assert np.linalg.norm(ahat) < 1e4


def test_substep_count_grows_with_gain_and_length_and_is_capped() -> None:
    assert kc.substep_count(0.2, 0.2, 0.05) == 1
    assert kc.substep_count(0.5, 5.0, 0.05) == 4  # k* h / 0.0625
    assert kc.substep_count(0.2, 0.2, 0.35) == 4  # at most 0.1 s each
    assert kc.substep_count(0.5, 5.0, 60.0) == 64  # (the cap)
    assert kc.substep_count(0.0, 0.0, 0.0) == 1


def _held_at_start(xh1, m, zs, y, v, k, ks, h, n):
    """The simple alternative: ``y*`` and ``M^-1 (v - M^-1 xh1)`` held at their values at
    the start of each sub-step (``zs`` then integrated exactly)."""
    hs = h / n
    for _ in range(n):
        sol = np.linalg.solve(m, np.array((y, xh1)).T)
        ys = sol[:, 0] / np.linalg.norm(sol[:, 0])
        vs = np.linalg.solve(m, v - sol[:, 1])
        e, g = math.exp(-ks * hs), -math.expm1(-ks * hs) / ks
        p = np.outer(ys, ys)
        zs = (p + e * (np.eye(3) - p)) @ zs + (hs * p + g * (np.eye(3) - p)) @ vs
        xh1, m = kc.first_filter_step(xh1, m, y, v, k, hs)
    return xh1, m, zs


@pytest.mark.parametrize(
    ("h", "k", "ks"), [(0.05, 0.5, 5.0), (0.25, 0.5, 5.0), (1.0, 0.2, 0.2), (5.0, 0.2, 0.2)]
)
def test_the_dual_stage_against_rk4_of_the_continuous_equations(
    h: float, k: float, ks: float
) -> None:
    """The dual stage is not closed-form, but in the sub-steps the observer takes it stays
    within 1e-3 of a fine RK4 of the paper's equations with the inputs held (the first
    filter and ``M`` exact), and at least 10 times closer than holding ``y*`` and ``v*`` at
    their start-of-step values."""
    rng = np.random.default_rng(int(h * 1000 + ks * 10))
    y, v = _unit(rng), rng.normal(size=3)
    xh1, ahat = rng.normal(size=3) * 10, rng.normal(size=3)
    m = _spd(rng, 3)
    zs = kc.paper_zs(xh1, m, ahat)
    n = kc.substep_count(k, ks, h)
    x1, m1, a1 = xh1, m, ahat
    for _ in range(n):
        x1, m1, a1 = kc.substep(x1, m1, a1, y, v, k, ks, h / n)
    xr, mr, zr = _rk4_paper_state(xh1, m, zs, y, v, k, ks, h)
    ours = np.linalg.norm(kc.paper_estimate(x1, m1, a1) - mr @ zr)
    np.testing.assert_allclose(x1, xr, atol=1e-10)
    np.testing.assert_allclose(m1, mr, atol=1e-10)
    assert ours < 1e-3
    assert np.linalg.norm(a1 - (zr - np.linalg.solve(mr, xr))) < 1e-3
    _, mh, zh = _held_at_start(xh1, m, zs, y, v, k, ks, h, n)
    assert ours * 10 < np.linalg.norm(mh @ zh - mr @ zr)


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_solve_pair_matches_numpy(n: int) -> None:
    """Closed form for n = 2 and 3, Gauss-Jordan with pivoting above."""
    rng = np.random.default_rng(n)
    for _ in range(20):
        a = rng.normal(size=(n, n)) + n * np.eye(n)
        b0, b1 = rng.normal(size=n), rng.normal(size=n)
        x0, x1 = kc.solve_pair(a, b0, b1)
        ref = np.linalg.solve(a, np.column_stack((b0, b1)))
        np.testing.assert_allclose(x0, ref[:, 0], atol=1e-12)
        np.testing.assert_allclose(x1, ref[:, 1], atol=1e-12)


def test_the_static_test_needs_a_still_relative_velocity_and_a_bearing_on_the_estimate() -> None:
    """Static: ``|v + ahat|`` at most the hold speed and the bearing within the hold angle
    of the estimate's direction; not with no estimate (at the origin)."""
    m = np.eye(3)
    xh1 = np.array([10.0, 0.0, 0.0])
    ahat = np.array([0.5, 0.0, 0.0])
    y = np.array([1.0, 0.0, 0.0])
    v_still = np.array([-0.5, 0.03, 0.0])  # |v + ahat| = 0.03
    xhat = kc.paper_estimate(xh1, m, ahat)  # 10.5 along x
    assert xhat[0] == pytest.approx(10.5)
    assert kc.is_static(xh1, m, ahat, v_still, y, 0.05, 3.0)
    assert not kc.is_static(xh1, m, ahat, v_still + np.array([0.0, 0.03, 0.0]), y, 0.05, 3.0)
    ang = math.radians(2.9)
    assert kc.is_static(xh1, m, ahat, v_still, [math.cos(ang), math.sin(ang), 0.0], 0.05, 3.0)
    ang = math.radians(3.1)
    assert not kc.is_static(xh1, m, ahat, v_still, [math.cos(ang), 0.0, math.sin(ang)], 0.05, 3.0)
    assert not kc.is_static(np.zeros(3), m, np.zeros(3), -np.zeros(3), y, 0.05, 3.0)


def test_the_static_hold_keeps_a_hovering_observer_as_it_was() -> None:
    """Hovering on the estimate's bearing (``v + ahat = 0``): with the hold the state stays
    exactly as it was for a minute (``M`` does not grow along the bearing); without it (the
    paper's equations) ``M`` grows by the time along it; a bearing off the estimate by more
    than the hold angle is integrated."""
    y = [0.6, 0.0, 0.8]

    def hover(static_hold: bool, y_later) -> BiasObserver:
        obs = BiasObserver(ObserverConfig.paper(initial_range_m=10.0, static_hold=static_hold))
        for k in range(1201):
            t = 0.05 * k
            obs.update_velocity_values(t, [0.0, 0.0, 0.0])
            obs.update_bearing_values(t, y if k == 0 else y_later)
        return obs

    held = hover(True, y)
    assert held.committed_t_s == pytest.approx(60.0)
    np.testing.assert_array_equal(held.xh1_m, [6.0, 0.0, 8.0])
    np.testing.assert_array_equal(held.m_s, np.eye(3))
    np.testing.assert_array_equal(held.a_mps, np.zeros(3))
    free = hover(False, y)
    assert np.array(y) @ free.m_s @ np.array(y) == pytest.approx(61.0, rel=1e-9)
    np.testing.assert_allclose(free.x_m, [6.0, 0.0, 8.0], atol=1e-9)  # (the fixed point)
    ang = math.radians(5.0)
    off = [
        0.6 * math.cos(ang) - 0.8 * math.sin(ang),
        0.0,
        0.8 * math.cos(ang) + 0.6 * math.sin(ang),
    ]
    moved = hover(True, off)
    assert np.array(off) @ moved.m_s @ np.array(off) > 2.0
    x = np.array(moved.x_m)
    assert math.degrees(math.acos(x @ off / np.linalg.norm(x))) < 3.0  # turned onto it
