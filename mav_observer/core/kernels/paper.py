"""The observer of Le Bras, Hamel, Mahony and Samson (2015), exact discrete steps (numba).

Continuous equations (the paper's Section 3 with its sign misprint corrected,
``docs/observer.md``)::

    xh1' = v - k Pi_y xh1                     first filter
    M'   = I - k Pi_y M                       matrix, M(0) symmetric positive definite
    y*   = M^-1 y / |M^-1 y|                  dual output
    ahat' = -k* Pi_{y*} (ahat + w),  w = M^-1 xh1,   xhat = M ahat + xh1

``Pi_y`` is a projection, so over a step ``h`` with ``y`` and ``v`` held::

    exp(-k h Pi_y) = y y^T + e Pi_y,  int_0^h exp(-k s Pi_y) = h y y^T + g Pi_y,
    e = exp(-k h), g = (1 - e) / k

and the first filter and ``M`` are propagated exactly for any ``h``; the dual stage with
``y*`` and ``w`` frozen at the sub-step's midpoint, ``ahat <- ahat - (1 - exp(-k* h))
Pi_{y*} (ahat + w)``, unconditionally stable. Without a bearing ``k = k* = 0``: ``xh1 += h
v``, ``M += h I``. State: ``xh1`` (n), ``m`` (n, n), ``ahat`` (n), in the caller's arrays.
No I/O, no clock.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mav_observer.core.kernels.algebra import solve

#: Largest ``max(k, k*) h`` of one sub-step (inputs frozen at its midpoint: at 20 Hz with
#: k* = 5, four sub-steps; docs/observer.md, "Stability and accuracy, measured").
SUBSTEP_KH = 0.0625
#: Longest sub-step (s): ``w`` and ``y*`` move at rates set by ``M^-1`` whatever the gains.
SUBSTEP_MAX_S = 0.1
#: Cap on sub-steps per interval (stability does not depend on it).
MAX_SUBSTEPS = 64


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def substep_count(k, k_star, h) -> int:
    """Sub-steps for an interval of ``h`` s with gains ``k``, ``k*`` (1/s)."""
    c = max(h * max(k, k_star) / SUBSTEP_KH, h / SUBSTEP_MAX_S)
    return min(MAX_SUBSTEPS, max(1, math.ceil(c - 1e-9)))


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def first_filter_step(xh1, m, y, has_y, v, k, h) -> None:
    """``(xh1, M)`` over ``h`` s with ``y`` (unit; ``has_y`` False: a prediction) and ``v``
    held, exact. In place."""
    n = xh1.shape[0]
    if not has_y or k == 0.0:
        for i in range(n):
            xh1[i] += h * v[i]
            m[i, i] += h
        return
    e = math.exp(-k * h)
    g = -math.expm1(-k * h) / k
    c = 1.0 - e
    hg = h - g
    # Phi X = e X + (1 - e) y (y^T X);  Gamma u = g u + (h - g) y (y^T u)
    yx = 0.0
    yv = 0.0
    for i in range(n):
        yx += y[i] * xh1[i]
        yv += y[i] * v[i]
    s = c * yx + hg * yv
    for i in range(n):
        xh1[i] = e * xh1[i] + s * y[i] + g * v[i]
    for j in range(n):
        ym = 0.0
        for i in range(n):
            ym += y[i] * m[i, j]
        rj = c * ym + hg * y[j]
        for i in range(n):
            m[i, j] = e * m[i, j] + y[i] * rj
    for i in range(n):
        m[i, i] += g


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def solve_pair(m, b0, b1, out0, out1, work) -> None:
    """``out0 = M^-1 b0``, ``out1 = M^-1 b1``: closed form for n = 2 and 3, the pivoting
    solve of :mod:`~mav_observer.core.kernels.algebra` above (``work`` (n, n + 2) scratch)."""
    n = b0.shape[0]
    if n == 3:
        a, b, c = m[0, 0], m[0, 1], m[0, 2]
        d, e, f = m[1, 0], m[1, 1], m[1, 2]
        g, h, i = m[2, 0], m[2, 1], m[2, 2]
        c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
        c10, c11, c12 = f * g - d * i, a * i - c * g, c * d - a * f
        c20, c21, c22 = d * h - e * g, b * g - a * h, a * e - b * d
        inv = 1.0 / (a * c00 + b * c10 + c * c20)
        x0 = inv * (c00 * b0[0] + c01 * b0[1] + c02 * b0[2])
        x1 = inv * (c10 * b0[0] + c11 * b0[1] + c12 * b0[2])
        x2 = inv * (c20 * b0[0] + c21 * b0[1] + c22 * b0[2])
        w0 = inv * (c00 * b1[0] + c01 * b1[1] + c02 * b1[2])
        w1 = inv * (c10 * b1[0] + c11 * b1[1] + c12 * b1[2])
        w2 = inv * (c20 * b1[0] + c21 * b1[1] + c22 * b1[2])
        out0[0], out0[1], out0[2] = x0, x1, x2
        out1[0], out1[1], out1[2] = w0, w1, w2
        return
    if n == 2:
        a, b, c, d = m[0, 0], m[0, 1], m[1, 0], m[1, 1]
        inv = 1.0 / (a * d - b * c)
        x0, x1 = inv * (d * b0[0] - b * b0[1]), inv * (a * b0[1] - c * b0[0])
        w0, w1 = inv * (d * b1[0] - b * b1[1]), inv * (a * b1[1] - c * b1[0])
        out0[0], out0[1] = x0, x1
        out1[0], out1[1] = w0, w1
        return
    b = np.empty((n, 2))  # (above three dimensions only: rare, allocated)
    for r in range(n):
        b[r, 0], b[r, 1] = b0[r], b1[r]
    solve(m, b, work)
    for r in range(n):
        out0[r], out1[r] = b[r, 0], b[r, 1]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def substep(xh1, m, ahat, y, has_y, v, k, k_star, h, estimate_bias, wk) -> None:
    """``(xh1, M, ahat)`` over ``h`` s with ``y`` and ``v`` frozen: ``xh1`` and ``M`` exact,
    ``ahat`` with ``y*`` and ``w`` at the midpoint; a prediction (``has_y`` False) leaves
    ``ahat``; ``estimate_bias`` False is the bias-free observer (Lemma 3.1). In place."""
    n = xh1.shape[0]
    if has_y and estimate_bias and k_star > 0.0 and h > 0.0:
        xmid = wk[0:n]
        mmid = wk[n : n + n * n].reshape((n, n))
        ys = wk[n + n * n : 2 * n + n * n]
        w = wk[2 * n + n * n : 3 * n + n * n]
        work = wk[3 * n + n * n : 3 * n + n * n + n * (n + 2)].reshape((n, n + 2))
        xmid[:] = xh1
        mmid[:, :] = m
        first_filter_step(xmid, mmid, y, has_y, v, k, 0.5 * h)
        solve_pair(mmid, y, xmid, ys, w, work)
        nrm = 0.0
        for i in range(n):
            nrm += ys[i] * ys[i]
        nrm = math.sqrt(nrm)
        dd = 0.0
        for i in range(n):
            ys[i] /= nrm
            dd += ys[i] * (ahat[i] + w[i])
        f = math.expm1(-k_star * h)
        for i in range(n):
            ahat[i] += f * ((ahat[i] + w[i]) - dd * ys[i])
    first_filter_step(xh1, m, y, has_y, v, k, h)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def estimate(xh1, m, ahat, x_out) -> None:
    """``xhat = M ahat + xh1`` (m) into ``x_out``."""
    n = xh1.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += m[i, j] * ahat[j]
        x_out[i] = acc + xh1[i]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def is_static(xh1, m, ahat, v, y, hold_speed2, hold_cos, wk) -> bool:
    """The static-geometry test: ``|v + ahat|`` at most the hold speed and the bearing ``y``
    within the hold angle of the estimate's direction."""
    n = v.shape[0]
    rel2 = 0.0
    for i in range(n):
        rel2 += (v[i] + ahat[i]) * (v[i] + ahat[i])
    if rel2 > hold_speed2:
        return False
    x = wk[0:n]
    estimate(xh1, m, ahat, x)
    r2 = 0.0
    xy = 0.0
    for i in range(n):
        r2 += x[i] * x[i]
        xy += x[i] * y[i]
    if r2 <= 0.0:
        return False
    return xy >= hold_cos * math.sqrt(r2)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def zs(xh1, m, ahat, out, wk) -> None:
    """The paper's dual state ``zs = ahat + M^-1 xh1`` (m/s) into ``out``."""
    n = xh1.shape[0]
    other = wk[0:n]
    work = wk[n : n + n * (n + 2)].reshape((n, n + 2))
    solve_pair(m, xh1, xh1, out, other, work)
    for i in range(n):
        out[i] += ahat[i]
