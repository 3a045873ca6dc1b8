"""Exact discrete-time steps of the Le Bras-Hamel-Mahony-Samson observer (pure functions).

Continuous equations (paper, Section 3, with the corrected sign; see ``docs/observer.md``)::

    xh1' = v - k Pi_y xh1                     first filter
    M'   = I - k Pi_y M                       matrix, M(0) symmetric positive definite
    y*   = M^-1 y / |M^-1 y|                  dual output
    zs'  = v* - k* Pi_{y*} zs,  v* = M^-1 (v - M^-1 xh1)
    xhat = M zs,  ahat = zs - M^-1 xh1

With ``w = M^-1 xh1`` one has exactly ``w' = v*``, so the dual stage is equivalently::

    ahat' = -k* Pi_{y*} (ahat + w),   xhat = M ahat + xh1

which is the form integrated here: ``ahat`` is the stored state, ``zs = ahat + w``.

Over a step of length ``h`` with ``y`` and ``v`` held constant, ``Pi_y`` is a projection, so::

    exp(-k h Pi_y)          = y y^T + e Pi_y,          e = exp(-k h)
    int_0^h exp(-k s Pi_y)  = h y y^T + g Pi_y,        g = (1 - e) / k

and the first filter and ``M`` are propagated exactly, for any ``h``. The dual stage is
integrated with ``y*`` and ``w`` frozen at the midpoint of each sub-step (both evaluated from
the exact ``xh1(s)``, ``M(s)``), whose exact solution is::

    ahat <- ahat - (1 - exp(-k* h_s)) Pi_{y*} (ahat + w)

It is unconditionally stable: each sub-step moves ``ahat`` toward the plane where
``Pi_{y*} zs = 0`` by a fraction in [0, 1).

Without a bearing (prediction only, no correction term) the steps are the same with
``k = k* = 0``: ``xh1 += h v``, ``M += h I``, ``ahat`` unchanged, so ``xhat' = v + ahat``.

Representation: vectors are lists of floats, ``M`` a flat row-major list of ``n * n`` floats.
Plain floats, not numpy: for n = 3 a numpy call costs more than the arithmetic it does, and
this step runs for every sample (numpy was 2.5 times slower here). Any n >= 2 works; n = 2
and 3 get a closed-form solve, and the first filter an unrolled n = 3 branch (both tested
against the generic code). No I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import mul

Vec = list[float]

#: Largest ``max(k, k*) * h`` of one sub-step. Inputs are frozen at each sub-step's
#: midpoint; at 20 Hz with the paper's k* = 5 this gives 4 sub-steps per sample interval,
#: which measured 4e-4 relative to a fine RK4 of the continuous equations (1 sub-step: 7e-3).
SUBSTEP_KH = 0.0625
#: Longest sub-step (s): ``w = M^-1 xh1`` and ``y*`` move at rates set by ``M^-1`` whatever
#: the gains. No effect at 10 Hz and above.
SUBSTEP_MAX_S = 0.1
#: Cap on sub-steps per interval (keeps a 60 s step cheap; stability does not depend on it).
MAX_SUBSTEPS = 64


def substep_count(k: float, k_star: float, h: float) -> int:
    """Number of sub-steps for an interval of ``h`` seconds with gains ``k``, ``k*`` (1/s)."""
    n = max(h * max(k, k_star) / SUBSTEP_KH, h / SUBSTEP_MAX_S)
    return min(MAX_SUBSTEPS, max(1, math.ceil(n - 1e-9)))


def decay_terms(k: float, h: float) -> tuple[float, float]:
    """Return ``(e, g)``: ``e = exp(-k h)`` and ``g = int_0^h exp(-k s) ds`` (s).

    ``k`` in 1/s, ``h`` in s, ``k >= 0``, ``h >= 0``. ``g = h`` when ``k = 0``.
    """
    if k == 0.0:
        return 1.0, h
    e = math.exp(-k * h)
    return e, -math.expm1(-k * h) / k


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    return sum(map(mul, a, b))


def mat_vec(m: Sequence[float], v: Sequence[float]) -> Vec:
    """``M v`` for a flat row-major ``M``."""
    n = len(v)
    if n == 3:
        v0, v1, v2 = v
        return [
            m[0] * v0 + m[1] * v1 + m[2] * v2,
            m[3] * v0 + m[4] * v1 + m[5] * v2,
            m[6] * v0 + m[7] * v1 + m[8] * v2,
        ]
    return [sum(map(mul, m[i * n : (i + 1) * n], v)) for i in range(n)]


def identity(n: int, scale: float = 1.0) -> Vec:
    out = [0.0] * (n * n)
    for i in range(n):
        out[i * n + i] = scale
    return out


def first_filter_step(
    xh1: Sequence[float],
    m: Sequence[float],
    y: Sequence[float] | None,
    v: Sequence[float],
    k: float,
    h: float,
) -> tuple[Vec, Vec]:
    """Propagate ``(xh1, M)`` over ``h`` seconds with ``y`` and ``v`` held constant (exact).

    ``y`` is a unit vector, or ``None`` for a prediction step without correction.
    Returns new lists; the inputs are not modified.
    """
    n = len(xh1)
    if y is None or k == 0.0:
        m2 = list(m)
        for i in range(n):
            m2[i * n + i] += h
        return [xh1[i] + h * v[i] for i in range(n)], m2
    e, g = decay_terms(k, h)
    c = 1.0 - e
    hg = h - g
    # Phi X = e X + (1 - e) y (y^T X);  Gamma u = g u + (h - g) y (y^T u)
    if n == 3:
        y0, y1, y2 = y
        s = c * (y0 * xh1[0] + y1 * xh1[1] + y2 * xh1[2]) + hg * (y0 * v[0] + y1 * v[1] + y2 * v[2])
        xn = [
            e * xh1[0] + s * y0 + g * v[0],
            e * xh1[1] + s * y1 + g * v[1],
            e * xh1[2] + s * y2 + g * v[2],
        ]
        r0 = c * (y0 * m[0] + y1 * m[3] + y2 * m[6]) + hg * y0
        r1 = c * (y0 * m[1] + y1 * m[4] + y2 * m[7]) + hg * y1
        r2 = c * (y0 * m[2] + y1 * m[5] + y2 * m[8]) + hg * y2
        return xn, [
            e * m[0] + y0 * r0 + g, e * m[1] + y0 * r1, e * m[2] + y0 * r2,
            e * m[3] + y1 * r0, e * m[4] + y1 * r1 + g, e * m[5] + y1 * r2,
            e * m[6] + y2 * r0, e * m[7] + y2 * r1, e * m[8] + y2 * r2 + g,
        ]  # fmt: skip
    return _first_filter_generic(xh1, m, y, v, e, g, c, hg)


def _first_filter_generic(
    xh1: Sequence[float],
    m: Sequence[float],
    y: Sequence[float],
    v: Sequence[float],
    e: float,
    g: float,
    c: float,
    hg: float,
) -> tuple[Vec, Vec]:
    n = len(xh1)
    s = c * dot(y, xh1) + hg * dot(y, v)
    xn = [e * xh1[i] + s * y[i] + g * v[i] for i in range(n)]
    r = [c * sum(y[i] * m[i * n + j] for i in range(n)) + hg * y[j] for j in range(n)]
    mn = [e * m[i * n + j] + y[i] * r[j] for i in range(n) for j in range(n)]
    for i in range(n):
        mn[i * n + i] += g
    return xn, mn


def solve2(m: Sequence[float], b0: Sequence[float], b1: Sequence[float]) -> tuple[Vec, Vec]:
    """``(M^-1 b0, M^-1 b1)`` for a flat row-major, invertible ``M`` (closed form for n <= 3,
    Gauss-Jordan with partial pivoting above)."""
    n = len(b0)
    if n == 3:
        a, b, c, d, e, f, g, h, i = m
        c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
        c10, c11, c12 = f * g - d * i, a * i - c * g, c * d - a * f
        c20, c21, c22 = d * h - e * g, b * g - a * h, a * e - b * d
        inv = 1.0 / (a * c00 + b * c10 + c * c20)
        return (
            [
                inv * (c00 * b0[0] + c01 * b0[1] + c02 * b0[2]),
                inv * (c10 * b0[0] + c11 * b0[1] + c12 * b0[2]),
                inv * (c20 * b0[0] + c21 * b0[1] + c22 * b0[2]),
            ],
            [
                inv * (c00 * b1[0] + c01 * b1[1] + c02 * b1[2]),
                inv * (c10 * b1[0] + c11 * b1[1] + c12 * b1[2]),
                inv * (c20 * b1[0] + c21 * b1[1] + c22 * b1[2]),
            ],
        )
    if n == 2:
        a, b, c, d = m
        inv = 1.0 / (a * d - b * c)
        return (
            [inv * (d * b0[0] - b * b0[1]), inv * (a * b0[1] - c * b0[0])],
            [inv * (d * b1[0] - b * b1[1]), inv * (a * b1[1] - c * b1[0])],
        )
    return _solve2_generic(m, b0, b1)


def _solve2_generic(
    m: Sequence[float], b0: Sequence[float], b1: Sequence[float]
) -> tuple[Vec, Vec]:
    n = len(b0)
    rows = [[*m[i * n : (i + 1) * n], b0[i], b1[i]] for i in range(n)]
    for col in range(n):
        piv = max(range(col, n), key=lambda r: abs(rows[r][col]))
        rows[col], rows[piv] = rows[piv], rows[col]
        p = rows[col]
        for r in range(n):
            if r != col and rows[r][col] != 0.0:
                f = rows[r][col] / p[col]
                row = rows[r]
                for cc in range(col, n + 2):
                    row[cc] -= f * p[cc]
    return [rows[i][n] / rows[i][i] for i in range(n)], [
        rows[i][n + 1] / rows[i][i] for i in range(n)
    ]


def substep(
    xh1: Sequence[float],
    m: Sequence[float],
    ahat: Sequence[float],
    y: Sequence[float] | None,
    v: Sequence[float],
    k: float,
    k_star: float,
    h: float,
    *,
    estimate_bias: bool = True,
) -> tuple[Vec, Vec, Vec]:
    """Propagate ``(xh1, M, ahat)`` over ``h`` seconds with ``y`` and ``v`` frozen.

    ``xh1`` and ``M`` are exact for the frozen inputs; ``ahat`` uses ``y*`` and ``w`` at the
    midpoint (see the module docstring). ``y is None`` is a prediction step: no correction,
    ``ahat`` unchanged. ``estimate_bias=False`` is the bias-free observer (Lemma 3.1):
    ``ahat`` is left as given (zero). Returns new lists.
    """
    n = len(xh1)
    if y is None:
        x2, m2 = first_filter_step(xh1, m, None, v, k, h)
        return x2, m2, list(ahat)
    a = list(ahat)
    if estimate_bias and k_star > 0.0 and h > 0.0:
        xh1_mid, m_mid = first_filter_step(xh1, m, y, v, k, 0.5 * h)
        m_inv_y, w = solve2(m_mid, y, xh1_mid)
        norm = math.sqrt(dot(m_inv_y, m_inv_y))
        ys = [t / norm for t in m_inv_y]
        zs = [a[i] + w[i] for i in range(n)]
        d = dot(ys, zs)
        f = math.expm1(-k_star * h)
        a = [a[i] + f * (zs[i] - d * ys[i]) for i in range(n)]
    x2, m2 = first_filter_step(xh1, m, y, v, k, h)
    return x2, m2, a


def estimate_from_state(ahat: Sequence[float], xh1: Sequence[float], m: Sequence[float]) -> Vec:
    """``xhat = M zs = M ahat + xh1`` (m)."""
    ma = mat_vec(m, ahat)
    return [ma[i] + xh1[i] for i in range(len(xh1))]


def zs_from_state(ahat: Sequence[float], xh1: Sequence[float], m: Sequence[float]) -> Vec:
    """The paper's dual state ``zs = ahat + M^-1 xh1`` (m/s)."""
    w, _ = solve2(m, xh1, xh1)
    return [ahat[i] + w[i] for i in range(len(xh1))]


def ahat_from_paper_state(xh1: Sequence[float], m: Sequence[float], zs: Sequence[float]) -> Vec:
    """``ahat = zs - M^-1 xh1`` (m/s), for building the stored state from the paper's."""
    w, _ = solve2(m, xh1, xh1)
    return [zs[i] - w[i] for i in range(len(xh1))]


def sym_eigvals(a: Sequence[float], n: int) -> list[float]:
    """Eigenvalues (ascending) of a symmetric flat row-major ``n x n`` matrix: closed form for
    n = 2 and 3 (Smith's trigonometric method), numpy otherwise."""
    if n == 3:
        a00, a01, a02, _, a11, a12, _, _, a22 = a
        p1 = a01 * a01 + a02 * a02 + a12 * a12
        if p1 == 0.0:
            return sorted((a00, a11, a22))
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
        return [e3, 3.0 * q - e1 - e3, e1]
    if n == 2:
        a00, a01, _, a11 = a
        mid = 0.5 * (a00 + a11)
        rad = math.hypot(0.5 * (a00 - a11), a01)
        return [mid - rad, mid + rad]
    import numpy as np  # larger n only: rare, not on the hot path

    return sorted(float(x) for x in np.linalg.eigvalsh(np.array(a, dtype=float).reshape(n, n)))


def cond2(m: Sequence[float], n: int) -> float:
    """2-norm condition number of a flat row-major ``n x n`` matrix, from the eigenvalues of
    ``M^T M`` (singular values squared); numpy's SVD where that loses precision."""
    if n == 3:
        a, b, c, d, e, f, g, h, i = m
        mtm = [
            a * a + d * d + g * g, a * b + d * e + g * h, a * c + d * f + g * i,
            0.0, b * b + e * e + h * h, b * c + e * f + h * i,
            0.0, 0.0, c * c + f * f + i * i,
        ]  # fmt: skip
        mtm[3], mtm[6], mtm[7] = mtm[1], mtm[2], mtm[5]
    else:
        cols = [m[j::n] for j in range(n)]
        mtm = [sum(map(mul, cols[i], cols[j])) for i in range(n) for j in range(n)]
    lo, *_, hi = sym_eigvals(mtm, n)
    if lo > 0.0 and hi / lo < 1e10:
        return math.sqrt(hi / lo)
    import numpy as np

    sv = np.linalg.svd(np.array(m, dtype=float).reshape(n, n), compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0.0 else math.inf
