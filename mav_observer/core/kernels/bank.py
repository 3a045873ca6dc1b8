"""The default estimator's filter bank, one run, compiled (numba): the only implementation.

A run is a few Kalman filters on ``s = [x, a]`` (2n): the range hypotheses (``hypotheses`` at
the start, one once they have been pruned and merged), the Riccati observer that supervises
them and, while the bias's random walk is learnt, two probes. The maths is in
``docs/estimator.md``; this module is the code of it, called once per velocity interval
(:func:`predict`) and once per bearing (:func:`update`). The Monte Carlo harness runs the
same functions over its runs (`bench/accuracy/bankruns.py`).

State of one run, in arrays the caller owns (:mod:`mav_observer.core.kernels.layout` lays them out):

* ``fs`` (rows, 2n): the filters' states; rows ``0 .. F-1`` the hypotheses still alive (in
  their order), row ``H`` (:func:`pilot`) the Riccati observer, ``H + 1`` and ``H + 2`` the
  walk's probes (one level down, one up); ``fp`` (rows, 2n, 2n) their covariances, ``logw``
  (H,) the hypotheses' log weights;
* ``bs``: the run's scalars (``B_*`` below); ``bp``: the settings (``P_*`` below);
* ``wk``: scratch (``mav_observer.core.state.bank_scratch_size`` floats).

Units: m, m/s, s; the bearing noise in rad. No I/O, no clock.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from mav_observer.core.kernels.algebra import carve, mahalanobis2, solve
from mav_observer.core.kernels.kalman import (
    R_LOGDET,
    R_NIS,
    R_STAT,
    R_WEIGHT,
    initial_covariance,
    mirror,
    predict_filter,
    range_update,
    update_filter,
)
from mav_observer.core.kernels.layout import (
    B_AGE_S,
    B_BEARINGS,
    B_COUNT,
    B_F,
    B_INLIER_AVG,
    B_NIS_AVG,
    B_NOISE_ALPHA,
    B_NOISE_BETA,
    B_OUTLIERS,
    B_R0,
    B_RESEEDS,
    B_WALK_LL_HI,
    B_WALK_LL_LO,
    B_WALK_ON,
    B_WALK_Q,
    P_BIAS_STD,
    P_HYPOTHESES,
    P_LEARN_NOISE,
    P_LEARN_WALK,
    P_MERGE_MAHA,
    P_NIS_GATE,
    P_NIS_WINDOW_S,
    P_NOISE_MAX_RAD,
    P_NOISE_MEMORY_S,
    P_NOISE_MIN_RAD,
    P_NOISE_PRIOR_DOF,
    P_OUTLIER_NIS,
    P_PRUNE,
    P_PRUNE_EARLY,
    P_PRUNE_EARLY_S,
    P_Q_A,
    P_RANGE_REL_STD,
    P_SIGMA_RAD,
    P_SPAN,
    P_WALK_DOWN_NATS,
    P_WALK_FACTOR,
    P_WALK_JUMP,
    P_WALK_LEAVE_NATS,
    P_WALK_MAX,
    P_WALK_MEMORY_S,
    P_WALK_MIN,
    P_WALK_UP_NATS,
    P_WALK_WARMUP_S,
)

#: A bearing's noise statistic counts at most this many times its expected value
#: (``(n - 1)`` times the variance in use).
NOISE_CLIP = 4.0
#: Below this share of bearings within the robust threshold the noise in use is taken to
#: be too small and every bearing counts in learning it (``docs/estimator.md``).
INLIER_SHARE_MIN = 0.5
#: The most one bearing weighs in the innovations' running mean (a share of its window):
#: a gap in the bearings is no evidence, so the first bearing after one cannot alone
#: re-seed a consistent bank.
NIS_MAX_WEIGHT = 0.1


@njit(inline="always", error_model="numpy")
def pilot(bp) -> int:
    """The row of the Riccati observer (after the hypotheses' rows)."""
    return int(bp[P_HYPOTHESES])


@njit(inline="always", error_model="numpy")
def noise_var(bs, bp) -> float:
    """The bearing noise variance in use (rad^2): learnt or told."""
    if bp[P_LEARN_NOISE] == 0.0:
        return bp[P_SIGMA_RAD] ** 2
    v = bs[B_NOISE_BETA] / bs[B_NOISE_ALPHA]
    return min(max(v, bp[P_NOISE_MIN_RAD] ** 2), bp[P_NOISE_MAX_RAD] ** 2)


@njit(inline="always", error_model="numpy")
def bias_walk(bs, bp) -> float:
    """The bias's random-walk intensity in use (m^2/s^3)."""
    return bs[B_WALK_Q] if bp[P_LEARN_WALK] != 0.0 else bp[P_Q_A]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _seed(fs, fp, logw, y, centre, a0, sigma, bp) -> None:
    """The hypotheses around ``centre`` (m) along ``y`` with bias ``a0`` and bearing noise
    ``sigma`` (rad): rows ``0 .. H-1``, prior weights proportional to ``1/sqrt(range)``."""
    n = y.shape[0]
    hyp = int(bp[P_HYPOTHESES])
    span = bp[P_SPAN]
    top = -math.inf
    for k in range(hyp):
        u = -1.0 + 2.0 * k / (hyp - 1) if hyp > 1 else 0.0
        rk = centre * span**u
        for i in range(n):
            fs[k, i] = rk * y[i]
            fs[k, n + i] = a0[i]
        initial_covariance(y, rk, bp[P_RANGE_REL_STD] * rk, bp[P_BIAS_STD], sigma, fp[k])
        logw[k] = -0.5 * math.log(rk)
        top = max(top, logw[k])
    total = 0.0
    for k in range(hyp):
        total += math.exp(logw[k] - top)
    lse = top + math.log(total)
    for k in range(hyp):
        logw[k] -= lse


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def start(fs, fp, logw, bs, bp, y, r0) -> None:
    """A run started at its first bearing ``y`` with the range guess ``r0`` (m): the bank
    spans ``r0 / span`` to ``r0 * span``; the Riccati observer starts at ``r0 y`` with a
    range standard deviation of ``3 r0``."""
    n = y.shape[0]
    bs[:] = 0.0
    fs[:, :] = 0.0
    fp[:, :, :] = 0.0
    sigma = bp[P_SIGMA_RAD]
    zero = fs[pilot(bp), n:]  # (zeros: the pilot's bias, filled below)
    _seed(fs, fp, logw, y, r0, zero, sigma, bp)
    h = pilot(bp)
    for i in range(n):
        fs[h, i] = r0 * y[i]
        fs[h, n + i] = 0.0
    initial_covariance(y, r0, 3.0 * r0, bp[P_BIAS_STD], sigma, fp[h])
    bs[B_F] = bp[P_HYPOTHESES]
    bs[B_R0] = r0
    bs[B_NIS_AVG] = n - 1.0
    alpha0 = 0.5 * bp[P_NOISE_PRIOR_DOF]
    bs[B_NOISE_ALPHA] = alpha0
    bs[B_NOISE_BETA] = alpha0 * sigma * sigma
    bs[B_INLIER_AVG] = 1.0


@njit(inline="always", error_model="numpy")
def walk_levels(q, bp) -> tuple[float, float]:
    """The probes' ``q_a`` around ``q``: one level down (0 below ``walk_min``; at 0, the
    jump ``walk_jump``) and one up (at least ``walk_min``, at most ``walk_max``)."""
    lo = q / bp[P_WALK_FACTOR]
    hi = min(max(q * bp[P_WALK_FACTOR], bp[P_WALK_MIN]), bp[P_WALK_MAX])
    if q <= 0.0:
        return bp[P_WALK_JUMP], hi
    return (0.0 if lo < bp[P_WALK_MIN] else lo), hi


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def predict(fs, fp, bs, bp, dx, h, q_x) -> None:
    """Every filter of the run over ``h`` s with the integral ``dx`` of ``v`` (m) and the
    process noise ``q_x`` (m^2/s) on ``x``; the probes only while they run."""
    probes = bp[P_LEARN_WALK] != 0.0 and bs[B_WALK_ON] > 0.0
    q = bs[B_WALK_Q] if probes else bp[P_Q_A]
    f = int(bs[B_F])
    for i in range(f):
        predict_filter(fs[i], fp[i], dx, h, q_x, q)
    hp = pilot(bp)
    predict_filter(fs[hp], fp[hp], dx, h, q_x, q)
    if probes:
        lo, hi = walk_levels(q, bp)
        predict_filter(fs[hp + 1], fp[hp + 1], dx, h, q_x, lo)
        predict_filter(fs[hp + 2], fp[hp + 2], dx, h, q_x, hi)
    bs[B_AGE_S] += h


@njit(inline="always", error_model="numpy")
def _copy_filter(fs, fp, src, dst) -> None:
    fs[dst, :] = fs[src, :]
    fp[dst, :, :] = fp[src, :, :]


@njit(inline="always", error_model="numpy")
def _start_probes(fs, fp, bs, bp) -> None:
    hp = pilot(bp)
    _copy_filter(fs, fp, 0, hp + 1)
    _copy_filter(fs, fp, 0, hp + 2)
    bs[B_WALK_LL_LO] = 0.0
    bs[B_WALK_LL_HI] = 0.0


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _walk_step(fs, fp, bs, bp, nis, logdet, nis_lo, logdet_lo, nis_hi, logdet_hi, h,
               walk_hold, walk_hold_nats) -> None:  # fmt: skip
    """Learn the bias's random walk by likelihood (``docs/estimator.md``): the filter
    against its two probes on the same bearings; a probe leading by enough nats becomes the
    filter and its level the one in use."""
    g = bp[P_OUTLIER_NIS]
    if nis > g or nis_lo > g or nis_hi > g:  # a gross error: neutral
        diff_lo = diff_hi = 0.0
    else:
        ll0 = -0.5 * (nis + logdet)
        diff_lo = -0.5 * (nis_lo + logdet_lo) - ll0
        diff_hi = -0.5 * (nis_hi + logdet_hi) - ll0
    rho = math.exp(-max(h, 0.0) / bp[P_WALK_MEMORY_S])
    lead_lo = rho * bs[B_WALK_LL_LO] + diff_lo
    lead_hi = rho * bs[B_WALK_LL_HI] + diff_hi
    q = bs[B_WALK_Q]
    bar = bp[P_WALK_UP_NATS] if q > 0.0 else bp[P_WALK_LEAVE_NATS]
    if walk_hold and q == 0.0:  # leaving 0 is held
        bar = max(bar, walk_hold_nats)
    if q > 0.0:
        lo_bar = bp[P_WALK_DOWN_NATS]
    elif bp[P_WALK_JUMP] > 0.0 and not walk_hold:  # at 0 the lower probe is the jump
        lo_bar = bp[P_WALK_LEAVE_NATS]
    else:
        lo_bar = math.inf
    if (lead_hi > bar and q < bp[P_WALK_MAX]
            and not (q <= 0.0 and lead_lo > max(lo_bar, lead_hi))):  # fmt: skip
        k = 1
    elif lead_lo > lo_bar:
        k = 0
    else:
        bs[B_WALK_LL_LO] = lead_lo
        bs[B_WALK_LL_HI] = lead_hi
        return
    lo, hi = walk_levels(q, bp)
    bs[B_WALK_Q] = hi if k == 1 else lo
    _copy_filter(fs, fp, pilot(bp) + 1 + k, 0)
    _start_probes(fs, fp, bs, bp)


@njit(inline="always", error_model="numpy")
def _logsumexp(v, count) -> float:
    top = -math.inf
    for i in range(count):
        top = max(top, v[i])
    s = 0.0
    for i in range(count):
        s += math.exp(v[i] - top)
    return top + math.log(s)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _select(fs, fp, logw, bs, keep) -> None:
    """Keep the hypotheses whose ``keep`` is nonzero (in order), weights renormalised."""
    f = int(bs[B_F])
    j = 0
    for i in range(f):
        if keep[i] != 0.0:
            if j != i:
                _copy_filter(fs, fp, i, j)
                logw[j] = logw[i]
            j += 1
    bs[B_F] = j
    lse = _logsumexp(logw, j)
    for i in range(j):
        logw[i] -= lse


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _merge(fs, fp, logw, bs, bp, wk) -> None:
    """Merge every hypothesis within ``merge_maha`` (squared Mahalanobis distance under the
    sum of the two covariances) of the heaviest into it, moments matched."""
    f = int(bs[B_F])
    d2 = fs.shape[1]
    kmax = 0
    for i in range(1, f):
        if logw[i] > logw[kmax]:
            kmax = i
    o = 0
    diff, o = carve(wk, o, d2)
    acov, o = carve(wk, o, d2 * d2)
    acov = acov.reshape((d2, d2))
    low, o = carve(wk, o, d2 * d2)
    low = low.reshape((d2, d2))
    zv, o = carve(wk, o, d2)
    gauss, o = carve(wk, o, d2 * (d2 + 1))
    gauss = gauss.reshape((d2, d2 + 1))
    close, o = carve(wk, o, f)
    mean, o = carve(wk, o, d2)
    acc, o = carve(wk, o, d2 * d2)
    acc = acc.reshape((d2, d2))
    bar = bp[P_MERGE_MAHA]
    any_close = False
    for i in range(f):
        close[i] = 0.0
        if i == kmax:
            continue
        for j in range(d2):
            diff[j] = fs[i, j] - fs[kmax, j]
        for a in range(d2):
            for b in range(d2):
                acov[a, b] = fp[i, a, b] + fp[kmax, a, b]
        m2 = mahalanobis2(diff, acov, low, zv)
        if math.isnan(m2):  # not numerically positive definite: a pivoting solve decides
            for j in range(d2):
                zv[j] = diff[j]
            if solve(acov, zv, gauss):
                m2 = 0.0
                for j in range(d2):
                    m2 += diff[j] * zv[j]
            else:
                m2 = math.inf
        if m2 < bar:
            close[i] = 1.0
            any_close = True
    if not any_close:
        return
    total = 0.0
    for i in range(f):
        if i == kmax or close[i] != 0.0:
            total += math.exp(logw[i])
    mean[:] = 0.0
    for i in range(f):
        if i == kmax or close[i] != 0.0:
            w = math.exp(logw[i])
            for j in range(d2):
                mean[j] += w * fs[i, j]
    for j in range(d2):
        mean[j] /= total
    acc[:, :] = 0.0
    for i in range(f):
        if i == kmax or close[i] != 0.0:
            w = math.exp(logw[i])
            for j in range(d2):
                diff[j] = fs[i, j] - mean[j]
            for a in range(d2):
                for b in range(a, d2):
                    acc[a, b] += w * fp[i, a, b] + w * diff[a] * diff[b]
    for a in range(d2):
        fs[kmax, a] = mean[a]
        for b in range(a, d2):
            fp[kmax, a, b] = acc[a, b] / total
    mirror(fp[kmax])
    logw[kmax] = math.log(total)
    for i in range(f):
        close[i] = 0.0 if close[i] != 0.0 else 1.0  # keep the others
    _select(fs, fp, logw, bs, close)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def reseed(fs, fp, logw, bs, bp, y) -> None:
    """Replace the hypotheses by a new bank around the Riccati observer's range (its
    estimate converges from anywhere) at the bearing ``y``."""
    n = y.shape[0]
    hp = pilot(bp)
    rp = 0.0
    for i in range(n):
        rp += fs[hp, i] * fs[hp, i]
    rp = math.sqrt(rp)
    centre = rp if rp > 0.0 else bs[B_R0]
    sigma = math.sqrt(noise_var(bs, bp))
    _seed(fs, fp, logw, y, centre, fs[hp, n:], sigma, bp)
    bs[B_F] = bp[P_HYPOTHESES]
    bs[B_NIS_AVG] = n - 1.0
    bs[B_AGE_S] = 0.0
    bs[B_RESEEDS] += 1.0
    if bp[P_LEARN_NOISE] != 0.0:
        # what was learnt while the filters disagreed with the bearings is suspect: the
        # level is kept, weighing as the prior
        alpha0 = 0.5 * bp[P_NOISE_PRIOR_DOF]
        bs[B_NOISE_BETA] = bs[B_NOISE_BETA] / bs[B_NOISE_ALPHA] * alpha0
        bs[B_NOISE_ALPHA] = alpha0


@njit(inline="always", error_model="numpy")
def _with_shape(var, shape_m2, s, n) -> float:
    """The bearing noise (rad^2) plus a position variance ``shape_m2`` (m^2) seen from the
    filter's range (at least 1 m)."""
    if shape_m2 == 0.0:
        return var
    r2 = 0.0
    for j in range(n):
        r2 += s[j] * s[j]
    return var + shape_m2 / max(r2, 1.0)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def update(fs, fp, logw, bs, bp, y, h, walk_hold, walk_hold_nats, shape_m2, wk) -> None:
    """The bearing ``y`` (unit), ``h`` s after the previous one, applied to the run: every
    hypothesis in tracking form, weights by likelihood, the Riccati observer in acquisition
    form, the probes; then the walk, the noise learnt, prune, merge, and a re-seeding when
    the innovations stay inconsistent. ``walk_hold`` / ``walk_hold_nats``: the walk held
    while the bearings' latency is being learnt (``inf``: no probe runs). ``shape_m2``: the
    variance (m^2 per axis) of the vehicle's position at this bearing inside a telemetry gap,
    added to each filter's bearing noise at its range (such a bearing teaches no noise)."""
    n = y.shape[0]
    m = n - 1
    g = bp[P_OUTLIER_NIS]
    var = noise_var(bs, bp)
    f = int(bs[B_F])
    hyp = int(bp[P_HYPOTHESES])
    hp = hyp
    res = wk[0 : 4 * (hyp + 3)].reshape((hyp + 3, 4))
    kw = wk[4 * (hyp + 3) :]
    for i in range(f):
        update_filter(fs[i], fp[i], y, _with_shape(var, shape_m2, fs[i], n), 0.0, g, kw, res[i])
    update_filter(fs[hp], fp[hp], y, _with_shape(var, shape_m2, fs[hp], n), bs[B_R0], g, kw,
                  res[hp])  # fmt: skip
    probes = bp[P_LEARN_WALK] != 0.0 and bs[B_WALK_ON] > 0.0
    robust = res[hp, R_WEIGHT] < 1.0
    if probes:
        for k in (hp + 1, hp + 2):
            update_filter(fs[k], fp[k], y, _with_shape(var, shape_m2, fs[k], n), 0.0, g, kw,
                          res[k])  # fmt: skip
        robust = robust or res[hp + 1, R_WEIGHT] < 1.0 or res[hp + 2, R_WEIGHT] < 1.0
    if bp[P_LEARN_WALK] != 0.0:
        off = walk_hold and not math.isfinite(walk_hold_nats)
        if off or f != 1 or not bs[B_AGE_S] > bp[P_WALK_WARMUP_S]:
            bs[B_WALK_ON] = 0.0
        elif probes:
            _walk_step(fs, fp, bs, bp, res[0, R_NIS], res[0, R_LOGDET],
                       res[hp + 1, R_NIS], res[hp + 1, R_LOGDET],
                       res[hp + 2, R_NIS], res[hp + 2, R_LOGDET], h,
                       walk_hold, walk_hold_nats)  # fmt: skip
        else:  # the probes start as copies of the filter
            _start_probes(fs, fp, bs, bp)
            bs[B_WALK_ON] = 1.0
    w_prior = kw[0:f]
    stat = 0.0
    if f == 1:  # the converged run: its one filter weighs 1
        mix_nis = min(res[0, R_NIS], g)
        w_run = res[0, R_WEIGHT]
        inlier_share = 1.0 if res[0, R_WEIGHT] >= 1.0 else 0.0
    else:
        for i in range(f):
            w_prior[i] = math.exp(logw[i])
            robust = robust or res[i, R_WEIGHT] < 1.0
        floor = g + m * math.log(var)
        for i in range(f):
            loss = res[i, R_NIS] + res[i, R_LOGDET]
            if robust:
                loss = min(loss, floor)
            logw[i] -= 0.5 * loss
        lse = _logsumexp(logw, f)
        for i in range(f):
            logw[i] -= lse
        mix_nis = 0.0
        w_run = 0.0
        inlier_share = 0.0
        for i in range(f):
            mix_nis += w_prior[i] * min(res[i, R_NIS], g)
            w_run += w_prior[i] * res[i, R_WEIGHT]
            if res[i, R_WEIGHT] >= 1.0:
                inlier_share += w_prior[i]
    bs[B_NIS_AVG] += min(NIS_MAX_WEIGHT, h / bp[P_NIS_WINDOW_S]) * (mix_nis - bs[B_NIS_AVG])
    bs[B_BEARINGS] += 1.0
    if w_run < 0.5:
        bs[B_OUTLIERS] += 1.0
    if bp[P_LEARN_NOISE] != 0.0 and shape_m2 == 0.0:
        beta_ = min(1.0, max(h, 0.0) / bp[P_NIS_WINDOW_S])
        bs[B_INLIER_AVG] += beta_ * (inlier_share - bs[B_INLIER_AVG])
        all_in = bs[B_INLIER_AVG] >= INLIER_SHARE_MIN
        if f == 1:
            stat = res[0, R_STAT]
            if res[0, R_WEIGHT] < 1.0 and all_in:
                stat = m * var
        else:
            for i in range(f):
                use = res[i, R_WEIGHT] >= 1.0 or not all_in
                stat += w_prior[i] * (res[i, R_STAT] if use else m * var)
        stat = min(stat, NOISE_CLIP * m * var)
        rho = math.exp(-max(h, 0.0) / bp[P_NOISE_MEMORY_S])
        bs[B_NOISE_ALPHA] = rho * bs[B_NOISE_ALPHA] + 0.5 * m
        bs[B_NOISE_BETA] = rho * bs[B_NOISE_BETA] + 0.5 * stat
    if f > 1:
        early = bs[B_AGE_S] < bp[P_PRUNE_EARLY_S] and bs[B_RESEEDS] == 0.0
        floor_w = bp[P_PRUNE_EARLY] if early else bp[P_PRUNE]
        keep = kw[0:f]
        pruned = False
        for i in range(f):
            keep[i] = 1.0 if math.exp(logw[i]) >= floor_w else 0.0
            pruned = pruned or keep[i] == 0.0
        if pruned:
            _select(fs, fp, logw, bs, keep)
        if bs[B_F] > 1:
            _merge(fs, fp, logw, bs, bp, kw)
    if bs[B_NIS_AVG] > bp[P_NIS_GATE] * m and bs[B_AGE_S] > 2.0 * bp[P_NIS_WINDOW_S]:
        reseed(fs, fp, logw, bs, bp, y)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def update_range(fs, fp, logw, bs, bp, r_meas, var, wk) -> None:
    """A range ``r_meas`` (m) of variance ``var`` (m^2), measured with the bearing just applied
    (a rangefinder on the gimbal), applied to every hypothesis, the Riccati observer and the
    probes; the hypotheses' weights by its likelihood (robust as a bearing's)."""
    g = bp[P_OUTLIER_NIS]
    f = int(bs[B_F])
    hp = int(bp[P_HYPOTHESES])
    res = wk[0 : 4 * (hp + 3)].reshape((hp + 3, 4))
    kw = wk[4 * (hp + 3) :]
    for i in range(f):
        range_update(fs[i], fp[i], r_meas, var, g, kw, res[i])
    last = hp + 3 if bp[P_LEARN_WALK] != 0.0 and bs[B_WALK_ON] > 0.0 else hp + 1
    for k in range(hp, last):
        range_update(fs[k], fp[k], r_meas, var, g, kw, res[k])
    if f > 1:
        floor = g + math.log(var)
        for i in range(f):
            logw[i] -= 0.5 * min(res[i, R_NIS] + res[i, R_LOGDET], floor)
        lse = _logsumexp(logw, f)
        for i in range(f):
            logw[i] -= lse


@njit(inline="always", error_model="numpy")
def mean_state(fs, logw, bs, out) -> None:
    """The run's ``[x, a]`` into ``out`` (2n): the mixture's mean."""
    f = int(bs[B_F])
    if f == 1:
        out[:] = fs[0, :]
        return
    out[:] = 0.0
    for k in range(f):
        w = math.exp(logw[k])
        for j in range(out.shape[0]):
            out[j] += w * fs[k, j]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def estimate(fs, fp, logw, bs, bp, s_out, p_out, wk) -> None:
    """The run's estimate: ``s_out`` (2n) the mixture's mean, ``p_out`` (2n, 2n) its
    covariance, the hypotheses' spread included; with one filter whose probes run, its mean
    and the covariance over the walk's three levels (the filter and its probes weighted by
    their likelihood over the walk's memory, each with its spread about the filter's mean)."""
    f = int(bs[B_F])
    d2 = fs.shape[1]
    diff = wk[0:d2]
    mean_state(fs, logw, bs, s_out)
    p_out[:, :] = 0.0
    if f == 1 and bs[B_WALK_ON] > 0.0:
        hp = pilot(bp)
        lo, hi = bs[B_WALK_LL_LO], bs[B_WALK_LL_HI]
        top = max(0.0, lo, hi)
        w0, w1, w2 = math.exp(-top), math.exp(lo - top), math.exp(hi - top)
        t = 1.0 / (w0 + w1 + w2)
        _spread_add(p_out, fp[0], w0 * t, fs[0], s_out, diff)
        _spread_add(p_out, fp[hp + 1], w1 * t, fs[hp + 1], s_out, diff)
        _spread_add(p_out, fp[hp + 2], w2 * t, fs[hp + 2], s_out, diff)
    elif f == 1:
        p_out[:, :] = fp[0, :, :]
        return
    else:
        for k in range(f):
            _spread_add(p_out, fp[k], math.exp(logw[k]), fs[k], s_out, diff)
    mirror(p_out)


@njit(inline="always", error_model="numpy")
def _spread_add(acc, p, w, s, mean, diff) -> None:
    """``acc += w (P + d d^T)``, ``d = s - mean``, on the upper triangle."""
    d2 = s.shape[0]
    for j in range(d2):
        diff[j] = s[j] - mean[j]
    for a in range(d2):
        for b in range(a, d2):
            acc[a, b] += w * p[a, b] + w * diff[a] * diff[b]


def new_arrays(n: int, hypotheses: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Zeroed ``(fs, fp, logw, bs)`` of one run."""
    rows = hypotheses + 3
    return (
        np.zeros((rows, 2 * n)),
        np.zeros((rows, 2 * n, 2 * n)),
        np.zeros(hypotheses),
        np.zeros(B_COUNT),
    )
