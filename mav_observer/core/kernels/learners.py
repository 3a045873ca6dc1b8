"""What the default estimator learns online besides its state (numba): the bearings'
latency, whether it has settled, the velocity's white noise, and the innovations' lag-1
correlation (a diagnostic). ``docs/estimator.md`` explains each; each keeps its scalars in a
slice of the observer's scalar array laid out by the constants beside it. No I/O, no clock.
"""

from __future__ import annotations

import math

from numba import njit

from mav_observer.core.kernels.layout import (
    L_B_T0,
    L_B_WW,
    L_B_ZW,
    L_N_B,
    L_Q_WW,
    L_Q_ZW,
    L_Q_ZZ,
    L_S_WW,
    L_S_ZW,
    L_T,
    L_T0,
    L_TAU,
    L_TAU_FIT,
    T_REF,
    T_SETTLED,
    T_TAU_REF,
    V_COUNT_LAST,
    V_S,
    V_SP,
    V_T,
    V_W,
    V_WP,
    W_C0,
    W_C1,
    W_DT,
    W_HAS_PREV,
    W_M,
    W_N,
    W_PREV_SQ,
    W_SQ,
    W_T_PREV,
)

# -- the bearings' latency --------------------------------------------------------------
# A bearing at t shows the line of sight at t - tau. The filter's tangent innovation z is
# regressed on the line of sight's rate w, z ~ -tau w, with forgetting and a zero-mean prior;
# the fit is used only where it stands out of the scatter of its blocks.
#: The regression's forgetting time constant (s).
LAT_MEMORY_S = 120.0
#: The prior's standard deviation (s).
LAT_PRIOR_S = 0.05
#: The blocks over which the scatter is measured (s) ...
LAT_BLOCK_S = 10.0
#: ... and how many standard deviations of it a fit must stand out by.
LAT_SIGNIFICANCE_SIGMA = 2.0
#: A bearing further than this many sigma from the estimate teaches nothing.
LAT_GATE_SIGMA = 3.0


@njit(inline="always", error_model="numpy")
def latency_learning_for(lat, t) -> float:
    """How long (s) it has been learning at ``t``: 0 before its first bearing."""
    return 0.0 if math.isnan(lat[L_T0]) else max(t - lat[L_T0], 0.0)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def latency_observe(lat, t, x, a, v, y, sig2, max_s) -> None:
    """One bearing ``y`` at ``t`` against a converged estimate ``x``, ``a`` with the
    velocity ``v`` (the paper's) and the bearing noise variance in use ``sig2``."""
    n = x.shape[0]
    r2 = 0.0
    for j in range(n):
        r2 += x[j] * x[j]
    if r2 <= 0.0 or sig2 <= 0.0:
        return
    r = math.sqrt(r2)
    along = 0.0
    y_along = 0.0
    for j in range(n):
        u = x[j] / r
        along += (v[j] + a[j]) * u
        y_along += y[j] * u
    tau = lat[L_TAU]
    miss2 = 0.0
    zw = 0.0
    ww = 0.0
    for j in range(n):
        u = x[j] / r
        w = ((v[j] + a[j]) - along * u) / r
        z = y[j] - y_along * u
        miss2 += (z + tau * w) ** 2
        zw += z * w
        ww += w * w
    if miss2 > LAT_GATE_SIGMA**2 * (n - 1) * sig2:
        return  # an outlier (beyond the latency in use) says nothing of the latency
    rho = 1.0 if math.isnan(lat[L_T]) else math.exp(-max(t - lat[L_T], 0.0) / LAT_MEMORY_S)
    lat[L_T] = t
    if math.isnan(lat[L_T0]):
        lat[L_T0] = t
    lat[L_S_ZW] = rho * lat[L_S_ZW] + zw
    lat[L_S_WW] = rho * lat[L_S_WW] + ww
    if math.isnan(lat[L_B_T0]) or t < lat[L_B_T0]:
        lat[L_B_T0], lat[L_B_ZW], lat[L_B_WW] = t, 0.0, 0.0
    elif t - lat[L_B_T0] >= LAT_BLOCK_S:  # the block closes: its score into the scatter
        f = math.exp(-(t - lat[L_B_T0]) / LAT_MEMORY_S)
        lat[L_Q_ZZ] = f * lat[L_Q_ZZ] + lat[L_B_ZW] * lat[L_B_ZW]
        lat[L_Q_ZW] = f * lat[L_Q_ZW] + lat[L_B_ZW] * lat[L_B_WW]
        lat[L_Q_WW] = f * lat[L_Q_WW] + lat[L_B_WW] * lat[L_B_WW]
        lat[L_N_B] = f * lat[L_N_B] + 1.0
        lat[L_B_T0], lat[L_B_ZW], lat[L_B_WW] = t, 0.0, 0.0
    lat[L_B_ZW] += zw
    lat[L_B_WW] += ww
    fit = -lat[L_S_ZW] / (lat[L_S_WW] + sig2 / LAT_PRIOR_S**2)
    lat[L_TAU_FIT] = fit
    lat[L_TAU] = max(-max_s, min(max_s, _significant(lat, fit)))


@njit(inline="always", error_model="numpy")
def _significant(lat, tau) -> float:
    """The fit ``tau`` shrunk by its variance from the blocks' scatter (a sandwich
    estimate), 0 before two blocks."""
    n_b = lat[L_N_B]
    if n_b < 1.5 or lat[L_S_WW] <= 0.0:
        return 0.0
    u2 = lat[L_Q_ZZ] + 2.0 * tau * lat[L_Q_ZW] + tau * tau * lat[L_Q_WW]
    var = max(u2, 0.0) / (lat[L_S_WW] * lat[L_S_WW]) * n_b / (n_b - 1.0)
    k2 = LAT_SIGNIFICANCE_SIGMA**2
    if tau * tau <= k2 * var:
        return 0.0
    return tau * (1.0 - k2 * var / (tau * tau))


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def advance(y, x, a, v, tau, out) -> None:
    """The bearing ``y`` that shows the line of sight ``tau`` s late, brought forward along
    the estimate's line-of-sight rate ``w = (I - y y^T)(v + a) / |x|``: ``y + tau w``,
    re-normalised, into ``out``."""
    n = y.shape[0]
    r = 0.0
    for j in range(n):
        r += x[j] * x[j]
    r = math.sqrt(r)
    if r <= 0.0:
        out[:] = y
        return
    along = 0.0
    for j in range(n):
        along += (v[j] + a[j]) * y[j]
    nn = 0.0
    for j in range(n):
        out[j] = y[j] + tau * ((v[j] + a[j]) - along * y[j]) / r
        nn += out[j] * out[j]
    inv = 1.0 / math.sqrt(nn)
    for j in range(n):
        out[j] *= inv


# -- whether the latency has settled ----------------------------------------------------
#: Settled: learning for at least this long (s) ...
SETTLE_AFTER_S = 30.0
#: ... and moved by less than this (s) over the latest window (s).
SETTLE_STEP_S = 0.003
SETTLE_WINDOW_S = 20.0


@njit(inline="always", error_model="numpy")
def settling_update(st, t, tau, learning_for) -> bool:
    """Account the latency ``tau`` learnt for ``learning_for`` s at ``t``; whether it has
    settled (checked once per window)."""
    if math.isnan(st[T_REF]) or t < st[T_REF]:
        st[T_REF], st[T_TAU_REF] = t, tau
    elif t - st[T_REF] >= SETTLE_WINDOW_S:
        ok = learning_for >= SETTLE_AFTER_S and abs(tau - st[T_TAU_REF]) < SETTLE_STEP_S
        st[T_SETTLED] = 1.0 if ok else 0.0
        st[T_REF], st[T_TAU_REF] = t, tau
    return st[T_SETTLED] != 0.0


# -- the velocity's white noise ---------------------------------------------------------
# The third divided difference of four consecutive samples is zero for any motion whose
# velocity is quadratic in time; for white noise of sigma per axis its variance is
# sigma^2 sum c_i^2. An exponentially forgetting mean of those, from a prior.
#: Longest interval (s) between samples whose differences are used.
VN_MAX_INTERVAL_S = 0.5
#: A prior weighing less than this many samples is dropped.
VN_PRIOR_GONE = 1e-6
#: A single sample's variance counts at most this many times the current estimate ...
VN_CLIP = 25.0
#: ... and at least this (m^2/s^2): from zero, the estimate can still grow.
VN_CLIP_FLOOR = 1e-4
#: The forgetting time constant (s); the prior's weight is set with the state (``layout``).
VN_MEMORY_S = 60.0


@njit(inline="always", error_model="numpy")
def vnoise_sigma(vn, prior_mps) -> float:
    """The velocity noise learnt (m/s per axis)."""
    w = vn[V_W] + vn[V_WP]
    return math.sqrt((vn[V_S] + vn[V_SP]) / w) if w > 0.0 else prior_mps


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def vnoise_update(vn, last, t, v, prior_mps) -> None:
    """A velocity sample (``last`` (4, n): the latest samples' vectors); a repeated or older
    time starts the run of samples again."""
    k = int(vn[V_COUNT_LAST])
    if k > 0 and t <= vn[V_T + k - 1]:
        k = 0
    if k == 4:  # drop the oldest
        for i in range(3):
            vn[V_T + i] = vn[V_T + i + 1]
            last[i, :] = last[i + 1, :]
        k = 3
    vn[V_T + k] = t
    last[k, :] = v
    k += 1
    vn[V_COUNT_LAST] = k
    if k < 4:
        return
    t0, t1, t2, t3 = vn[V_T], vn[V_T + 1], vn[V_T + 2], vn[V_T + 3]
    h1, h2, h3 = t1 - t0, t2 - t1, t3 - t2
    lo, hi = min(h1, h2, h3), max(h1, h2, h3)
    if hi > VN_MAX_INTERVAL_S or hi > 4.0 * lo:
        return
    c0 = -1.0 / (h1 * (h1 + h2) * (h1 + h2 + h3))
    c1 = 1.0 / (h1 * h2 * (h2 + h3))
    c2 = -1.0 / ((h1 + h2) * h2 * h3)
    c3 = 1.0 / ((h1 + h2 + h3) * (h2 + h3) * h3)
    n = last.shape[1]
    d2 = 0.0
    for j in range(n):
        e = c0 * last[0, j] + c1 * last[1, j] + c2 * last[2, j] + c3 * last[3, j]
        d2 += e * e
    sample = d2 / ((c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3) * n)
    cap = max(VN_CLIP * vnoise_sigma(vn, prior_mps) ** 2, VN_CLIP_FLOOR)
    rho = math.exp(-h3 / VN_MEMORY_S)
    vn[V_W] = rho * vn[V_W] + 1.0
    vn[V_S] = rho * vn[V_S] + min(sample, cap)
    rho_p = rho**10
    vn[V_WP] = rho_p * vn[V_WP] if vn[V_WP] > VN_PRIOR_GONE else 0.0
    vn[V_SP] = rho_p * vn[V_SP] if vn[V_WP] > 0.0 else 0.0


# -- the innovations' lag-1 correlation (a diagnostic) ----------------------------------
# The covariance is honest only while the bearing errors are white; successive innovations
# alike say they are not (docs/geolocation.md, "When the sigma is not to be trusted").
#: Successive bearings further apart than this (s) are not compared.
WH_MAX_GAP_S = 2.0
#: No correlation is reported from fewer (forgotten) pairs.
WH_MIN_PAIRS = 30.0
#: An innovation larger than this many times the running RMS is left out.
WH_CLIP_RMS = 5.0
WH_MEMORY_S = 60.0


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def whiteness_add(wh, prev, t, z) -> None:
    """One innovation ``z`` (tangent to the predicted direction, in units of the bearing
    noise in use) at the bearing time ``t``; ``prev`` (n,) holds the previous one."""
    n = z.shape[0]
    sq = 0.0
    for j in range(n):
        sq += z[j] * z[j]
    if not math.isfinite(sq):
        wh[W_HAS_PREV] = 0.0
        return
    m = wh[W_M]
    if wh[W_N] >= WH_MIN_PAIRS and sq * m > WH_CLIP_RMS * WH_CLIP_RMS * wh[W_SQ]:
        wh[W_HAS_PREV] = 0.0  # a gross error: neither compared nor a neighbour
        return
    t_prev = t if m == 0.0 else wh[W_T_PREV]
    dt = t - t_prev
    rho = math.exp(-dt / WH_MEMORY_S) if dt > 0.0 else 1.0
    wh[W_SQ] = rho * wh[W_SQ] + sq
    wh[W_M] = rho * m + 1.0
    if wh[W_HAS_PREV] != 0.0 and 0.0 <= dt <= WH_MAX_GAP_S:
        c1 = 0.0
        for j in range(n):
            c1 += z[j] * prev[j]
        wh[W_C0] = rho * wh[W_C0] + 0.5 * (sq + wh[W_PREV_SQ])
        wh[W_C1] = rho * wh[W_C1] + c1
        wh[W_N] = rho * wh[W_N] + 1.0
        wh[W_DT] = rho * wh[W_DT] + dt
    elif rho != 1.0:
        wh[W_C0] *= rho
        wh[W_C1] *= rho
        wh[W_N] *= rho
        wh[W_DT] *= rho
    prev[:] = z
    wh[W_PREV_SQ] = sq
    wh[W_HAS_PREV] = 1.0
    if t > t_prev or m == 0.0:
        wh[W_T_PREV] = t
