"""The two sample streams of one observer and the inputs they give its estimator (numba).

The velocity (the paper's ``v``, m/s) and bearing (unit vectors) samples, in time order, in
fixed-size buffers the caller owns, and the inputs of the continuous equations made from
them: interpolated between samples, held after the latest, the integration's breakpoints,
the data horizon. The rules are ``docs/observer.md``'s ("How samples become inputs").

* ``vbuf`` (capacity, 2 + 2n): per velocity sample its time, whether the mean over the
  interval that ends at it is known from the positions (1.0) and that mean, its vector;
  columns ``VB_*``;
* ``bbuf`` (capacity, 3 + n): per bearing its time, unit vector, and the range measured with
  it (m, NaN: none) and that range's variance (m^2);
* ``q``: the streams' scalars (``Q_*``): the rows in use, the velocity's latest sample
  interval and a sparse stream's extrapolation error learnt.

No I/O, no clock.
"""

from __future__ import annotations

import math

from numba import njit

from mav_observer.core.kernels.algebra import sort_small
from mav_observer.core.kernels.layout import (
    Q_EX_S,
    Q_EX_SP,
    Q_EX_W,
    Q_EX_WP,
    Q_NB,
    Q_NV,
    Q_VDT,
    VB_HAS_MEAN,
    VB_T,
    VB_V,
)

#: The forgetting time constant (s) of a sparse stream's extrapolation error (its prior, and
#: the breakpoints' merging interval, are set with the state: ``layout``).
EXTRAPOLATION_MEMORY_S = 60.0
#: A velocity interval at least this long (s) whose mean is known from the positions is a
#: sparse stream's: a prediction past its latest sample continues its trend.
SPARSE_INTERVAL_S = 0.2
#: The least drift rate (m/s^2) of a velocity held across a telemetry gap: a vehicle may turn
#: or brake in a gap however steady it was before, and the covariance must say so.
GAP_ACCEL_MPS2 = 1.0
#: A velocity interval longer than the staleness limit is a telemetry gap only when it is also
#: more than this many times the stream's interval before it: a stream whose own cadence is
#: longer than the limit (LOCAL_POSITION_NED at 0.4 Hz) has no gap between its samples.
GAP_CADENCE_FACTOR = 2.0


@njit(inline="always", error_model="numpy")
def _vel(vbuf, i, n):
    return vbuf[i, VB_V : VB_V + n]


@njit(inline="always", error_model="numpy")
def _mean(vbuf, i, n):
    return vbuf[i, VB_V + n : VB_V + 2 * n]


@njit(inline="always", error_model="numpy")
def append_velocity(q, vbuf, t, v) -> None:
    """Append a velocity sample (its time already checked against the previous one)."""
    nv = int(q[Q_NV])
    n = v.shape[0]
    if nv > 0 and t > vbuf[nv - 1, VB_T]:
        q[Q_VDT] = min(1.0, t - vbuf[nv - 1, VB_T])
    vbuf[nv, VB_T] = t
    vbuf[nv, VB_HAS_MEAN] = 0.0
    vbuf[nv, VB_V : VB_V + n] = v
    q[Q_NV] = nv + 1


@njit(inline="always", error_model="numpy")
def set_bearing_range(q, bbuf, n, r, var) -> None:
    """The range ``r`` (m) of variance ``var`` (m^2) measured with the latest bearing."""
    nb = int(q[Q_NB])
    bbuf[nb - 1, 1 + n] = r
    bbuf[nb - 1, 2 + n] = var


@njit(inline="always", error_model="numpy")
def append_bearing(q, bbuf, t, y) -> None:
    nb = int(q[Q_NB])
    bbuf[nb, 0] = t
    bbuf[nb, 1 : 1 + y.shape[0]] = y
    bbuf[nb, 1 + y.shape[0]] = math.nan
    bbuf[nb, 2 + y.shape[0]] = 0.0
    q[Q_NB] = nb + 1


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def set_interval_mean(q, vbuf, t, mean) -> None:
    """The mean velocity (m/s) over the interval ending at the latest sample, ``t``."""
    nv = int(q[Q_NV])
    n = mean.shape[0]
    if nv >= 2 and vbuf[nv - 2, VB_T] < t:
        if (  # the prediction before this sample continued the previous one's trend
            nv >= 3
            and vbuf[nv - 1, VB_T] == t
            and vbuf[nv - 2, VB_HAS_MEAN] != 0.0
            and vbuf[nv - 2, VB_T] - vbuf[nv - 3, VB_T] >= SPARSE_INTERVAL_S
        ):
            _learn_extrapolation(q, vbuf, t, mean)
        vbuf[nv - 1, VB_HAS_MEAN] = 1.0
        vbuf[nv - 1, VB_V + n : VB_V + 2 * n] = mean


@njit(inline="always", error_model="numpy")
def _trend_at(vbuf, i, n, j) -> tuple[float, float, float]:
    """Component ``j`` of the trend at velocity row ``i`` (its interval's mean known): the
    model's velocity there (the samples' shape shifted to the mean), its slope, the
    interval."""
    tp, tv = vbuf[i - 1, VB_T], vbuf[i, VB_T]
    vp, vl, mn = vbuf[i - 1, VB_V + j], vbuf[i, VB_V + j], vbuf[i, VB_V + n + j]
    iv = tv - tp
    return vl + mn - 0.5 * (vp + vl), (vl - vp) / iv, iv


@njit(inline="always", error_model="numpy")
def _trend_integral(v_end, slope, iv, s) -> float:
    """The displacement over ``[0, s]`` past the latest sample of a trend continued for at
    most one interval ``iv``, then held."""
    ramp = 0.5 * s * s if s <= iv else 0.5 * iv * iv + iv * (s - iv)
    return s * v_end + ramp * slope


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _learn_extrapolation(q, vbuf, t, mean) -> None:
    """Score the prediction the stream gave before the sample at ``t`` arrived (its latest
    trend continued) against the interval's mean now known, as a drift rate of the velocity
    from its trend."""
    nv = int(q[Q_NV])
    n = mean.shape[0]
    i = nv - 2
    s = t - vbuf[i, VB_T]
    err2 = 0.0
    for j in range(n):
        v_end, slope, iv = _trend_at(vbuf, i, n, j)
        e = _trend_integral(v_end, slope, iv, s) - s * mean[j]
        err2 += e * e
    sample = 4.0 * err2 / (n * s**4)
    rho = math.exp(-s / EXTRAPOLATION_MEMORY_S)
    rho_p = rho**10
    q[Q_EX_W] = rho * q[Q_EX_W] + 1.0
    q[Q_EX_S] = rho * q[Q_EX_S] + sample
    q[Q_EX_WP] = rho_p * q[Q_EX_WP]
    q[Q_EX_SP] = rho_p * q[Q_EX_SP]


@njit(inline="always", error_model="numpy")
def extrapolation_mps2(q) -> float:
    """A sparse stream's drift rate from its latest trend learnt (m/s^2 per axis)."""
    return math.sqrt((q[Q_EX_S] + q[Q_EX_SP]) / (q[Q_EX_W] + q[Q_EX_WP]))


@njit(inline="always", error_model="numpy")
def trend_known(q, vbuf) -> bool:
    """The latest velocity interval's mean came from the positions and it is
    :data:`SPARSE_INTERVAL_S` or longer: a sparse stream."""
    nv = int(q[Q_NV])
    return (
        nv >= 2
        and vbuf[nv - 1, VB_HAS_MEAN] != 0.0
        and vbuf[nv - 1, VB_T] - vbuf[nv - 2, VB_T] >= SPARSE_INTERVAL_S
    )


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def extrapolation_var(q, vbuf, t) -> float:
    """The variance (m^2 per axis) of the displacement predicted to ``t`` beyond the latest
    velocity sample of a sparse stream, ``(alpha s^2 / 2)^2`` after ``s``; 0 for a dense
    stream or at or before the latest sample."""
    nv = int(q[Q_NV])
    if nv == 0:
        return 0.0
    tv = vbuf[nv - 1, VB_T]
    if t <= tv or not trend_known(q, vbuf):
        return 0.0
    s = t - tv
    return 0.25 * extrapolation_mps2(q) ** 2 * s**4


@njit(inline="always", error_model="numpy")
def held_var_increment(q, vbuf, t, h) -> float:
    """The variance (m^2 per axis) that the velocity held past its latest sample (a telemetry
    gap) adds to the displacement over the step of ``h`` s centred on ``t``: it grows as
    ``(alpha s^2 / 2)^2`` after ``s``, ``alpha`` the stream's extrapolation error learnt, at
    least :data:`GAP_ACCEL_MPS2`; 0 for a step before the latest sample."""
    nv = int(q[Q_NV])
    if nv == 0:
        return 0.0
    tv = vbuf[nv - 1, VB_T]
    s1 = t + 0.5 * h - tv
    if s1 <= 0.0:
        return 0.0
    s0 = max(t - 0.5 * h - tv, 0.0)
    alpha = max(extrapolation_mps2(q), GAP_ACCEL_MPS2)
    return 0.25 * alpha * alpha * (s1**4 - s0**4)


@njit(inline="always", error_model="numpy")
def shape_var(q, vbuf, t, gap_s) -> float:
    """The variance (m^2 per axis) of the displacement at ``t`` inside a velocity interval
    longer than ``gap_s`` and than :data:`GAP_CADENCE_FACTOR` times the interval before it (a
    telemetry gap) whose mean is known from the positions: exact at
    both ends, the samples' shape in between may miss a turn by ``alpha s (T - s) / 2``
    (``alpha`` as :func:`held_var_increment`'s); 0 elsewhere."""
    nv = int(q[Q_NV])
    for i in range(1, nv):
        tq = vbuf[i, VB_T]
        if tq > t:
            tp = vbuf[i - 1, VB_T]
            if t <= tp or tq - tp <= gap_s or vbuf[i, VB_HAS_MEAN] == 0.0:
                return 0.0
            if i >= 2 and tq - tp <= GAP_CADENCE_FACTOR * (tp - vbuf[i - 2, VB_T]):
                return 0.0  # the stream's own cadence, not a gap in it
            alpha = max(extrapolation_mps2(q), GAP_ACCEL_MPS2)
            e = 0.5 * alpha * (t - tp) * (tq - t)
            return e * e
    return 0.0


@njit(inline="always", error_model="numpy")
def keep_latest(q, vbuf, bbuf) -> None:
    """Before the start only the latest sample of each stream matters."""
    nv, nb = int(q[Q_NV]), int(q[Q_NB])
    if nv > 1:
        vbuf[0, :] = vbuf[nv - 1, :]
        q[Q_NV] = 1
    if nb > 1:
        bbuf[0, :] = bbuf[nb - 1, :]
        q[Q_NB] = 1


@njit(inline="always", error_model="numpy")
def _drop_front(buf, count, k) -> None:
    for i in range(count - k):
        buf[i, :] = buf[i + k, :]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def trim(q, vbuf, bbuf, t_c) -> None:
    """Drop samples no longer needed at the committed time ``t_c``: keep the latest one at
    or before it (the interpolation anchor) and all after; of the velocities the one before
    the anchor too (a prediction continues the latest interval's trend)."""
    nb = int(q[Q_NB])
    keep = 0
    for i in range(nb):
        if bbuf[i, 0] <= t_c:
            keep = i
        else:
            break
    if keep > 0:
        _drop_front(bbuf, nb, keep)
        q[Q_NB] = nb - keep
    nv = int(q[Q_NV])
    keep = 0
    for i in range(nv):
        if vbuf[i, VB_T] <= t_c:
            keep = i
        else:
            break
    keep = max(0, keep - 1)
    if keep > 0:
        _drop_front(vbuf, nv, keep)
        nv -= keep
        q[Q_NV] = nv
    if nv > 0:
        first = vbuf[0, VB_T]
        for i in range(nv):
            if vbuf[i, VB_T] <= first:
                vbuf[i, VB_HAS_MEAN] = 0.0


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def restart_velocity(q, vbuf, bbuf, t, v) -> None:
    """After a gap in the data: the velocity ``v`` from ``t``, the latest bearing kept only
    to hold the horizon."""
    n = v.shape[0]
    vbuf[0, VB_T] = t
    vbuf[0, VB_HAS_MEAN] = 0.0
    vbuf[0, VB_V : VB_V + n] = v
    q[Q_NV] = 1
    nb = int(q[Q_NB])
    if nb > 1:
        bbuf[0, :] = bbuf[nb - 1, :]
        q[Q_NB] = 1


@njit(inline="always", error_model="numpy")
def horizon(q, vbuf, bbuf, max_bearing_age_s, max_velocity_wait_s, max_buffer, held) -> float:
    """The latest time both streams determine: the earlier stream's latest sample, unless
    the other has gone stale (the velocity: ``max_velocity_wait_s`` behind the bearings, or
    ``held`` already, the state committed past it) or a buffer is full."""
    nv, nb = int(q[Q_NV]), int(q[Q_NB])
    tb = bbuf[nb - 1, 0]
    tv = vbuf[nv - 1, VB_T]
    # the bearings past the latest velocity have waited since the first of them after the
    # latest gap in the bearings too (after a gap in both streams, the first bearing back
    # waits for the velocity back)
    first = tb
    if tb > tv + max_velocity_wait_s:  # (else no bearing can have waited that long)
        first = math.nan
        for i in range(nb):
            ti = bbuf[i, 0]
            if ti > tv and (math.isnan(first) or ti - bbuf[i - 1, 0] > max_bearing_age_s):
                first = ti
        if math.isnan(first):
            first = tb
    if tv > tb + max_bearing_age_s:
        h = tv  # bearing stale: no future bearing can correct this stretch
    elif tb > first + max_velocity_wait_s or held:
        h = tb  # velocity stale: hold it
    else:
        h = min(tb, tv)
    if nb > max_buffer or nv > max_buffer:
        h = max(tb, tv)
    return h


@njit(inline="always", error_model="numpy")
def can_wait(q, vbuf, bbuf, max_bearing_age_s, max_buffer) -> bool:
    """A new velocity sample may leave the integration to the next bearing: the bearing is
    not stale and the velocity buffer not full."""
    nv, nb = int(q[Q_NV]), int(q[Q_NB])
    stale = vbuf[nv - 1, VB_T] > bbuf[nb - 1, 0] + max_bearing_age_s
    return not stale and nv <= max_buffer


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def breakpoints(q, vbuf, bbuf, t0, t1, min_interval_s, max_bearing_age_s, out) -> int:
    """``t0``, the sample times and bearing expiries between, ``t1``, each once, in order,
    into ``out``; points closer than ``min_interval_s`` to the previous one or to ``t1``
    merge. Returns how many."""
    nv, nb = int(q[Q_NV]), int(q[Q_NB])
    k = 0
    inner = out[1:]
    for i in range(nv):
        t = vbuf[i, VB_T]
        if t0 < t < t1:
            inner[k] = t
            k += 1
    for i in range(nb):
        t = bbuf[i, 0]
        if t0 < t < t1:
            inner[k] = t
            k += 1
        te = t + max_bearing_age_s
        if t0 < te < t1:
            inner[k] = te
            k += 1
    sort_small(inner, k)
    out[0] = t0
    c = 1
    for i in range(k):
        t = inner[i]
        if t == out[c - 1]:
            continue  # (each once)
        if min_interval_s > 0.0 and (t - out[c - 1] < min_interval_s or t1 - t < min_interval_s):
            continue
        out[c] = t
        c += 1
    out[c] = t1
    return c + 1


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def bearing_at(q, bbuf, t, linear, max_bearing_age_s, out) -> bool:
    """The bearing in force at ``t`` into ``out``, or False when there is no usable one:
    interpolated along the chord and re-normalised between the samples around ``t`` when at
    most ``max_bearing_age_s`` apart, else the earlier one held for at most that long."""
    nb = int(q[Q_NB])
    p = -1
    for i in range(nb):
        if bbuf[i, 0] <= t:
            p = i
        else:
            break
    if p < 0:
        return False
    n = out.shape[0]
    if p + 1 < nb and linear and bbuf[p + 1, 0] - bbuf[p, 0] <= max_bearing_age_s:
        f = (t - bbuf[p, 0]) / (bbuf[p + 1, 0] - bbuf[p, 0])
        nn = 0.0
        for j in range(n):
            a = bbuf[p, 1 + j]
            out[j] = a + f * (bbuf[p + 1, 1 + j] - a)
            nn += out[j] * out[j]
        inv = 1.0 / math.sqrt(nn)
        for j in range(n):
            out[j] *= inv
        return True
    if t <= bbuf[p, 0] + max_bearing_age_s:
        out[:] = bbuf[p, 1 : 1 + out.shape[0]]
        return True
    return False


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def velocity_at(q, vbuf, t, linear, max_velocity_age_s, out) -> None:
    """The velocity at ``t`` into ``out``: where the interval's mean is known from the
    positions, the samples' shape shifted so that its integral is the positions' change;
    else interpolated as bearings are, or the latest held (the first held backwards)."""
    nv = int(q[Q_NV])
    n = out.shape[0]
    p = -1
    for i in range(nv):
        if vbuf[i, VB_T] <= t:
            p = i
        else:
            break
    if p < 0:
        out[:] = vbuf[0, VB_V : VB_V + n]
        return
    if p + 1 < nv:
        qi = p + 1
        tp, tq = vbuf[p, VB_T], vbuf[qi, VB_T]
        if vbuf[qi, VB_HAS_MEAN] != 0.0:
            f = (t - tp) / (tq - tp)
            for j in range(n):
                a, b = vbuf[p, VB_V + j], vbuf[qi, VB_V + j]
                out[j] = (a + f * (b - a)) + vbuf[qi, VB_V + n + j] - 0.5 * (a + b)
            return
        if linear and tq - tp <= max_velocity_age_s:
            f = (t - tp) / (tq - tp)
            for j in range(n):
                a = vbuf[p, VB_V + j]
                out[j] = a + f * (vbuf[qi, VB_V + j] - a)
            return
    out[:] = vbuf[p, VB_V : VB_V + n]


@njit(inline="always", error_model="numpy")
def chord_at(q, vbuf, t) -> bool:
    """The velocity at ``t`` is an interval's mean from the positions."""
    nv = int(q[Q_NV])
    for i in range(nv):
        if vbuf[i, VB_T] > t:
            return vbuf[i, VB_HAS_MEAN] != 0.0
    return False


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def predicted_displacement(q, vbuf, t0, t1, linear, max_velocity_age_s, out, wk) -> None:
    """The integral of ``v`` from ``t0`` to ``t1`` for a prediction (m) into ``out``: the
    known velocity (its midpoint on each stretch) up to the latest sample; past it held,
    or for a sparse stream its latest trend continued for at most one interval."""
    nv = int(q[Q_NV])
    n = out.shape[0]
    v = wk[0:n]
    tv = vbuf[nv - 1, VB_T]
    if t1 <= tv or nv < 2 or vbuf[nv - 1, VB_HAS_MEAN] == 0.0:
        h = t1 - t0
        velocity_at(q, vbuf, t0 + 0.5 * h, linear, max_velocity_age_s, v)
        for j in range(n):
            out[j] = h * v[j]
        return
    out[:] = 0.0
    if t0 < tv:  # the known stretch
        h = tv - t0
        velocity_at(q, vbuf, t0 + 0.5 * h, linear, max_velocity_age_s, v)
        for j in range(n):
            out[j] = h * v[j]
    sparse = trend_known(q, vbuf)
    for j in range(n):
        v_end, slope, iv = _trend_at(vbuf, nv - 1, n, j)
        if not sparse:  # a dense stream: its model's latest velocity held
            slope = 0.0
        a = _trend_integral(v_end, slope, iv, max(t0 - tv, 0.0))
        b = _trend_integral(v_end, slope, iv, t1 - tv)
        out[j] += b - a
