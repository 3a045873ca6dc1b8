"""The observability monitor (numba): excitation over a sliding window, the convergence
indicator and the status rules. ``docs/observer.md`` ("The monitor") states them; in short:

* **excitation**: the smallest eigenvalue of the time-average of ``Pi_y = I - y y^T`` over
  the window (0: the bearing did not move), time without a usable bearing counting as 0;
* **correction_rel**: ``(|sum dx| + W |sum da|) / |xhat|``, the net correction over the
  window relative to the range, a truth-free proxy of the relative error;
* **status**, first match wins: ``stale`` (not started, or a stream older than its maximum
  age), ``not observable`` (window full, excitation below ``excitation_min``; twice it while
  already so), ``converged`` (observable for a window, ``correction_rel <= converged_tol``,
  twice it while already so, and the estimator settled), else ``converging``.

The window is ``buckets`` equal time buckets, rows of ``win`` (buckets + 2, 3 + n^2 + 2n):
``[index, covered_s, valid_s, yy (n^2), dx (n), da (n)]`` (one row more than the buckets: a
new one is added before the oldest drops); the last row holds the totals, its first column
the number of buckets in use. No I/O, no clock.
"""

from __future__ import annotations

import math

from numba import njit

from mav_observer.core.kernels.algebra import sym_eigvals
from mav_observer.core.kernels.layout import (
    C_COVERED,
    C_IDX,
    C_VALID,
    C_YY,
    CONVERGED,
    CONVERGING,
    NOT_OBSERVABLE,
    STALE,
)

#: A converged estimate's position sigma is at most this share of its range.
CONVERGED_SD_REL = 0.05


@njit(inline="always", error_model="numpy")
def _count(win) -> int:
    return int(win[win.shape[0] - 1, 0])


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _resum(win) -> None:
    """The totals again from the buckets (exact; done when buckets drop)."""
    tot = win.shape[0] - 1
    k = _count(win)
    for c in range(1, win.shape[1]):
        s = 0.0
        for i in range(k):
            s += win[i, c]
        win[tot, c] = s


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _bucket(win, t, bucket_s) -> int:
    """The row of the bucket holding time ``t``, created if new (the oldest dropped)."""
    buckets = win.shape[0] - 2
    tot = win.shape[0] - 1
    idx = math.floor(t / bucket_s)
    k = _count(win)
    if k > 0 and idx <= win[k - 1, C_IDX]:
        return k - 1  # same bucket, or (rounding at an edge) an older one: the newest
    win[k, :] = 0.0
    win[k, C_IDX] = idx
    k += 1
    cut = 0
    while cut < k and win[cut, C_IDX] <= idx - buckets:
        cut += 1
    if cut:
        for i in range(k - cut):
            win[i, :] = win[i + cut, :]
        k -= cut
        win[tot, 0] = k
        _resum(win)
    else:
        win[tot, 0] = k
    return k - 1


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def add_interval(win, t0, t1, yy, valid_s, window_s, bucket_s) -> None:
    """Account ``[t0, t1]``: ``valid_s`` of it had a usable bearing, over which ``yy`` is the
    integral of ``y y^T`` (n, n); an interval spanning buckets is shared out by time."""
    span = t1 - t0
    if span <= 0.0:
        return
    tot = win.shape[0] - 1
    n = yy.shape[0]
    idx = math.floor(t0 / bucket_s)
    k = _count(win)
    if k > 0 and win[k - 1, C_IDX] == idx and t1 <= (idx + 1) * bucket_s:
        _add(win, k - 1, tot, span, yy, valid_s, 1.0, n)  # the usual case: the newest bucket
        return
    t = max(t0, t1 - window_s)  # older parts would fall out anyway
    while t < t1:
        pos = _bucket(win, t, bucket_s)
        end = min(t1, (win[pos, C_IDX] + 1) * bucket_s)
        if end <= t:  # guard against rounding at a bucket edge
            end = t1
        dt = end - t
        _add(win, pos, tot, dt, yy, valid_s, dt / span, n)
        t = end


@njit(inline="always", error_model="numpy")
def _add(win, pos, tot, dt, yy, valid_s, f, n) -> None:
    win[pos, C_COVERED] += dt
    win[tot, C_COVERED] += dt
    if valid_s > 0.0:
        win[pos, C_VALID] += f * valid_s
        win[tot, C_VALID] += f * valid_s
        for i in range(n):
            for j in range(n):
                v = f * yy[i, j]
                win[pos, C_YY + i * n + j] += v
                win[tot, C_YY + i * n + j] += v


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def add_correction(win, t, dx, da, bucket_s) -> None:
    """The correction a step ending at ``t`` applied: ``dx`` (m), ``da`` (m/s)."""
    n = dx.shape[0]
    pos = _bucket(win, t, bucket_s)
    tot = win.shape[0] - 1
    ox = C_YY + n * n
    for i in range(n):
        win[pos, ox + i] += dx[i]
        win[tot, ox + i] += dx[i]
        win[pos, ox + n + i] += da[i]
        win[tot, ox + n + i] += da[i]


@njit(inline="always", error_model="numpy")
def covered(win) -> float:
    return win[win.shape[0] - 1, C_COVERED]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def excitation(win, n, avg, ev, work) -> float:
    """The smallest eigenvalue of the window's average of ``Pi_y`` (0 with no data);
    ``avg``, ``work`` (n, n) and ``ev`` (n,) scratch."""
    tot = win.shape[0] - 1
    cov = win[tot, C_COVERED]
    if cov <= 0.0:
        return 0.0
    for i in range(n):
        for j in range(n):
            avg[i, j] = -win[tot, C_YY + i * n + j] / cov
        avg[i, i] += win[tot, C_VALID] / cov
    sym_eigvals(avg, ev, work)
    return max(0.0, ev[0])


@njit(inline="always", error_model="numpy")
def correction_rel(win, n, range_m) -> float:
    tot = win.shape[0] - 1
    ox = C_YY + n * n
    ndx = 0.0
    nda = 0.0
    for i in range(n):
        ndx += win[tot, ox + i] ** 2
        nda += win[tot, ox + n + i] ** 2
    return (math.sqrt(ndx) + win[tot, C_COVERED] * math.sqrt(nda)) / max(range_m, 1e-9)


@njit(inline="always", error_model="numpy")
def shift(win, dt_s, bucket_s) -> None:
    """Move the window's contents ``dt_s`` later (whole buckets): an observer carried across
    a gap keeps the excitation it had seen."""
    k = round(dt_s / bucket_s)
    for i in range(_count(win)):
        win[i, C_IDX] += k


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def next_status(status, since, t, started, b_age, v_age, exc, cov, corr, settled,
                max_bearing_age_s, max_velocity_age_s, window_s, window_full_s,
                excitation_min, converged_tol, sd_rel, ranged) -> tuple[int, float]:  # fmt: skip
    """The status rules: the new ``(status, observable_since)`` from the previous ones
    (``since`` NaN: not observable now; an age NaN: no sample yet). ``sd_rel``: the position's
    1-sigma radius over the range (0 where the estimator has no covariance): an estimate
    whose own sigma is more than :data:`CONVERGED_SD_REL` of its range is not converged,
    however little it moves (a geometry that does not determine the range). ``ranged``: a
    range was measured with a recent bearing: the position is observed without motion, so
    neither the excitation nor the window's wait applies; converged on its sigma alone."""
    if (
        not started
        or math.isnan(b_age)
        or math.isnan(v_age)
        or b_age > max_bearing_age_s
        or v_age > max_velocity_age_s
    ):
        return STALE, math.nan
    hold = 2.0 if status == CONVERGED else 1.0
    if ranged:
        s = t if math.isnan(since) else since
        return (CONVERGED if sd_rel <= CONVERGED_SD_REL * hold else CONVERGING), s
    threshold = excitation_min * (2.0 if status == NOT_OBSERVABLE else 1.0)
    if cov >= window_full_s and exc < threshold:
        return NOT_OBSERVABLE, math.nan
    s = t if math.isnan(since) else since
    if (
        settled
        and t - s >= window_s
        and corr <= converged_tol * hold
        and (sd_rel <= CONVERGED_SD_REL * hold)
    ):
        return CONVERGED, s
    return CONVERGING, s
