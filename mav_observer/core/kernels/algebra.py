"""Small fixed-size linear algebra for the compiled estimator (numba, no scipy).

numba's ``np.linalg`` needs scipy's LAPACK; the matrices here are 2x2 to 8x8, where loops
written out cost less than a library call. Every function works in place on views of the
caller's arrays and allocates nothing, so a kernel's hot path has no heap allocation.
"""

from __future__ import annotations

import math

from numba import njit


@njit(inline="always", error_model="numpy")
def carve(wk, o, size):
    """``wk[o : o + size]`` and the offset after it: scratch handed out piece by piece."""
    return wk[o : o + size], o + size


@njit(inline="always", error_model="numpy")
def dot(a, b) -> float:
    """``a . b`` of two vectors of the same length."""
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(inline="always", error_model="numpy")
def norm(a) -> float:
    return math.sqrt(dot(a, a))


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def tangent_basis(d, e) -> None:
    """Columns ``e`` (n, n - 1): an orthonormal basis of the plane orthogonal to the unit
    vector ``d`` (n,), columns 1.. of the Householder reflection that maps ``e_0`` to
    ``-sign(d_0) d``."""
    n = d.shape[0]
    u0 = d[0] + (1.0 if d[0] >= 0.0 else -1.0)
    s = u0 * u0
    for i in range(1, n):
        s += d[i] * d[i]
    beta = 2.0 / s  # |u|^2 = 2 (1 + |d_0|) >= 2
    for c in range(1, n):
        for r in range(n):
            ur = u0 if r == 0 else d[r]
            e[r, c - 1] = (1.0 if r == c else 0.0) - beta * ur * d[c]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def cholesky(a, low) -> bool:
    """``a = L L^T`` into ``low`` (lower triangle; the rest zeroed); False if ``a`` is not
    positive definite to working precision."""
    n = a.shape[0]
    for j in range(n):
        t = a[j, j]
        for k in range(j):
            t -= low[j, k] * low[j, k]
        if not t > 0.0:
            return False
        ljj = math.sqrt(t)
        low[j, j] = ljj
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= low[i, k] * low[j, k]
            low[i, j] = t / ljj
        for i in range(j):
            low[i, j] = 0.0
    return True


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def spd_inverse(a, inv, low) -> float:
    """The inverse of symmetric positive definite ``a`` into ``inv`` (``low`` a scratch of
    its shape); returns ``log det a`` (NaN if not positive definite: ``inv`` is then
    undefined). Closed form for 1x1 and 2x2 (the bearing's innovation in 2-D and 3-D)."""
    m = a.shape[0]
    if m == 1:
        inv[0, 0] = 1.0 / a[0, 0]
        return math.log(a[0, 0]) if a[0, 0] > 0.0 else math.nan
    if m == 2:
        a00, b, d = a[0, 0], a[0, 1], a[1, 1]
        det = a00 * d - b * b
        inv[0, 0] = d / det
        inv[1, 1] = a00 / det
        inv[0, 1] = -b / det
        inv[1, 0] = -b / det
        return math.log(det) if det > 0.0 else math.nan
    if not cholesky(a, low):
        return math.nan
    logdet = 0.0
    for i in range(m):
        logdet += 2.0 * math.log(low[i, i])
    # inv = L^-T L^-1, column by column
    for c in range(m):
        for i in range(m):  # forward: L w = e_c
            t = 1.0 if i == c else 0.0
            for k in range(i):
                t -= low[i, k] * inv[k, c]
            inv[i, c] = t / low[i, i]
        for i in range(m - 1, -1, -1):  # back: L^T x = w
            t = inv[i, c]
            for k in range(i + 1, m):
                t -= low[k, i] * inv[k, c]
            inv[i, c] = t / low[i, i]
    return logdet


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def mahalanobis2(d, a, low, z) -> float:
    """``d^T a^-1 d`` for symmetric positive definite ``a`` by its Cholesky factor (``low``
    and ``z`` scratch); NaN if ``a`` is not positive definite."""
    if not cholesky(a, low):
        return math.nan
    n = d.shape[0]
    acc = 0.0
    for j in range(n):
        t = d[j]
        for k in range(j):
            t -= low[j, k] * z[k]
        z[j] = t / low[j, j]
        acc += z[j] * z[j]
    return acc


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def solve(a, b, work) -> bool:
    """``b <- a^-1 b`` (``b`` (n,) or (n, k)) by Gauss-Jordan elimination with partial
    pivoting on ``work`` (a scratch (n, n + k)); False if ``a`` is singular."""
    n = a.shape[0]
    k = 1 if b.ndim == 1 else b.shape[1]
    for i in range(n):
        for j in range(n):
            work[i, j] = a[i, j]
        for j in range(k):
            work[i, n + j] = b.flat[i * k + j]
    cols = n + k
    for col in range(n):
        piv = col
        big = abs(work[col, col])
        for r in range(col + 1, n):
            if abs(work[r, col]) > big:
                big = abs(work[r, col])
                piv = r
        if big == 0.0:
            return False
        if piv != col:
            for j in range(cols):
                t = work[col, j]
                work[col, j] = work[piv, j]
                work[piv, j] = t
        for r in range(n):
            if r != col and work[r, col] != 0.0:
                f = work[r, col] / work[col, col]
                for j in range(col, cols):
                    work[r, j] -= f * work[col, j]
    for i in range(n):
        for j in range(k):
            b.flat[i * k + j] = work[i, n + j] / work[i, i]
    return True


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def sym_eigvals(a, out, work) -> None:
    """Eigenvalues (ascending) of the symmetric ``a`` (n, n) into ``out`` (n,): closed form
    for n = 2 and 3 (Smith's trigonometric method), cyclic Jacobi above (``work`` (n, n))."""
    n = a.shape[0]
    if n == 3:
        a00, a01, a02 = a[0, 0], a[0, 1], a[0, 2]
        a11, a12, a22 = a[1, 1], a[1, 2], a[2, 2]
        p1 = a01 * a01 + a02 * a02 + a12 * a12
        if p1 == 0.0:
            out[0], out[1], out[2] = a00, a11, a22
            _sort3(out)
            return
        q = (a00 + a11 + a22) / 3.0
        b00, b11, b22 = a00 - q, a11 - q, a22 - q
        p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * p1) / 6.0)
        det = (
            b00 * (b11 * b22 - a12 * a12)
            - a01 * (a01 * b22 - a12 * a02)
            + a02 * (a01 * a12 - b11 * a02)
        )
        r = max(-1.0, min(1.0, det / (2.0 * p * p * p)))
        phi = math.acos(r) / 3.0
        e1 = q + 2.0 * p * math.cos(phi)
        e3 = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
        out[0], out[1], out[2] = e3, 3.0 * q - e1 - e3, e1
        return
    if n == 2:
        mid = 0.5 * (a[0, 0] + a[1, 1])
        rad = math.hypot(0.5 * (a[0, 0] - a[1, 1]), a[0, 1])
        out[0], out[1] = mid - rad, mid + rad
        return
    for i in range(n):
        for j in range(n):
            work[i, j] = a[i, j]
    for _sweep in range(100):
        off = 0.0
        for i in range(n):
            for j in range(i + 1, n):
                off += work[i, j] * work[i, j]
        if off <= 1e-30 * _frob2(work):
            break
        for p in range(n):
            for q in range(p + 1, n):
                apq = work[p, q]
                if apq == 0.0:
                    continue
                theta = (work[q, q] - work[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(n):
                    akp, akq = work[k, p], work[k, q]
                    work[k, p] = c * akp - s * akq
                    work[k, q] = s * akp + c * akq
                for k in range(n):
                    apk, aqk = work[p, k], work[q, k]
                    work[p, k] = c * apk - s * aqk
                    work[q, k] = s * apk + c * aqk
    for i in range(n):
        out[i] = work[i, i]
    sort_small(out, n)


@njit(inline="always", error_model="numpy")
def _frob2(a) -> float:
    s = 0.0
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            s += a[i, j] * a[i, j]
    return s


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def sort_small(v, count) -> None:
    """Sort ``v[:count]`` ascending in place (insertion: a handful of values)."""
    for i in range(1, count):
        x = v[i]
        j = i - 1
        while j >= 0 and v[j] > x:
            v[j + 1] = v[j]
            j -= 1
        v[j + 1] = x


@njit(inline="always", error_model="numpy")
def _sort3(v) -> None:
    if v[1] < v[0]:
        v[0], v[1] = v[1], v[0]
    if v[2] < v[1]:
        v[1], v[2] = v[2], v[1]
        if v[1] < v[0]:
            v[0], v[1] = v[1], v[0]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def cond2(m, mtm, ev, work) -> float:
    """The 2-norm condition number of ``m`` (n, n): from the eigenvalues of ``M^T M``, or
    from singular values by one-sided Jacobi where that loses precision (``mtm``, ``work``
    (n, n) and ``ev`` (n,) scratch)."""
    n = m.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += m[k, i] * m[k, j]
            mtm[i, j] = s
    sym_eigvals(mtm, ev, work)
    lo, hi = ev[0], ev[n - 1]
    if lo > 0.0 and hi / lo < 1e10:
        return math.sqrt(hi / lo)
    # one-sided Jacobi on the columns of a copy of m: their norms are the singular values
    for i in range(n):
        for j in range(n):
            work[i, j] = m[i, j]
    for _sweep in range(60):
        rotated = False
        for p in range(n):
            for q in range(p + 1, n):
                alpha = beta = gamma = 0.0
                for k in range(n):
                    alpha += work[k, p] * work[k, p]
                    beta += work[k, q] * work[k, q]
                    gamma += work[k, p] * work[k, q]
                if gamma == 0.0 or abs(gamma) <= 1e-15 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                c = 1.0 / math.sqrt(1.0 + t * t)
                s = c * t
                for k in range(n):
                    wp, wq = work[k, p], work[k, q]
                    work[k, p] = c * wp - s * wq
                    work[k, q] = s * wp + c * wq
        if not rotated:
            break
    lo, hi = math.inf, 0.0
    for j in range(n):
        sv = 0.0
        for k in range(n):
            sv += work[k, j] * work[k, j]
        sv = math.sqrt(sv)
        lo = min(lo, sv)
        hi = max(hi, sv)
    return hi / lo if lo > 0.0 else math.inf
