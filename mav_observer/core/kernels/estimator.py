"""The estimator an observer drives (numba): the filter bank (the default) or the paper's
observer, behind the few calls :mod:`~mav_observer.core.kernels.observer` makes between and
at sample times: start, predict, update, output and what the monitor reads.

Around the bank (``docs/estimator.md``) this is where what it learns besides its state is
used: the velocity noise (the process noise on ``x``), the bearings' latency (each bearing
brought forward to its own time; the bias walk held while it is learnt) and the innovations'
correlation. No I/O, no clock.
"""

from __future__ import annotations

import math

from numba import njit

from mav_observer.core.kernels import bank, learners, paper, streams
from mav_observer.core.kernels.algebra import cond2, sym_eigvals
from mav_observer.core.kernels.layout import (
    B_AGE_S,
    B_COUNT,
    B_F,
    B_NIS_AVG,
    KIND_BANK,
    L_COUNT,
    L_TAU,
    O_BANK,
    O_BIASED,
    O_HOLD_COS,
    O_HOLD_SPEED2,
    O_INITIAL_RANGE_M,
    O_K,
    O_K_STAR,
    O_KIND,
    O_LATENCY_S,
    O_LINEAR,
    O_MAX_LATENCY_S,
    O_MAX_VELOCITY_AGE_S,
    O_N,
    O_RANGE_GUESS_M,
    O_STATIC_HOLD,
    O_VELOCITY_NOISE_MPS,
    O_VELOCITY_NOISE_PRIOR_MPS,
    O_WK_EST,
    OFF_BS,
    OFF_LAT,
    OFF_LOGW,
    OFF_Q,
    OFF_SET,
    OFF_VN,
    OFF_WH,
    P_COUNT,
    P_HYPOTHESES,
    P_LEARN_WALK,
    Q_COUNT,
    Q_VDT,
    R_AHAT,
    R_M,
    R_VN,
    R_WH_PREV,
    R_XH1,
    S_HELD,
    S_SETTLED,
    S_STARTED,
    S_T_BEARING,
    T_COUNT,
    V_COUNT,
    W_COUNT,
    W_HAS_PREV,
)

#: The error (m/s, as a white velocity noise) of a velocity interval whose mean comes from
#: the vehicle's positions: GNSS-aided positions do not accumulate the velocity's noise, and
#: successive intervals' displacements telescope.
CHORD_NOISE_MPS = 0.0003
#: The latency is learnt from a converged estimate only: this long after the bank's seeding
#: (s), its position variance below this share of the range, squared.
LATENCY_AFTER_S = 30.0
LATENCY_CONVERGED_REL = 0.05
#: The bias walk (learnt) waits for a learnt latency: off until it has been learning this
#: long (s; a lag not yet accounted for looks like a wandering bias) ...
WALK_AFTER_LATENCY_S = 30.0
#: ... but at most this long after the bank's seeding (s) ...
WALK_HOLD_MAX_S = 90.0
#: ... then held (leaving its level upward takes this lead, nats) until the latency settles.
WALK_HOLD_NATS = 60.0


@njit(inline="always", error_model="numpy")
def _bp(cfg):
    return cfg[O_BANK : O_BANK + P_COUNT]


@njit(inline="always", error_model="numpy")
def _bs(s):
    return s[OFF_BS : OFF_BS + B_COUNT]


@njit(inline="always", error_model="numpy")
def _logw(cfg, s):
    return s[OFF_LOGW : OFF_LOGW + int(cfg[O_BANK + P_HYPOTHESES])]


@njit(inline="always", error_model="numpy")
def _m(vec, n):
    return vec[R_M : R_M + n]


@njit(inline="always", error_model="numpy")
def velocity_noise_mps(cfg, s) -> float:
    """The white velocity noise in use (m/s per axis): learnt or told."""
    told = cfg[O_VELOCITY_NOISE_MPS]
    if not math.isnan(told):
        return told
    prior = cfg[O_VELOCITY_NOISE_PRIOR_MPS]
    return learners.vnoise_sigma(s[OFF_VN : OFF_VN + V_COUNT], prior)


@njit(inline="always", error_model="numpy")
def latency_s(cfg, s) -> float:
    """The bearings' latency in use (s): learnt or told."""
    told = cfg[O_LATENCY_S]
    return told if not math.isnan(told) else s[OFF_LAT + L_TAU]


@njit(inline="always", error_model="numpy")
def noise_var(cfg, s) -> float:
    """The bearing noise variance in use (rad^2)."""
    return bank.noise_var(_bs(s), _bp(cfg))


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def start(cfg, s, vec, fs, fp, t, y, r_meas) -> None:
    """Begin at ``t`` from the bearing ``y`` (of ``t`` or before), at the range ``r_meas``
    (m) measured with it when there is one (NaN: none)."""
    n = int(cfg[O_N])
    s[S_STARTED] = 1.0
    if cfg[O_KIND] == KIND_BANK:
        r0 = r_meas if r_meas > 0.0 else cfg[O_RANGE_GUESS_M]
        bank.start(fs, fp, _logw(cfg, s), _bs(s), _bp(cfg), y, r0)
        s[S_T_BEARING] = t
        return
    r = r_meas if r_meas > 0.0 else cfg[O_INITIAL_RANGE_M]
    if not math.isnan(r):  # xhat = M ahat + xh1 with ahat = 0
        for i in range(n):
            vec[R_XH1, i] = r * y[i]
            vec[R_AHAT, i] = 0.0


@njit(inline="always", error_model="numpy")
def substeps(cfg, span, corrected) -> int:
    if cfg[O_KIND] == KIND_BANK or not corrected:
        return 1
    return paper.substep_count(cfg[O_K], cfg[O_K_STAR], span)


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def predict(cfg, s, vec, fs, fp, vbuf, t, h, v, y, has_y, a_ref, moved, wk) -> None:
    """Propagate over the sub-step of ``h`` s centred on ``t`` with ``v`` and ``y`` (if
    ``has_y``) of its midpoint held; ``moved`` receives the open-loop displacement (what the
    model alone moved ``x`` by, with the bias ``a_ref`` of the step's start)."""
    n = v.shape[0]
    if cfg[O_KIND] == KIND_BANK:
        q = s[OFF_Q : OFF_Q + Q_COUNT]
        q_x = velocity_noise_mps(cfg, s) ** 2 * q[Q_VDT]
        if streams.chord_at(q, vbuf, t):
            q_x = min(q_x, CHORD_NOISE_MPS**2 * q[Q_VDT])
        if h > 0.0 and s[S_HELD] != 0.0:  # past a stale velocity (a gap): the held one's error
            q_x += streams.held_var_increment(q, vbuf, t, h) / h
        dx = wk[0:n]
        for i in range(n):
            dx[i] = v[i] * h
            moved[i] = h * v[i] + h * a_ref[i]
        bank.predict(fs, fp, _bs(s), _bp(cfg), dx, h, q_x)
        return
    xh1, ahat, m = vec[R_XH1], vec[R_AHAT], _m(vec, n)
    if (
        cfg[O_STATIC_HOLD] != 0.0
        and has_y
        and paper.is_static(xh1, m, ahat, v, y, cfg[O_HOLD_SPEED2], cfg[O_HOLD_COS], wk)
    ):
        moved[:] = 0.0
        return
    for i in range(n):
        moved[i] = h * (v[i] + ahat[i])
    paper.substep(xh1, m, ahat, y, has_y, v, cfg[O_K], cfg[O_K_STAR], h,
                  cfg[O_BIASED] != 0.0, wk)  # fmt: skip


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def output(cfg, s, vec, fs, fp, s_out, p_out, wk) -> bool:
    """The estimate at the current time: ``s_out`` = ``[x, a]`` (2n) and, for the bank,
    ``p_out`` its covariance (2n, 2n; returns whether there is one)."""
    n = int(cfg[O_N])
    if cfg[O_KIND] == KIND_BANK:
        if s[S_STARTED] == 0.0:
            s_out[:] = 0.0
            p_out[:, :] = math.inf
            return True
        bank.estimate(fs, fp, _logw(cfg, s), _bs(s), _bp(cfg), s_out, p_out, wk)
        return True
    paper.estimate(vec[R_XH1], _m(vec, n), vec[R_AHAT], s_out[:n])
    s_out[n:] = vec[R_AHAT]
    return False


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def mean(cfg, s, vec, fs, s_out) -> None:
    """The estimate ``[x, a]`` at the current time into ``s_out`` (what :func:`output`
    gives, without the covariance)."""
    n = int(cfg[O_N])
    if cfg[O_KIND] == KIND_BANK:
        if s[S_STARTED] == 0.0:
            s_out[:] = 0.0
        else:
            bank.mean_state(fs, _logw(cfg, s), _bs(s), s_out)
        return
    paper.estimate(vec[R_XH1], _m(vec, n), vec[R_AHAT], s_out[:n])
    s_out[n:] = vec[R_AHAT]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def position_cov(cfg, s, p, dt, sparse, pxx) -> None:
    """The covariance of ``x`` (n, n) predicted ``dt`` s ahead of the covariance ``p`` of
    ``[x, a]`` with the velocity held: the bias's uncertainty grows it, and the velocity
    noise's (but for a sparse stream's, whose trend's error the caller adds)."""
    n = pxx.shape[0]
    if dt <= 0.0:
        pxx[:, :] = p[:n, :n]
        return
    q = 0.0
    if not sparse:
        q = velocity_noise_mps(cfg, s) ** 2 * s[OFF_Q + Q_VDT]
    for i in range(n):
        for j in range(n):
            pxx[i, j] = (
                p[i, j] + dt * (p[i, n + j] + p[n + i, j]) + dt * dt * p[n + i, n + j]
                + (q * dt if i == j else 0.0)
            )  # fmt: skip


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def cond(cfg, s, vec, p, wk) -> float:
    """The condition number of the position's information (the bank: of its covariance's
    position block; the paper: of ``M``); 1 before the start."""
    n = int(cfg[O_N])
    if s[S_STARTED] == 0.0 and cfg[O_KIND] == KIND_BANK:
        return 1.0
    a = wk[0 : n * n].reshape((n, n))
    ev = wk[n * n : n * n + n]
    work = wk[n * n + n : 2 * n * n + n].reshape((n, n))
    if cfg[O_KIND] == KIND_BANK:
        for i in range(n):
            for j in range(n):
                a[i, j] = p[i, j]
        sym_eigvals(a, ev, work)
        return ev[n - 1] / ev[0] if ev[0] > 0.0 else math.inf
    return cond2(_m(vec, n), a, ev, work)


@njit(inline="always", error_model="numpy")
def nis(cfg, s) -> float:
    """The recent NIS per degree of freedom (NaN: none)."""
    if cfg[O_KIND] != KIND_BANK or s[S_STARTED] == 0.0:
        return math.nan
    return s[OFF_BS + B_NIS_AVG] / (cfg[O_N] - 1.0)


@njit(inline="always", error_model="numpy")
def settled(cfg, s) -> bool:
    """Nothing learnt still moves the estimate for long: the latency learnt has settled once
    (always with a latency told, and for the paper's observer)."""
    if cfg[O_KIND] != KIND_BANK or not math.isnan(cfg[O_LATENCY_S]):
        return True
    return s[S_SETTLED] != 0.0


@njit(inline="always", error_model="numpy")
def observe_velocity(cfg, s, vec, t, v) -> None:
    """A velocity sample accepted: the velocity noise learns from it."""
    if cfg[O_KIND] == KIND_BANK and math.isnan(cfg[O_VELOCITY_NOISE_MPS]):
        vn = s[OFF_VN : OFF_VN + V_COUNT]
        learners.vnoise_update(vn, vec[R_VN : R_VN + 4], t, v, cfg[O_VELOCITY_NOISE_PRIOR_MPS])


@njit(inline="always", error_model="numpy")
def shift(cfg, vec, fs, dx) -> None:
    """Move the position estimate by ``dx`` (m), across a gap in the data."""
    n = dx.shape[0]
    if cfg[O_KIND] == KIND_BANK:
        for r in range(fs.shape[0]):
            for i in range(n):
                fs[r, i] += dx[i]
        return
    for i in range(n):
        vec[R_XH1, i] += dx[i]


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def update(cfg, s, vec, fs, fp, vbuf, t, y, wk) -> None:
    """The bearing sample ``y`` of time ``t`` (the paper's observer corrects continuously,
    in :func:`predict`, and does nothing here)."""
    if cfg[O_KIND] != KIND_BANK:
        return
    n = y.shape[0]
    bs, bp = _bs(s), _bp(cfg)
    lat = s[OFF_LAT : OFF_LAT + L_COUNT]
    gap = 0.0 if math.isnan(s[S_T_BEARING]) else t - s[S_T_BEARING]
    age = bs[B_AGE_S]
    tau = latency_s(cfg, s)
    learnt = math.isnan(cfg[O_LATENCY_S])
    hold = False
    hold_nats = WALK_HOLD_NATS
    if learnt:
        learning = learners.latency_learning_for(lat, t)
        ok = learners.settling_update(s[OFF_SET : OFF_SET + T_COUNT], t, tau, learning)
        if ok or (learning == 0.0 and age >= WALK_HOLD_MAX_S):
            s[S_SETTLED] = 1.0
        if bp[P_LEARN_WALK] != 0.0:  # the walk waits for the latency
            if learning < WALK_AFTER_LATENCY_S and age < WALK_HOLD_MAX_S:
                hold, hold_nats = True, math.inf
            elif not ok:
                hold = True
    # scratch: the bank's from 0, this function's after it
    o = int(cfg[O_WK_EST])
    d2 = 2 * n
    st = wk[o : o + d2]
    p = wk[o + d2 : o + d2 + d2 * d2].reshape((d2, d2))
    v = wk[o + d2 + d2 * d2 : o + 2 * d2 + d2 * d2][:n]
    y_use = wk[o + 3 * d2 + d2 * d2 : o + 4 * d2 + d2 * d2][:n]
    y_use[:] = y
    learns = learnt and age > LATENCY_AFTER_S
    f = int(bs[B_F])
    if learns or tau != 0.0:
        q = s[OFF_Q : OFF_Q + Q_COUNT]
        streams.velocity_at(q, vbuf, t, cfg[O_LINEAR] != 0.0, cfg[O_MAX_VELOCITY_AGE_S], v)
        bank.mean_state(fs, _logw(cfg, s), bs, st)
        x, a = st[:n], st[n:]
        if learns:
            var_x = 0.0
            if f == 1:
                for j in range(n):
                    var_x += fp[0, j, j]
            else:
                bank.estimate(fs, fp, _logw(cfg, s), bs, bp, st, p, wk)
                for j in range(n):
                    var_x += p[j, j]
            r2 = 0.0
            for j in range(n):
                r2 += x[j] * x[j]
            if var_x < LATENCY_CONVERGED_REL**2 * r2:
                learners.latency_observe(lat, t, x, a, v, y, noise_var(cfg, s),
                                         cfg[O_MAX_LATENCY_S])  # fmt: skip
        if tau != 0.0:  # the line of sight tau earlier, brought to t
            learners.advance(y, x, a, v, tau, y_use)
    wh = s[OFF_WH : OFF_WH + W_COUNT]
    if f == 1:  # the innovation of the one filter, in units of the noise in use
        r = 0.0
        for j in range(n):
            r += fs[0, j] * fs[0, j]
        r = math.sqrt(r)
        if r > 0.0:
            c = 0.0
            for j in range(n):
                c += y_use[j] * fs[0, j] / r
            k = 1.0 / math.sqrt(noise_var(cfg, s))
            z = st[:n]
            for j in range(n):
                z[j] = (y_use[j] - c * fs[0, j] / r) * k
            learners.whiteness_add(wh, vec[R_WH_PREV], t, z)
    else:
        wh[W_HAS_PREV] = 0.0
    q = s[OFF_Q : OFF_Q + Q_COUNT]
    shape = streams.shape_var(q, vbuf, t, cfg[O_MAX_VELOCITY_AGE_S])
    bank.update(fs, fp, _logw(cfg, s), bs, bp, y_use, gap, hold, hold_nats, shape, wk)
    s[S_T_BEARING] = t


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def update_range(cfg, s, fs, fp, r_meas, var, wk) -> None:
    """The range ``r_meas`` (m, variance ``var``) measured with the bearing just applied (the
    paper's observer has no use for it)."""
    if cfg[O_KIND] == KIND_BANK:
        bank.update_range(fs, fp, _logw(cfg, s), _bs(s), _bp(cfg), r_meas, var, wk)
