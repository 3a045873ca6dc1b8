"""One observer's per-sample work (numba): the entry points the Python
:class:`~mav_observer.core.observer.BiasObserver` calls once per sample.

The observer keeps a committed state at the latest time both streams cover (the data
horizon), stepped from interval to interval between the sample times: sub-steps of
prediction with the inputs at their midpoints, an update at each bearing, the monitor's
window fed with the excitation and the corrections. Estimates at later times are
predictions from it, never committed, so late samples still count (``docs/observer.md``).
Every entry point takes the observer's arrays (:mod:`~mav_observer.core.kernels.layout`)
and returns a code: ``>= 0`` the committed estimates it wrote into ``out`` (rows from 0),
``< 0`` an ``ERR_*`` (the sample was refused, nothing changed). A live estimate goes into
``out``'s last row. No I/O, no clock.
"""

from __future__ import annotations

import math

from numba import njit

from mav_observer.core.kernels import estimator, kalman, monitor, streams
from mav_observer.core.kernels.algebra import carve
from mav_observer.core.kernels.layout import (
    A_BBUF,
    A_CFG,
    A_FP,
    A_FS,
    A_OUT,
    A_S,
    A_VBUF,
    A_VEC,
    A_WIN,
    A_WK,
    E_BEARING_AGE,
    E_COND,
    E_CORRECTED,
    E_CORRECTION_REL,
    E_EXCITATION,
    E_FIXED,
    E_HAS_COV,
    E_NIS,
    E_RANGE,
    E_RANGE_STD,
    E_STATUS,
    E_T,
    E_VELOCITY_AGE,
    ERR_BEARING_BACKWARDS,
    ERR_BEARING_TOO_OLD,
    ERR_BEFORE_COMMITTED,
    ERR_BUFFER_FULL,
    ERR_VELOCITY_BACKWARDS,
    O_ARRAYS,
    O_BANK,
    O_BUCKET_S,
    O_COMMITTED,
    O_CONVERGED_TOL,
    O_EXCITATION_MIN,
    O_KIND,
    O_LINEAR,
    O_MAX_BEARING_AGE_S,
    O_MAX_BUFFER,
    O_MAX_VELOCITY_AGE_S,
    O_MAX_VELOCITY_WAIT_S,
    O_MIN_INTERVAL_S,
    O_N,
    O_WINDOW_FULL_S,
    O_WINDOW_S,
    O_WK_OBS,
    OFF_Q,
    P_COUNT,
    P_OUTLIER_NIS,
    Q_COUNT,
    Q_NB,
    Q_NV,
    S_COND,
    S_COND_OK,
    S_COND_T,
    S_DIAG_EXC,
    S_DIAG_T,
    S_HELD,
    S_N_BEARING,
    S_N_VELOCITY,
    S_SINCE,
    S_STATUS,
    S_T_C,
    S_T_RANGE,
    VB_T,
)

#: The excitation level describes the window: it is evaluated again at most this often (s).
DIAGNOSTICS_PERIOD_S = 0.5


@njit(inline="always", error_model="numpy")
def _q(s):
    return s[OFF_Q : OFF_Q + Q_COUNT]


@njit(inline="always", error_model="numpy")
def _scratch(cfg) -> int:
    """Where this module's scratch starts in ``wk`` (after the estimator's)."""
    return int(cfg[O_WK_OBS])


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _commit_piece(cfg, s, vec, fs, fp, vbuf, bbuf, win, out, wk, t0, t1, at_bearing,
                  k_out) -> int:  # fmt: skip
    """Step the estimator from ``t0`` to ``t1`` and commit it: sub-steps of prediction with
    the inputs at their midpoints between the breakpoints, an update at each bearing in
    ``(t0, t1]``; the monitor's window accounts the integral of ``y y^T`` over the time with
    a usable bearing and the correction applied (what moved ``x`` beyond the model's
    prediction, and ``a``). At a bearing's time (``at_bearing``) its committed estimate is
    written into ``out[k_out]``; returns the rows written so far."""
    n = int(cfg[O_N])
    d2 = 2 * n
    q = _q(s)
    o = _scratch(cfg)
    yy = wk[o : o + n * n].reshape((n, n))
    dxa = wk[o + n * n : o + n * n + 2 * n]
    sub = wk[o + n * n + 2 * n :]
    linear = cfg[O_LINEAR] != 0.0
    mba, mva = cfg[O_MAX_BEARING_AGE_S], cfg[O_MAX_VELOCITY_AGE_S]
    o = 0
    before, o = carve(sub, o, d2)
    after, o = carve(sub, o, d2)
    openloop, o = carve(sub, o, n)
    moved, o = carve(sub, o, n)
    v, o = carve(sub, o, n)
    y, o = carve(sub, o, n)
    ymid, o = carve(sub, o, n)
    cap = vbuf.shape[0]
    pts, o = carve(sub, o, 3 * cap + 4)
    nb = int(q[Q_NB])
    estimator.mean(cfg, s, vec, fs, before)
    kind_paper = cfg[O_KIND] != 0.0
    openloop[:] = 0.0
    yy[:, :] = 0.0
    valid = 0.0
    corrected = False
    count = streams.breakpoints(q, vbuf, bbuf, t0, t1, cfg[O_MIN_INTERVAL_S], mba, pts)
    for k in range(count - 1):
        a, b = pts[k], pts[k + 1]
        span = b - a
        if span > 0.0:
            has_mid = streams.bearing_at(q, bbuf, 0.5 * (a + b), linear, mba, ymid)
            n_sub = estimator.substeps(cfg, span, has_mid)
            hs = span / n_sub
            for i in range(n_sub):
                tm = a + (i + 0.5) * hs
                streams.velocity_at(q, vbuf, tm, linear, mva, v)
                has_y = has_mid
                if has_mid:
                    if n_sub == 1:
                        y[:] = ymid
                    else:
                        has_y = streams.bearing_at(q, bbuf, tm, linear, mba, y)
                estimator.predict(cfg, s, vec, fs, fp, vbuf, tm, hs, v, y, has_y,
                                  before[n:], moved, wk)  # fmt: skip
                for j in range(n):
                    openloop[j] += moved[j]
                if has_y:
                    valid += hs
                    for r in range(n):
                        for c in range(n):
                            yy[r, c] += hs * y[r] * y[c]
                    corrected = corrected or kind_paper
        # the bearing at b, the latest of that time, if any
        hit = -1
        for i in range(nb):
            if bbuf[i, 0] == b:
                hit = i
        if hit >= 0:
            estimator.update(cfg, s, vec, fs, fp, vbuf, b, bbuf[hit, 1 : 1 + n], wk)
            if not math.isnan(bbuf[hit, 1 + n]):  # a range measured with it
                estimator.update_range(cfg, s, fs, fp, bbuf[hit, 1 + n], bbuf[hit, 2 + n], wk)
                s[S_T_RANGE] = b
            corrected = True
    estimator.mean(cfg, s, vec, fs, after)
    s[S_T_C] = t1
    monitor.add_interval(win, t0, t1, yy, valid, cfg[O_WINDOW_S], cfg[O_BUCKET_S])
    if corrected:
        for j in range(n):
            dxa[j] = after[j] - before[j] - openloop[j]
            dxa[n + j] = after[n + j] - before[n + j]
        monitor.add_correction(win, t1, dxa[:n], dxa[n:], cfg[O_BUCKET_S])
    if at_bearing:
        _estimate_at(cfg, s, vec, fs, fp, vbuf, bbuf, win, out[k_out], sub, t1, at_bearing)
        k_out += 1
    return k_out


@njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy")
def _estimate_at(cfg, s, vec, fs, fp, vbuf, bbuf, win, row, sub, t, committed) -> None:
    """The estimate at ``t`` (at or after the committed time) into ``row``; ``committed``:
    at the committed time with the bearing there just applied."""
    n = int(cfg[O_N])
    d2 = 2 * n
    q = _q(s)
    o = 0
    st, o = carve(sub, o, d2)
    p, o = carve(sub, o, d2 * d2)
    p = p.reshape((d2, d2))
    pxx, o = carve(sub, o, n * n)
    pxx = pxx.reshape((n, n))
    xh, o = carve(sub, o, n)
    disp, o = carve(sub, o, n)
    wk2 = sub[o:]
    t_c = s[S_T_C]
    started = not math.isnan(t_c)
    has_cov = estimator.output(cfg, s, vec, fs, fp, st, p, wk2)
    xh[:] = st[:n]
    dt = 0.0
    predicted_cov = False
    if started and t > t_c:
        # beyond the committed state: a prediction (never committed); the bearings since are
        # applied when the velocity around them is known
        dt = t - t_c
        streams.predicted_displacement(q, vbuf, t_c, t, cfg[O_LINEAR] != 0.0,
                                       cfg[O_MAX_VELOCITY_AGE_S], disp, wk2)  # fmt: skip
        for j in range(n):
            xh[j] += disp[j] + dt * st[n + j]
        ev = streams.extrapolation_var(q, vbuf, t)
        if ev > 0.0 and has_cov:
            # a sparse stream's trend continued: its uncertainty, and the bearing at this
            # time (if it is one's) corrects the position published
            estimator.position_cov(cfg, s, p, dt, streams.trend_known(q, vbuf), pxx)
            for j in range(n):
                pxx[j, j] += ev
            nb = int(q[Q_NB])
            if bbuf[nb - 1, 0] == t:
                bp = cfg[O_BANK : O_BANK + P_COUNT]
                kalman.position_update(xh, pxx, bbuf[nb - 1, 1 : 1 + n],
                                       estimator.noise_var(cfg, s), bp[P_OUTLIER_NIS],
                                       wk2)  # fmt: skip
            predicted_cov = True
    rng = 0.0
    for j in range(n):
        rng += xh[j] * xh[j]
    rng = math.sqrt(rng)
    nv, nb = int(q[Q_NV]), int(q[Q_NB])
    if committed:
        b_age = 0.0
        v_age = math.nan
        for i in range(nv):
            if vbuf[i, VB_T] <= t:
                v_age = t - vbuf[i, VB_T]
    else:
        b_age = t - bbuf[nb - 1, 0] if nb > 0 else math.nan
        v_age = t - vbuf[nv - 1, VB_T] if nv > 0 else math.nan
    if math.isnan(s[S_DIAG_T]) or not 0.0 <= t - s[S_DIAG_T] < DIAGNOSTICS_PERIOD_S:
        avg = wk2[0 : n * n].reshape((n, n))
        evs = wk2[n * n : n * n + n]
        work = wk2[n * n + n : 2 * n * n + n].reshape((n, n))
        s[S_DIAG_T] = t
        s[S_DIAG_EXC] = monitor.excitation(win, n, avg, evs, work)
    exc = s[S_DIAG_EXC]
    if s[S_COND_OK] == 0.0 or s[S_COND_T] != t_c:  # of the committed state
        s[S_COND_OK] = 1.0
        s[S_COND_T] = t_c
        s[S_COND] = estimator.cond(cfg, s, vec, p, wk2)
    cov = monitor.covered(win)
    corr = monitor.correction_rel(win, n, rng)
    sd_rel = 0.0  # (an estimator without a covariance: its corrections alone)
    if has_cov and started:
        if not predicted_cov:
            estimator.position_cov(cfg, s, p, dt, streams.trend_known(q, vbuf), pxx)
        tr = 0.0
        for i in range(n):
            tr += max(pxx[i, i], 0.0)
        sd_rel = math.sqrt(tr) / max(rng, 1e-9)
    ranged = (
        has_cov
        and not math.isnan(s[S_T_RANGE])
        and (abs(t - s[S_T_RANGE]) <= cfg[O_MAX_BEARING_AGE_S])
    )
    status, since = monitor.next_status(
        int(s[S_STATUS]), s[S_SINCE], t, started, b_age, v_age, exc, cov, corr,
        estimator.settled(cfg, s), cfg[O_MAX_BEARING_AGE_S], cfg[O_MAX_VELOCITY_AGE_S],
        cfg[O_WINDOW_S], cfg[O_WINDOW_FULL_S], cfg[O_EXCITATION_MIN], cfg[O_CONVERGED_TOL],
        sd_rel, ranged,
    )  # fmt: skip
    s[S_STATUS] = status
    s[S_SINCE] = since
    row[E_T] = t
    row[E_RANGE] = rng
    row[E_EXCITATION] = exc
    row[E_COND] = s[S_COND]
    row[E_STATUS] = status
    row[E_CORRECTED] = 1.0 if started and b_age <= cfg[O_MAX_BEARING_AGE_S] else 0.0
    row[E_BEARING_AGE] = b_age
    row[E_VELOCITY_AGE] = v_age
    row[E_CORRECTION_REL] = corr
    row[E_NIS] = estimator.nis(cfg, s) if started else math.nan
    row[E_FIXED : E_FIXED + n] = xh
    row[E_FIXED + n : E_FIXED + 2 * n] = st[n:]
    if has_cov and started:
        var_r = 0.0
        for i in range(n):
            ui = xh[i] / rng if rng > 0.0 else xh[i]
            acc = 0.0
            for j in range(n):
                uj = xh[j] / rng if rng > 0.0 else xh[j]
                acc += pxx[i, j] * uj
            var_r += ui * acc
            row[E_FIXED + 2 * n + i] = math.sqrt(max(pxx[i, i], 0.0))
            row[E_FIXED + 3 * n + i] = math.sqrt(max(p[n + i, n + i], 0.0))
        row[E_RANGE_STD] = math.sqrt(max(var_r, 0.0))
        row[E_HAS_COV] = 1.0
    else:
        row[E_RANGE_STD] = math.nan
        row[E_HAS_COV] = 0.0


@njit(inline="always", error_model="numpy")
def _view(buf, a):
    """Array ``a`` (``layout.A_*``) of the observer's buffer, as laid out in its ``cfg``."""
    o = O_ARRAYS + 4 * a
    at, d0, d1, d2 = int(buf[o]), int(buf[o + 1]), int(buf[o + 2]), int(buf[o + 3])
    return buf[at : at + d0 * max(d1, 1) * max(d2, 1)]


@njit(inline="always", error_model="numpy")
def _views(buf):
    """The observer's arrays (views of its buffer)."""
    cfg = _view(buf, A_CFG)
    s = _view(buf, A_S)
    o = O_ARRAYS + 4 * A_VEC
    vec = _view(buf, A_VEC).reshape((int(buf[o + 1]), int(buf[o + 2])))
    o = O_ARRAYS + 4 * A_FS
    fs = _view(buf, A_FS).reshape((int(buf[o + 1]), int(buf[o + 2])))
    o = O_ARRAYS + 4 * A_FP
    fp = _view(buf, A_FP).reshape((int(buf[o + 1]), int(buf[o + 2]), int(buf[o + 3])))
    o = O_ARRAYS + 4 * A_VBUF
    vbuf = _view(buf, A_VBUF).reshape((int(buf[o + 1]), int(buf[o + 2])))
    o = O_ARRAYS + 4 * A_BBUF
    bbuf = _view(buf, A_BBUF).reshape((int(buf[o + 1]), int(buf[o + 2])))
    o = O_ARRAYS + 4 * A_WIN
    win = _view(buf, A_WIN).reshape((int(buf[o + 1]), int(buf[o + 2])))
    o = O_ARRAYS + 4 * A_OUT
    out = _view(buf, A_OUT).reshape((int(buf[o + 1]), int(buf[o + 2])))
    wk = _view(buf, A_WK)
    return cfg, s, vec, fs, fp, vbuf, bbuf, win, out, wk


#: The operations of :func:`run`.
OP_VELOCITY = 0
OP_VELOCITY_MEAN = 6
OP_BEARING = 1
OP_BEARING_LIVE = 2
OP_PREDICT = 3
OP_COMMIT_PENDING = 4
OP_RESUME = 5
OP_OUTPUT = 7
OP_DISPLACEMENT = 8


@njit(inline="always", error_model="numpy")
def _run(op, cfg, s, vec, fs, fp, vbuf, bbuf, win, out, wk, t, u, has_w, w) -> int:
    """One operation on the observer, at ``t``:

    * ``OP_VELOCITY``: the velocity sample ``u`` (the paper's ``v``, m/s); ``has_w``: ``w``
      is the mean of ``v`` over the interval since the previous sample, from the positions;
    * ``OP_BEARING``, ``OP_BEARING_LIVE``: the bearing sample ``u`` (unit); live: its
      estimate into ``out``'s last row;
    * ``OP_PREDICT``: integrate what the samples determine, then the estimate at ``t`` (a
      prediction past the data horizon, not committed) into ``out``'s last row;
    * ``OP_COMMIT_PENDING``: at the end of the data, commit through the latest bearing
      though no velocity follows it (the latest velocity held);
    * ``OP_RESUME``: carry the started observer across a gap in its data to ``t`` (at or
      after the committed time): the estimate moves by ``u`` (m), the velocity ``w`` holds
      from ``t``; what it had learnt, the window and the status carry over.

    A sample is appended to its stream, then the committed state integrated up to the data
    horizon (a velocity sample leaves that to the next bearing unless the bearing is stale
    or a buffer full). Returns the committed estimates written into ``out`` (rows from 0),
    or an ``ERR_*`` (nothing changed)."""
    q = _q(s)
    t_c = s[S_T_C]
    started = not math.isnan(t_c)
    live = (op == OP_PREDICT) | (op == OP_BEARING_LIVE)
    mba, cap = cfg[O_MAX_BEARING_AGE_S], int(cfg[O_MAX_BUFFER])
    nv, nb = int(q[Q_NV]), int(q[Q_NB])
    if op == OP_RESUME:
        estimator.shift(cfg, vec, fs, u)
        monitor.shift(win, t - t_c, cfg[O_BUCKET_S])
        if not math.isnan(s[S_SINCE]):
            s[S_SINCE] += t - t_c
        s[S_T_C] = t
        streams.restart_velocity(q, vbuf, bbuf, t, w)
        s[S_DIAG_T] = math.nan
        s[S_COND_OK] = 0.0
        return 0
    if op == OP_VELOCITY:
        if nv > 0 and t < vbuf[nv - 1, VB_T]:
            return ERR_VELOCITY_BACKWARDS
        if nv >= vbuf.shape[0] - 1 and started:  # a stream repeating one time
            streams.trim(q, vbuf, bbuf, t_c)
        if int(q[Q_NV]) >= vbuf.shape[0] - 1:
            return ERR_BUFFER_FULL
        streams.append_velocity(q, vbuf, t, u)
        s[S_HELD] = 0.0
        if has_w:  # before any commit: the interval just closed is integrated with its mean
            streams.set_interval_mean(q, vbuf, t, w)
    elif (op == OP_BEARING) | (op == OP_BEARING_LIVE):
        if nb > 0 and t < bbuf[nb - 1, 0]:
            return ERR_BEARING_BACKWARDS
        if started and t < t_c:
            return ERR_BEARING_TOO_OLD
        if nb >= bbuf.shape[0] - 1 and started:
            streams.trim(q, vbuf, bbuf, t_c)
        if int(q[Q_NB]) >= bbuf.shape[0] - 1:
            return ERR_BUFFER_FULL
        streams.append_bearing(q, bbuf, t, u)
        if w.shape[0] >= 2 and not math.isnan(w[0]):  # a range measured with the bearing
            streams.set_bearing_range(q, bbuf, u.shape[0], w[0], w[1])
    elif op == OP_PREDICT and started and t < t_c:
        return ERR_BEFORE_COMMITTED
    k = 0
    keep = cfg[O_COMMITTED] != 0.0
    if not started:  # start once both streams have a sample, from the latest bearing
        streams.keep_latest(q, vbuf, bbuf)
        if q[Q_NV] > 0 and q[Q_NB] > 0:
            t_b = bbuf[0, 0]
            n = int(cfg[O_N])
            estimator.start(cfg, s, vec, fs, fp, t_b, bbuf[0, 1 : 1 + n], bbuf[0, 1 + n])
            if not math.isnan(bbuf[0, 1 + n]):
                estimator.update_range(cfg, s, fs, fp, bbuf[0, 1 + n], bbuf[0, 2 + n], wk)
                s[S_T_RANGE] = t_b
            s[S_T_C] = max(t_b, vbuf[0, VB_T])
            started = True
            if keep and s[S_T_C] == t_b:  # at this bearing (not applied again): its estimate
                _estimate_at(cfg, s, vec, fs, fp, vbuf, bbuf, win, out[0], wk[_scratch(cfg) :],
                             t_b, keep)  # fmt: skip
                k = 1
            streams.trim(q, vbuf, bbuf, s[S_T_C])
    if started and not (op == OP_VELOCITY and streams.can_wait(q, vbuf, bbuf, mba, cap)):
        nb = int(q[Q_NB])
        if op == OP_COMMIT_PENDING:
            horizon = bbuf[nb - 1, 0] if nb > 0 else s[S_T_C]
        else:
            horizon = streams.horizon(q, vbuf, bbuf, mba, cfg[O_MAX_VELOCITY_WAIT_S], cap,
                                      s[S_HELD] != 0.0)  # fmt: skip
            if horizon > vbuf[int(q[Q_NV]) - 1, VB_T]:
                s[S_HELD] = 1.0  # the velocity is stale: held until the next one
        if horizon > s[S_T_C]:
            # stop at each bearing's time (each once) when its estimate is kept
            last = s[S_T_C]
            i = 0
            while last < horizon:
                while i < nb and not (keep and last < bbuf[i, 0] <= horizon):
                    i += 1
                at_bearing = i < nb
                t1 = bbuf[i, 0] if at_bearing else horizon
                k = _commit_piece(cfg, s, vec, fs, fp, vbuf, bbuf, win, out, wk, last, t1,
                                  at_bearing, k)  # fmt: skip
                last = t1
            streams.trim(q, vbuf, bbuf, horizon)
    if op == OP_VELOCITY:
        s[S_N_VELOCITY] += 1.0
        estimator.observe_velocity(cfg, s, vec, t, u)
    elif (op == OP_BEARING) | (op == OP_BEARING_LIVE):
        s[S_N_BEARING] += 1.0
    elif op == OP_PREDICT and started and t < s[S_T_C]:  # the data already reaches past t
        return ERR_BEFORE_COMMITTED
    if live:
        _estimate_at(cfg, s, vec, fs, fp, vbuf, bbuf, win, out[out.shape[0] - 1],
                     wk[_scratch(cfg) :], t, not live)  # fmt: skip
    return k


@njit(cache=True, error_model="numpy")
def run(op, buf, t, u, w) -> int:
    """The observer's one entry point, on its buffer (one array: the call from Python is
    cheap): :func:`_run`'s operations, ``OP_VELOCITY_MEAN`` (``OP_VELOCITY`` with the
    interval's mean ``w``), and two that read:

    * ``OP_OUTPUT``: the committed estimate, ``[x, a]`` (2n) and then its covariance
      (2n, 2n, row by row) into ``wk`` from ``cfg[O_WK_OBS]``; returns 1 if it has one;
    * ``OP_DISPLACEMENT``: the integral of ``v`` from ``t`` to ``u[0]`` (m), as the
      estimates are predicted with it, into ``out``'s first row (at least one velocity
      sample)."""
    cfg, s, vec, fs, fp, vbuf, bbuf, win, out, wk = _views(buf)
    n = int(cfg[O_N])
    if op == OP_OUTPUT:
        d2 = 2 * n
        o = _scratch(cfg)
        st, p = wk[o : o + d2], wk[o + d2 : o + d2 + d2 * d2].reshape((d2, d2))
        return 1 if estimator.output(cfg, s, vec, fs, fp, st, p, wk) else 0
    if op == OP_DISPLACEMENT:
        streams.predicted_displacement(_q(s), vbuf, t, u[0], cfg[O_LINEAR] != 0.0,
                                       cfg[O_MAX_VELOCITY_AGE_S], out[0, :n], wk)  # fmt: skip
        return 0
    has_w = op == OP_VELOCITY_MEAN
    if has_w:
        op = OP_VELOCITY
    return _run(op, cfg, s, vec, fs, fp, vbuf, bbuf, win, out, wk, t, u, has_w, w)
