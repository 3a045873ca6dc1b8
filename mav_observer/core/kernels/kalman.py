"""One Kalman filter on ``s = [x, a]`` (2n), compiled (numba): its covariance at the start,
its prediction between velocity samples and its robust update at a bearing.

The filter bank (:mod:`~mav_observer.core.kernels.bank`) runs several of these; the maths is
in ``docs/estimator.md``. Units: m, m/s, s; the bearing noise in rad. No I/O, no clock.
"""

from __future__ import annotations

import math

from numba import njit

from mav_observer.core.kernels.algebra import spd_inverse

# scratch offsets of update_filter's results
R_NIS, R_LOGDET, R_WEIGHT, R_STAT = 0, 1, 2, 3


@njit(inline="always", error_model="numpy")
def mirror(p) -> None:
    d = p.shape[0]
    for i in range(d):
        for j in range(i + 1, d):
            p[j, i] = p[i, j]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def initial_covariance(y, range0, range_std, bias_std, sigma, p) -> None:
    """``p`` (2n, 2n) of the state ``x = range0 y``, ``a = 0``: ``range_std`` along ``y``,
    ``range0 * sigma`` across it, ``bias_std`` on each component of ``a``."""
    n = y.shape[0]
    rs2 = range_std * range_std
    cross = (range0 * sigma) ** 2
    p[:, :] = 0.0
    for i in range(n):
        for j in range(n):
            yy = y[i] * y[j]
            p[i, j] = rs2 * yy + cross * ((1.0 if i == j else 0.0) - yy)
        p[n + i, n + i] = bias_std * bias_std


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def predict_filter(s, p, dx, h, q_x, q_a) -> None:
    """One filter over ``h`` s: ``x += dx + h a`` (``dx`` the integral of ``v``, m), ``a``
    unchanged, ``P = F P F^T + Q`` with ``F = [[I, h I], [0, I]]`` and per axis
    ``Q = [[q_x h + q_a h^3/3, q_a h^2/2], [q_a h^2/2, q_a h]]``. In place."""
    n = dx.shape[0]
    hh = h * h
    for i in range(n):
        s[i] += dx[i] + h * s[n + i]
    q0 = q_x * h + q_a * h * hh / 3.0
    q1 = q_a * hh / 2.0
    q2 = q_a * h
    # the x-x block reads the old x-a and a-a blocks: it goes first, then x-a
    for i in range(n):
        for j in range(i, n):
            v = p[i, j] + h * (p[i, n + j] + p[j, n + i]) + hh * p[n + i, n + j]
            p[i, j] = v + (q0 if i == j else 0.0)
    for i in range(n):
        for j in range(n):
            p[i, n + j] = p[i, n + j] + h * p[n + i, n + j] + (q1 if i == j else 0.0)
    for i in range(n):
        p[n + i, n + i] += q2
    mirror(p)


@njit(inline="always", error_model="numpy")
def update_filter(s, p, y, sig2, r_w, outlier_nis, wk, res) -> None:
    """One bearing ``y`` (unit, n) applied to one filter, in place; ``res`` receives
    ``(nis, log det S, weight, noise_stat)``.

    ``r_w`` 0: the extended Kalman filter's form (``d = x/|x|``, ``H = E^T/|x|``, ``z =
    E^T y``); ``r_w > 0``: the Riccati observer's (``d = y``, ``H = E^T / r_w``, ``z = -H
    x``, the weight range ``r_w``). A
    bearing whose NIS exceeds ``outlier_nis`` is applied with its variance ``sig2`` scaled
    by ``(nis / outlier_nis)^2`` (``weight`` its inverse). ``noise_stat`` is the
    covariance-matching statistic ``w (e^T e + tr(H P+ H^T))`` of the noise variance."""
    if y.shape[0] == 3:  # the common case compiled with its sizes known: loops unrolled
        _update_filter_n(s, p, y, sig2, r_w, outlier_nis, wk, res, 3)
    else:
        _update_filter_n(s, p, y, sig2, r_w, outlier_nis, wk, res, y.shape[0])


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _update_filter_n(s, p, y, sig2, r_w, outlier_nis, wk, res, n) -> None:
    """:func:`update_filter` in ``n`` dimensions (the scratch ``wk`` flat)."""
    d2 = 2 * n
    m = n - 1
    # scratch: d (n), E (n, m), H (m, n), P H^T (2n, m), z (m), S^-1 z (m), K (2n, m);
    # S, S^-1 and a factor (m, m) as views
    o_d = 0
    o_e = n
    o_h = o_e + n * m
    o_p = o_h + m * n
    o_z = o_p + d2 * m
    o_q = o_z + m
    o_k = o_q + m
    o_s = o_k + d2 * m
    sm = wk[o_s : o_s + m * m].reshape((m, m))
    sinv = wk[o_s + m * m : o_s + 2 * m * m].reshape((m, m))
    low = wk[o_s + 2 * m * m : o_s + 3 * m * m].reshape((m, m))
    r = 0.0
    for i in range(n):
        r += s[i] * s[i]
    r = math.sqrt(r)
    trk = r_w <= 0.0 and r > 1e-9
    if trk:
        for i in range(n):
            wk[o_d + i] = s[i] / r
        rw = r
    else:
        for i in range(n):
            wk[o_d + i] = y[i]
        rw = r_w if r_w > 0.0 else 1.0
    # the tangent basis E: columns 1.. of the Householder reflection mapping e_0 to -sign d
    d0 = wk[o_d]
    u0 = d0 + (1.0 if d0 >= 0.0 else -1.0)
    uu = u0 * u0
    for i in range(1, n):
        uu += wk[o_d + i] * wk[o_d + i]
    beta = 2.0 / uu
    for c in range(1, n):
        dc = wk[o_d + c]
        for i in range(n):
            ui = u0 if i == 0 else wk[o_d + i]
            ev = (1.0 if i == c else 0.0) - beta * ui * dc
            wk[o_e + i * m + c - 1] = ev
            wk[o_h + (c - 1) * n + i] = ev / rw
    for c in range(m):
        acc = 0.0
        if trk:
            for i in range(n):
                acc += wk[o_e + i * m + c] * y[i]
        else:
            for i in range(n):
                acc -= wk[o_h + c * n + i] * s[i]
        wk[o_z + c] = acc
    # P H^T (the rows of P's position columns), H P H^T
    for i in range(d2):
        for c in range(m):
            acc = 0.0
            for k in range(n):
                acc += p[i, k] * wk[o_h + c * n + k]
            wk[o_p + i * m + c] = acc
    for a in range(m):
        for b in range(m):
            acc = 0.0
            for k in range(n):
                acc += wk[o_h + a * n + k] * wk[o_p + k * m + b]
            sm[a, b] = acc + (sig2 if a == b else 0.0)
    logdet = spd_inverse(sm, sinv, low)
    nis = 0.0
    for a in range(m):
        acc = 0.0
        for b in range(m):
            acc += sinv[a, b] * wk[o_z + b]
        wk[o_q + a] = acc
        nis += wk[o_z + a] * acc
    weight = 1.0
    r_eff = sig2
    if nis > outlier_nis:
        weight = (outlier_nis / nis) ** 2
        r_eff = sig2 / weight
        for a in range(m):
            sm[a, a] += r_eff - sig2
        spd_inverse(sm, sinv, low)
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += sinv[a, b] * wk[o_z + b]
            wk[o_q + a] = acc
    # K = P H^T S^-1; s += K z; P -= K (P H^T)^T, exactly symmetric
    for i in range(d2):
        for c in range(m):
            acc = 0.0
            for b in range(m):
                acc += wk[o_p + i * m + b] * sinv[b, c]
            wk[o_k + i * m + c] = acc
    for i in range(d2):
        acc = 0.0
        for c in range(m):
            acc += wk[o_k + i * m + c] * wk[o_z + c]
        s[i] += acc
    for i in range(d2):
        for j in range(i, d2):
            acc = 0.0
            for c in range(m):
                acc += wk[o_k + i * m + c] * wk[o_p + j * m + c]
            v = p[i, j] - acc
            p[i, j] = v
            p[j, i] = v
    tr = 0.0
    sq = 0.0
    for a in range(m):
        tr += sinv[a, a]
        sq += wk[o_q + a] * wk[o_q + a]
    stat = r_eff * (m - r_eff * (tr - sq))
    res[R_NIS] = nis
    res[R_LOGDET] = logdet
    res[R_WEIGHT] = weight
    res[R_STAT] = weight * stat


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def range_update(s, p, r_meas, var, outlier_nis, wk, res) -> None:
    """A measured range ``r_meas`` (m) of variance ``var`` (m^2) applied to one filter, in
    place: ``z = r_meas - |x|``, ``H = [x^T / |x|, 0]``, robust as :func:`update_filter` (a
    range whose NIS exceeds ``outlier_nis`` applied with its variance scaled by
    ``(nis / outlier_nis)^2``); ``res`` receives ``(nis, log S, weight, 0)``; ``wk`` scratch
    of ``2n``."""
    d2 = p.shape[0]
    n = d2 // 2
    r = 0.0
    for i in range(n):
        r += s[i] * s[i]
    r = math.sqrt(r)
    if r < 1e-9:
        res[R_NIS] = 0.0
        res[R_LOGDET] = 0.0
        res[R_WEIGHT] = 1.0
        res[R_STAT] = 0.0
        return
    hp = 0.0  # H P H^T; P H^T is the column sum_k P[:, k] x_k / r
    for i in range(n):
        for k in range(n):
            hp += s[i] * p[i, k] * s[k]
    hp /= r * r
    z = r_meas - r
    sv = hp + var
    nis = z * z / sv
    weight = 1.0
    if nis > outlier_nis:
        weight = (outlier_nis / nis) ** 2
        sv = hp + var / weight
    logdet = math.log(sv)
    # K = P H^T / S: s += K z, P -= K (P H^T)^T
    ph = wk[:d2]
    for i in range(d2):
        acc = 0.0
        for k in range(n):
            acc += p[i, k] * s[k]
        ph[i] = acc / r
    for i in range(d2):
        s[i] += ph[i] * z / sv
    for i in range(d2):
        for j in range(i, d2):
            v = p[i, j] - ph[i] * ph[j] / sv
            p[i, j] = v
            p[j, i] = v
    res[R_NIS] = nis
    res[R_LOGDET] = logdet
    res[R_WEIGHT] = weight
    res[R_STAT] = 0.0


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def position_update(x, pxx, y, sig2, outlier_nis, wk) -> None:
    """A bearing ``y`` applied to a predicted position ``x`` (n) of covariance ``pxx``
    (n, n) alone, tracking form, in place: for an estimate published beyond the committed
    state (the bearing is applied to the state once the velocity around it is known)."""
    n = x.shape[0]
    d2 = 2 * n
    s = wk[0:d2]
    p = wk[d2 : d2 + d2 * d2].reshape((d2, d2))
    res = wk[d2 + d2 * d2 : d2 + d2 * d2 + 4]
    kw = wk[d2 + d2 * d2 + 4 :]
    s[:] = 0.0
    p[:, :] = 0.0
    s[:n] = x
    p[:n, :n] = pxx
    update_filter(s, p, y, sig2, 0.0, outlier_nis, kw, res)
    x[:] = s[:n]
    pxx[:, :] = p[:n, :n]
