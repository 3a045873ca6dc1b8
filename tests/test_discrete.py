"""The closed-form discrete steps against independent integrations."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer import discrete


class D:
    """numpy view of the list-based maths: vectors as arrays, M as an n x n array."""

    @staticmethod
    def _m(m):
        return np.asarray(m, dtype=float).ravel().tolist()

    @staticmethod
    def _back(m_flat, n):
        return np.array(m_flat).reshape(n, n)

    @classmethod
    def first_filter_step(cls, xh1, m, y, v, k, h):
        x, mm = discrete.first_filter_step(
            list(xh1), cls._m(m), None if y is None else list(y), list(v), k, h
        )
        return np.array(x), cls._back(mm, len(x))

    @classmethod
    def substep(cls, xh1, m, ahat, y, v, k, ks, h, **kw):
        x, mm, a = discrete.substep(
            list(xh1),
            cls._m(m),
            list(ahat),
            None if y is None else list(y),
            list(v),
            k,
            ks,
            h,
            **kw,
        )
        return np.array(x), cls._back(mm, len(x)), np.array(a)

    @classmethod
    def estimate_from_state(cls, ahat, xh1, m):
        return np.array(discrete.estimate_from_state(list(ahat), list(xh1), cls._m(m)))

    @classmethod
    def zs_from_state(cls, ahat, xh1, m):
        return np.array(discrete.zs_from_state(list(ahat), list(xh1), cls._m(m)))

    @classmethod
    def ahat_from_paper_state(cls, xh1, m, zs):
        return np.array(discrete.ahat_from_paper_state(list(xh1), cls._m(m), list(zs)))


def _unit(rng: np.random.Generator, n: int = 3) -> np.ndarray:
    y = rng.normal(size=n)
    return y / np.linalg.norm(y)


def _rk4_first_filter(xh1, m, y, v, k, h, steps=4000):
    pi = np.eye(len(y)) - np.outer(y, y)

    def f(state):
        x, mm = state
        return v - k * pi @ x, np.eye(len(y)) - k * pi @ mm

    x, mm = xh1.copy(), m.copy()
    dt = h / steps
    for _ in range(steps):
        k1 = f((x, mm))
        k2 = f((x + 0.5 * dt * k1[0], mm + 0.5 * dt * k1[1]))
        k3 = f((x + 0.5 * dt * k2[0], mm + 0.5 * dt * k2[1]))
        k4 = f((x + dt * k3[0], mm + dt * k3[1]))
        x = x + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        mm = mm + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    return x, mm


def test_decay_terms_limits() -> None:
    assert discrete.decay_terms(0.0, 2.5) == (1.0, 2.5)
    e, g = discrete.decay_terms(1e-12, 2.0)
    assert abs(g - 2.0) < 1e-9 and abs(e - 1.0) < 1e-9
    e, g = discrete.decay_terms(5.0, 1000.0)
    assert e == 0.0 and g == pytest.approx(0.2)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_first_filter_step_is_exact_for_held_inputs(n: int) -> None:
    rng = np.random.default_rng(11 + n)
    y = _unit(rng, n)
    xh1, v = rng.normal(size=n) * 10, rng.normal(size=n)
    a = rng.normal(size=(n, n))
    m = a @ a.T + np.eye(n)
    got = D.first_filter_step(xh1, m, y, v, 0.7, 1.3)
    ref = _rk4_first_filter(xh1, m, y, v, 0.7, 1.3)
    assert np.allclose(got[0], ref[0], rtol=0, atol=1e-10)
    assert np.allclose(got[1], ref[1], rtol=0, atol=1e-10)


def test_prediction_step_moves_estimate_with_v_plus_ahat() -> None:
    rng = np.random.default_rng(3)
    xh1, ahat, v = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
    m = np.diag([2.0, 3.0, 4.0])
    x0 = D.estimate_from_state(ahat, xh1, m)
    xh1b, mb, ahatb = D.substep(xh1, m, ahat, None, v, 0.5, 5.0, 7.0)
    assert np.array_equal(ahatb, ahat)
    assert np.allclose(mb, m + 7.0 * np.eye(3))
    assert np.allclose(D.estimate_from_state(ahatb, xh1b, mb), x0 + 7.0 * (v + ahat))


def test_paper_state_round_trip() -> None:
    rng = np.random.default_rng(5)
    xh1, zs = rng.normal(size=3), rng.normal(size=3)
    m = np.array([[2.0, 0.3, 0.0], [0.1, 1.5, 0.2], [0.0, 0.4, 3.0]])
    ahat = D.ahat_from_paper_state(xh1, m, zs)
    assert np.allclose(D.zs_from_state(ahat, xh1, m), zs)
    assert np.allclose(D.estimate_from_state(ahat, xh1, m), m @ zs)


def test_dual_stage_leaves_a_consistent_state_alone() -> None:
    # zs along y* => Pi_{y*} zs = 0: nothing to correct, and xhat follows v + ahat exactly
    y = np.array([0.0, 0.6, 0.8])
    m = np.eye(3) * 2.0
    xh1 = 4.0 * y
    ahat = 3.0 * y - xh1 / 2.0  # zs = ahat + M^-1 xh1 = 3 y, parallel to y* = y
    v = -ahat  # v + ahat = 0: the estimate is a fixed point (xhat = 6 y, static)
    xh1b, mb, ahatb = D.substep(xh1, m, ahat, y, v, 0.5, 5.0, 0.01)
    assert np.allclose(ahatb, ahat, atol=1e-12)
    assert np.allclose(D.estimate_from_state(ahatb, xh1b, mb), 6.0 * y, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    log_h=st.floats(min_value=-4.0, max_value=math.log10(60.0)),
    k=st.floats(min_value=0.01, max_value=5.0),
    k_star=st.floats(min_value=0.01, max_value=5.0),
    seed=st.integers(min_value=0, max_value=2**32 - 1),
)
def test_any_step_is_stable(log_h: float, k: float, k_star: float, seed: int) -> None:
    """Steps from 1e-4 s to 60 s (k* h up to 300) keep every number finite and bounded."""
    rng = np.random.default_rng(seed)
    h = 10.0**log_h
    xh1, ahat = rng.normal(size=3) * 50, rng.normal(size=3) * 5
    m = np.eye(3)
    for _ in range(20):
        y, v = _unit(rng), rng.normal(size=3) * 5
        n_sub = discrete.substep_count(k, k_star, h)
        for _ in range(n_sub):
            xh1, m, ahat = D.substep(xh1, m, ahat, y, v, k, k_star, h / n_sub)
        assert np.all(np.isfinite(xh1)) and np.all(np.isfinite(m)) and np.all(np.isfinite(ahat))
    # M's growth is bounded by I t (and its transverse part by 1/k)
    assert np.linalg.norm(m, 2) <= 1.0 + 20 * h + 1e-9
    assert np.linalg.norm(ahat) < 1e4


def test_substep_count_grows_with_gain_and_is_capped() -> None:
    assert discrete.substep_count(0.2, 0.2, 0.05) == 1
    assert discrete.substep_count(0.5, 5.0, 0.05) == 4
    assert discrete.substep_count(0.5, 5.0, 60.0) == discrete.MAX_SUBSTEPS


def _rk4_paper_state(xh1, m, zs, y, v, k, ks, h, steps=2000):
    from sim.reference import _rhs

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


def _held_at_start(xh1, m, zs, y, v, k, ks, h, n):
    """The simple alternative: y* and v* held at their start-of-step values."""
    hs = h / n
    for _ in range(n):
        sol = np.linalg.solve(m, np.array((y, xh1)).T)
        ys = sol[:, 0] / np.linalg.norm(sol[:, 0])
        vs = np.linalg.solve(m, v - sol[:, 1])
        e, g = discrete.decay_terms(ks, hs)
        p = np.outer(ys, ys)
        zs = (p + e * (np.eye(3) - p)) @ zs + (hs * p + g * (np.eye(3) - p)) @ vs
        xh1, m = D.first_filter_step(xh1, m, y, v, k, hs)
    return xh1, m, zs


@pytest.mark.parametrize(
    ("h", "k", "ks"), [(0.05, 0.5, 5.0), (0.25, 0.5, 5.0), (1.0, 0.2, 0.2), (5.0, 0.2, 0.2)]
)
def test_dual_stage_with_held_inputs_against_rk4(h: float, k: float, ks: float) -> None:
    """The dual stage is not closed-form, but with the sub-step rule it stays within 1e-3 of a
    fine RK4 of the same held-input equations, and at least 10 times closer than holding y*
    and v* at their start-of-step values."""
    rng = np.random.default_rng(int(h * 1000 + ks * 10))
    y, v = _unit(rng), rng.normal(size=3)
    xh1, ahat = rng.normal(size=3) * 10, rng.normal(size=3)
    a = rng.normal(size=(3, 3))
    m = a @ a.T + np.eye(3)
    zs = D.zs_from_state(ahat, xh1, m)
    n = discrete.substep_count(k, ks, h)
    x1, m1, a1 = xh1, m, ahat
    for _ in range(n):
        x1, m1, a1 = D.substep(x1, m1, a1, y, v, k, ks, h / n)
    xr, mr, zr = _rk4_paper_state(xh1, m, zs, y, v, k, ks, h)
    ours = np.linalg.norm(D.estimate_from_state(a1, x1, m1) - mr @ zr)
    assert np.allclose(x1, xr, atol=1e-10) and np.allclose(m1, mr, atol=1e-10)  # exact part
    assert ours < 1e-3
    assert np.linalg.norm(a1 - D.ahat_from_paper_state(xr, mr, zr)) < 1e-3
    _, mh, zh = _held_at_start(xh1, m, zs, y, v, k, ks, h, n)
    assert ours * 10 < np.linalg.norm(mh @ zh - mr @ zr)


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_closed_form_solve_matches_gauss_jordan_and_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(20):
        a = rng.normal(size=(n, n)) + n * np.eye(n)
        b0, b1 = rng.normal(size=n), rng.normal(size=n)
        x0, x1 = discrete.solve2(a.ravel().tolist(), b0.tolist(), b1.tolist())
        g0, g1 = discrete._solve2_generic(a.ravel().tolist(), b0.tolist(), b1.tolist())
        ref = np.linalg.solve(a, np.column_stack((b0, b1)))
        assert np.allclose(x0, ref[:, 0], atol=1e-12) and np.allclose(x1, ref[:, 1], atol=1e-12)
        assert np.allclose(g0, ref[:, 0], atol=1e-12) and np.allclose(g1, ref[:, 1], atol=1e-12)


def test_unrolled_first_filter_equals_the_generic_one() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        y = _unit(rng)
        xh1, v = rng.normal(size=3) * 10, rng.normal(size=3)
        m = rng.normal(size=(3, 3))
        k, h = rng.uniform(0.01, 5), rng.uniform(1e-4, 10)
        fast = discrete.first_filter_step(
            xh1.tolist(), m.ravel().tolist(), y.tolist(), v.tolist(), k, h
        )
        e, g = discrete.decay_terms(k, h)
        slow = discrete._first_filter_generic(
            xh1.tolist(), m.ravel().tolist(), y.tolist(), v.tolist(), e, g, 1 - e, h - g
        )
        assert np.allclose(fast[0], slow[0], rtol=1e-13, atol=1e-12)
        assert np.allclose(fast[1], slow[1], rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 5])
def test_symmetric_eigenvalues_and_condition_number_match_numpy(n: int) -> None:
    rng = np.random.default_rng(10 + n)
    for scale in (1e-3, 1.0, 1e3):
        a = rng.normal(size=(n, n)) * scale
        sym = a + a.T
        assert np.allclose(
            discrete.sym_eigvals(sym.ravel().tolist(), n),
            np.linalg.eigvalsh(sym),
            rtol=1e-9,
            atol=1e-9 * scale,
        )
        m = a + 2 * scale * np.eye(n)
        assert discrete.cond2(m.ravel().tolist(), n) == pytest.approx(np.linalg.cond(m), rel=1e-7)
    diag = np.diag(np.arange(1.0, n + 1.0))
    assert discrete.sym_eigvals(diag.ravel().tolist(), n) == pytest.approx(list(range(1, n + 1)))
    ill = np.diag([1e-7] + [1.0] * (n - 1))  # beyond the closed form's precision: SVD fallback
    assert discrete.cond2(ill.ravel().tolist(), n) == pytest.approx(1e7, rel=1e-9)
