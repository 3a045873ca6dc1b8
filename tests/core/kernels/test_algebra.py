"""The compiled core's small linear algebra (mav_observer/core/kernels/algebra.py) against
numpy: eigenvalues, condition number, inverse and log-determinant, the tangent basis, the
pivoting solve, the Mahalanobis distance."""

from __future__ import annotations

import kernel_calls as kc
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _rotation(rng: np.random.Generator, n: int) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return q


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_symmetric_eigenvalues_match_numpy(n: int) -> None:
    """Closed form for n = 2 and 3, Jacobi above: ascending, to 1e-9 of the scale, on random
    symmetric matrices of three scales, a diagonal one (3: no off-diagonal term) and one with
    a repeated eigenvalue."""
    rng = np.random.default_rng(10 + n)
    for scale in (1e-3, 1.0, 1e3):
        for _ in range(10):
            a = rng.normal(size=(n, n)) * scale
            sym = a + a.T
            got = kc.sym_eigvals(sym)
            np.testing.assert_allclose(got, np.linalg.eigvalsh(sym), rtol=1e-9, atol=1e-9 * scale)
    diag = np.diag(np.arange(n, 0.0, -1.0))
    np.testing.assert_allclose(kc.sym_eigvals(diag), np.arange(1.0, n + 1.0), rtol=1e-12)
    q = _rotation(rng, n)
    rep = q @ np.diag([2.0] * (n - 1) + [5.0]) @ q.T
    np.testing.assert_allclose(kc.sym_eigvals(rep), [2.0] * (n - 1) + [5.0], atol=1e-9)


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_condition_number_matches_numpy_including_an_ill_conditioned_matrix(n: int) -> None:
    """From the eigenvalues of M^T M where that is precise; beyond 1e10 between them, from
    singular values (one-sided Jacobi): still numpy's, on a diagonal and a rotated matrix of
    condition 1e7 and 3e8; inf for a singular one."""
    rng = np.random.default_rng(20 + n)
    for scale in (1e-3, 1.0, 1e3):
        for _ in range(10):
            m = rng.normal(size=(n, n)) * scale + 2.0 * scale * np.eye(n)
            assert kc.cond2(m) == pytest.approx(np.linalg.cond(m), rel=1e-7)
    ill = np.diag([1e-7] + [1.0] * (n - 1))
    assert kc.cond2(ill) == pytest.approx(1e7, rel=1e-9)
    u, v = _rotation(rng, n), _rotation(rng, n)
    rotated = u @ np.diag([3e-8, *np.linspace(9.0, 1.0, n - 1)]) @ v.T
    want = np.linalg.cond(rotated)
    assert want > 1e8
    assert kc.cond2(rotated) == pytest.approx(want, rel=1e-5)
    assert kc.cond2(np.diag([0.0] + [1.0] * (n - 1))) == np.inf


@pytest.mark.parametrize("n", [1, 2, 3, 4, 6])
def test_spd_inverse_and_its_log_determinant(n: int) -> None:
    """Closed form for 1x1 and 2x2 (the bearing's innovation in 2-D and 3-D), Cholesky
    above: numpy's inverse and log-determinant; NaN for a matrix not positive definite."""
    rng = np.random.default_rng(30 + n)
    for scale in (1e-6, 1.0, 1e4):
        g = rng.normal(size=(n, n))
        a = (g @ g.T + 0.1 * np.eye(n)) * scale
        inv, logdet = kc.spd_inverse(a)
        np.testing.assert_allclose(inv, np.linalg.inv(a), rtol=1e-9)
        sign, want = np.linalg.slogdet(a)
        assert sign == 1.0 and logdet == pytest.approx(want, rel=1e-10, abs=1e-10)
    bad = np.eye(n)
    bad[-1, -1] = -1.0
    assert np.isnan(kc.spd_inverse(bad)[1])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 6))
def test_tangent_basis_is_orthonormal_and_orthogonal_to_the_direction(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    directions = [_unit(rng, n) for _ in range(3)] + [np.eye(n)[0], -np.eye(n)[0]]
    for d in directions:  # (the reflection's own axis, both signs, too)
        e = kc.tangent_basis(d)
        assert e.shape == (n, n - 1)
        np.testing.assert_allclose(e.T @ e, np.eye(n - 1), atol=1e-12)
        np.testing.assert_allclose(d @ e, 0.0, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_solve_with_partial_pivoting_matches_numpy(n: int) -> None:
    """Random systems; a zero on the diagonal needs the pivoting; a singular matrix is said
    so."""
    rng = np.random.default_rng(40 + n)
    for _ in range(10):
        a = rng.normal(size=(n, n)) + n * np.eye(n)
        b = rng.normal(size=n)
        ok, x = kc.solve(a, b)
        assert ok
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
    perm = np.roll(np.eye(n), 1, axis=0) * np.arange(1.0, n + 1.0)[:, None]  # zero diagonal
    b = rng.normal(size=n)
    ok, x = kc.solve(perm, b)
    assert ok
    np.testing.assert_allclose(x, np.linalg.solve(perm, b), rtol=1e-12)
    assert not kc.solve(np.ones((n, n)), b)[0]


@pytest.mark.parametrize("seed", range(5))
def test_mahalanobis_distance_is_numpys_and_nan_when_not_positive_definite(seed: int) -> None:
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(6, 6))
    a = m @ m.T + 1e-3 * np.eye(6)
    d = rng.normal(size=6)
    assert kc.mahalanobis2(d, a) == pytest.approx(float(d @ np.linalg.solve(a, d)), rel=1e-8)
    a[0, 0] = -1.0
    assert np.isnan(kc.mahalanobis2(d, a))
