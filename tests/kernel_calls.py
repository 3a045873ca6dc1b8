"""Calls into the compiled kernels for the tests of the core (tests/test_core_*.py).

The kernels are compiled without a CPython wrapper (:mod:`mav_observer.core.kernels`): they
can be called from compiled code only. Each shim below is one ``@njit(cache=True)`` function
per kernel module that dispatches on an operation code to the kernel it names and hands the
result back; the Python helpers after each shim give them plain signatures. Arguments are
always passed as C-contiguous float64 arrays and Python floats and bools, so that each shim
is compiled for one signature only (compile time counts in the test suite).

numba checks a cached function against its own file only: a stamp of the kernels' sources
clears this module's cached machine code when any kernel changed (as
:mod:`mav_observer.core.compiled` does for the kernels' own cache).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from numba import njit

from mav_observer.core.compiled import clear_stale_cache
from mav_observer.core.kernels import algebra, bank, kalman, learners, monitor, paper, streams
from mav_observer.core.kernels import layout as L
from mav_observer.core.state import reset_streams

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:  # (the harness's bench.accuracy.bankruns)
    sys.path.insert(0, str(_ROOT))


clear_stale_cache(__file__)


def _f(a: object) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


# -- algebra ------------------------------------------------------------------------------
A_EIGVALS, A_COND2, A_SPD_INVERSE, A_TANGENT, A_SOLVE, A_MAHA = range(6)


@njit(cache=True)
def algebra_call(op, a, b, out):  # pragma: no cover - compiled
    """``a`` (n, n), ``b`` (k, n) an input, ``out`` an output of the operation's shape."""
    n = a.shape[0]
    w = np.zeros((n, n + 1))
    w2 = np.zeros((n, n))
    if op == 0:
        algebra.sym_eigvals(a, out[0], w2)
    elif op == 1:
        return algebra.cond2(a, np.zeros((n, n)), np.zeros(n), w2)
    elif op == 2:
        return algebra.spd_inverse(a, out, w2)
    elif op == 3:
        algebra.tangent_basis(b[0], out)
    elif op == 4:
        v = b[0].copy()
        ok = algebra.solve(a, v, w)
        out[0] = v
        return 1.0 if ok else 0.0
    elif op == 5:
        return algebra.mahalanobis2(b[0], a, w2, np.zeros(n))
    return 0.0


def sym_eigvals(a: np.ndarray) -> np.ndarray:
    out = np.zeros((1, a.shape[0]))
    algebra_call(A_EIGVALS, _f(a), np.zeros((1, 1)), out)
    return out[0]


def cond2(m: np.ndarray) -> float:
    return algebra_call(A_COND2, _f(m), np.zeros((1, 1)), np.zeros((1, 1)))


def spd_inverse(a: np.ndarray) -> tuple[np.ndarray, float]:
    inv = np.zeros(a.shape)
    logdet = algebra_call(A_SPD_INVERSE, _f(a), np.zeros((1, 1)), inv)
    return inv, logdet


def tangent_basis(d: np.ndarray) -> np.ndarray:
    n = d.shape[0]
    e = np.zeros((n, n - 1))
    algebra_call(A_TANGENT, np.zeros((n, n)), _f(d)[None], e)
    return e


def solve(a: np.ndarray, b: np.ndarray) -> tuple[bool, np.ndarray]:
    """``a^-1 b`` (``b`` (n,), as the merge solves it); the flag False if ``a`` is singular."""
    out = np.zeros((1, len(b)))
    ok = algebra_call(A_SOLVE, _f(a), _f(b)[None], out)
    return bool(ok), out[0]


def mahalanobis2(d: np.ndarray, a: np.ndarray) -> float:
    return algebra_call(A_MAHA, _f(a), _f(d)[None], np.zeros((1, 1)))


# -- the bank ------------------------------------------------------------------------------
(
    B_START,
    B_PREDICT,
    B_UPDATE,
    B_STEP,
    B_ESTIMATE,
    B_MERGE,
    B_RESEED,
    B_WALK_LEVELS,
    B_LEVELS_IN_USE,
    F_PREDICT,
    F_UPDATE,
    F_POSITION,
    F_INITIAL,
) = range(13)


@njit(cache=True)
def bank_call(
    op, fs, fp, logw, bs, bp, wk, y, dx, h, q_x, walk_hold, walk_hold_nats, st, p, args
):  # pragma: no cover - compiled
    """The bank's kernels on each run of arrays laid out as
    :class:`bench.accuracy.bankruns.BankRuns`'s (a leading runs axis); the ``F_*``
    operations on one filter ``st[0]``, ``p[0]`` (``args``: ``q_a``, the bearing noise
    variance, ``r_w``, the outlier threshold; the update's ``(nis, logdet, weight,
    noise_stat)`` back in ``args[4:8]``)."""
    if op >= 9:
        s, pp, yy, d = st[0], p[0], y[0], dx[0]
        kw = np.zeros(4096)
        res = np.zeros(4)
        if op == 9:
            kalman.predict_filter(s, pp, d, h, q_x, args[0])
        elif op == 10:
            kalman.update_filter(s, pp, yy, args[1], args[2], args[3], kw, res)
            args[4:8] = res
        elif op == 11:
            n = yy.shape[0]
            x = s[:n].copy()
            pxx = pp[:n, :n].copy()
            kalman.position_update(x, pxx, yy, args[1], args[3], kw)
            s[:n] = x
            pp[:n, :n] = pxx
        elif op == 12:
            kalman.initial_covariance(yy, h, q_x, args[0], args[1], pp)
        return
    for r in range(fs.shape[0]):
        if op == 0:
            bank.start(fs[r], fp[r], logw[r], bs[r], bp, y[r], dx[r, 0])
        elif op <= 3:  # (a prediction and/or an update, one call site each)
            if op != 2:
                bank.predict(fs[r], fp[r], bs[r], bp, dx[r], h, q_x)
            if op != 1:
                bank.update(
                    fs[r],
                    fp[r],
                    logw[r],
                    bs[r],
                    bp,
                    y[r],
                    h,
                    walk_hold,
                    walk_hold_nats,
                    0.0,
                    wk[r],
                )
        elif op == 4:
            bank.estimate(fs[r], fp[r], logw[r], bs[r], bp, st[r], p[r], wk[r])
        elif op == 5:
            bank._merge(fs[r], fp[r], logw[r], bs[r], bp, wk[r])
        elif op == 6:
            bank.reseed(fs[r], fp[r], logw[r], bs[r], bp, y[r])
        elif op == 7:
            lo, hi = bank.walk_levels(st[r, 0], bp)
            st[r, 0], st[r, 1] = lo, hi
        elif op == 8:
            st[r, 0] = bank.noise_var(bs[r], bp)
            st[r, 1] = bank.bias_walk(bs[r], bp)


def _filter(op, s, p, y=None, dx=None, h=0.0, q_x=0.0, args=None):
    """A one-filter operation on copies of ``s`` and ``p``; returns them and ``args``."""
    s, p = _f(s).copy()[None], _f(p).copy()[None]
    args = np.zeros(8) if args is None else _f([*args] + [0.0] * (8 - len(args)))
    n = len(y) if y is not None else len(dx)
    bank_call(
        op,
        np.zeros((1, 1, 1)),
        np.zeros((1, 1, 1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros(1),
        np.zeros((1, 1)),
        _f(y)[None] if y is not None else np.zeros((1, n)),
        _f(dx)[None] if dx is not None else np.zeros((1, n)),
        float(h),
        float(q_x),
        False,
        0.0,
        s,
        p,
        args,
    )
    return s[0], p[0], args


def predict_filter(s, p, dx, h, q_x, q_a) -> tuple[np.ndarray, np.ndarray]:
    s, p, _ = _filter(F_PREDICT, s, p, dx=dx, h=h, q_x=q_x, args=[q_a])
    return s, p


def update_filter(s, p, y, sig2, r_w, outlier_nis=math.inf):
    """``(s, p, nis, logdet, weight, noise_stat)`` after the bearing ``y``."""
    s, p, a = _filter(F_UPDATE, s, p, y=y, args=[0.0, sig2, r_w, outlier_nis])
    return s, p, float(a[4]), float(a[5]), float(a[6]), float(a[7])


def position_update(x, pxx, y, sig2, outlier_nis) -> tuple[np.ndarray, np.ndarray]:
    """A bearing applied to a position ``x`` of covariance ``pxx`` alone."""
    n = len(x)
    s = np.zeros(2 * n)
    s[:n] = x
    p = np.zeros((2 * n, 2 * n))
    p[:n, :n] = pxx
    s, p, _ = _filter(F_POSITION, s, p, y=y, args=[0.0, sig2, 0.0, outlier_nis])
    return s[:n], p[:n, :n]


def initial_covariance(y, range0, range_std, bias_std, sigma) -> np.ndarray:
    n = len(y)
    _, p, _ = _filter(
        F_INITIAL,
        np.zeros(2 * n),
        np.zeros((2 * n, 2 * n)),
        y=y,
        h=range0,
        q_x=range_std,
        args=[bias_std, sigma],
    )
    return p


class Runs:
    """``R`` runs of the bank in the arrays of :class:`bench.accuracy.bankruns.BankRuns`
    (``.b``), stepped with the bank's kernels in a serial loop (the harness's ``prange``
    costs a thread wake-up per step, milliseconds on a busy machine), and what the harness
    does not expose: a prediction alone, an update with the bias walk held."""

    def __init__(self, prm, runs: int, n: int) -> None:
        from bench.accuracy.bankruns import BankRuns

        self.b = BankRuns(prm, runs, n)
        self.runs, self.n = runs, n
        self._st = np.zeros((runs, 2 * n))
        self._p = np.zeros((runs, 2 * n, 2 * n))
        self._nodx = np.zeros((runs, n))
        self._args = np.zeros(8)

    def _call(self, op, y=None, dx=None, h=0.0, hold=False, hold_nats=60.0, k=None):
        b = self.b
        k = slice(None) if k is None else k
        bank_call(
            op,
            b.fs[k],
            b.fp[k],
            b.logw[k],
            b.bs[k],
            b.bp,
            b.wk[k],
            self._nodx[k] if y is None else _f(y),
            self._nodx[k] if dx is None else _f(dx),
            float(h),
            float(b.q_x),
            bool(hold),
            float(hold_nats),
            self._st[k],
            self._p[k],
            self._args,
        )

    def start(self, y0, r0) -> None:
        dx = np.zeros((self.runs, self.n))
        dx[:, 0] = r0
        self._call(B_START, y=y0, dx=dx)

    def predict(self, dx, h) -> None:
        self._call(B_PREDICT, dx=dx, h=h)

    def update(self, y, h, hold=False, hold_nats=60.0) -> None:
        self._call(B_UPDATE, y=y, h=h, hold=hold, hold_nats=hold_nats)

    def step(self, dx, h, y, hold=False, hold_nats=60.0) -> None:
        self._call(B_STEP, y=y, dx=dx, h=h, hold=hold, hold_nats=hold_nats)

    def estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        self._call(B_ESTIMATE)
        n = self.n
        return self._st[:, :n].copy(), self._st[:, n:].copy(), self._p.copy()

    def merge(self) -> None:
        self._call(B_MERGE)

    def reseed(self, y) -> None:
        self._call(B_RESEED, y=y)

    def walk_levels(self, q: float) -> tuple[float, float]:
        """The probes' levels around the walk ``q`` (m^2/s^3)."""
        self._st[0, 0] = q
        self._call(B_WALK_LEVELS, k=slice(0, 1))
        return float(self._st[0, 0]), float(self._st[0, 1])

    def levels_in_use(self) -> tuple[np.ndarray, np.ndarray]:
        """The bearing noise variance (rad^2) and the bias walk (m^2/s^3) in use, per run."""
        self._call(B_LEVELS_IN_USE)
        return self._st[:, 0].copy(), self._st[:, 1].copy()

    # the harness's arrays: the filters, their covariances, log weights, the runs' scalars
    @property
    def fs(self) -> np.ndarray:
        return self.b.fs

    @property
    def fp(self) -> np.ndarray:
        return self.b.fp

    @property
    def logw(self) -> np.ndarray:
        return self.b.logw

    @property
    def bs(self) -> np.ndarray:
        return self.b.bs

    @property
    def alive(self) -> np.ndarray:
        """The hypotheses alive per run."""
        return self.b.bs[:, L.B_F].astype(int)


# -- the paper's observer ------------------------------------------------------------------
P_SUBSTEP, P_FIRST, P_COUNT, P_SOLVE_PAIR, P_ESTIMATE, P_ZS, P_STATIC = range(7)


@njit(cache=True)
def paper_call(
    op, xh1, m, ahat, y, has_y, v, k, k_star, h, estimate_bias, out, hold_speed2, hold_cos
):  # pragma: no cover - compiled
    """The paper's kernels on ``(xh1, m, ahat)`` in place; ``out`` (2, n) a result."""
    n = xh1.shape[0]
    wk = np.zeros(8 * n * n + 16 * n)
    if op == 0:
        paper.substep(xh1, m, ahat, y, has_y, v, k, k_star, h, estimate_bias, wk)
    elif op == 1:
        paper.first_filter_step(xh1, m, y, has_y, v, k, h)
    elif op == 2:
        return float(paper.substep_count(k, k_star, h))
    elif op == 3:
        paper.solve_pair(m, y, v, out[0], out[1], wk[: n * (n + 2)].reshape((n, n + 2)))
    elif op == 4:
        paper.estimate(xh1, m, ahat, out[0])
    elif op == 5:
        paper.zs(xh1, m, ahat, out[0], wk)
    elif op == 6:
        ok = paper.is_static(xh1, m, ahat, v, y, hold_speed2, hold_cos, wk)
        return 1.0 if ok else 0.0
    return 0.0


def _paper(
    op, xh1, m, ahat, y=None, v=None, k=0.0, k_star=0.0, h=0.0, bias=True, speed2=0.0, cos=1.0
):
    n = len(xh1)
    xh1, m, ahat = _f(xh1).copy(), _f(m).copy(), _f(ahat).copy()
    out = np.zeros((2, n))
    r = paper_call(
        op,
        xh1,
        m,
        ahat,
        np.zeros(n) if y is None else _f(y),
        y is not None,
        np.zeros(n) if v is None else _f(v),
        float(k),
        float(k_star),
        float(h),
        bool(bias),
        out,
        float(speed2),
        float(cos),
    )
    return xh1, m, ahat, out, r


def substep(xh1, m, ahat, y, v, k, k_star, h, estimate_bias=True):
    """``(xh1, m, ahat)`` after one sub-step (``y`` None: a prediction)."""
    xh1, m, ahat, _, _ = _paper(P_SUBSTEP, xh1, m, ahat, y, v, k, k_star, h, estimate_bias)
    return xh1, m, ahat


def first_filter_step(xh1, m, y, v, k, h):
    xh1, m, _, _, _ = _paper(P_FIRST, xh1, m, np.zeros(len(xh1)), y, v, k, 0.0, h)
    return xh1, m


def substep_count(k, k_star, h) -> int:
    return int(_paper(P_COUNT, [0.0, 0.0], np.eye(2), [0.0, 0.0], k=k, k_star=k_star, h=h)[4])


def solve_pair(m, b0, b1) -> tuple[np.ndarray, np.ndarray]:
    n = len(b0)
    out = _paper(P_SOLVE_PAIR, np.zeros(n), m, np.zeros(n), b0, b1)[3]
    return out[0], out[1]


def paper_estimate(xh1, m, ahat) -> np.ndarray:
    return _paper(P_ESTIMATE, xh1, m, ahat)[3][0]


def paper_zs(xh1, m, ahat) -> np.ndarray:
    return _paper(P_ZS, xh1, m, ahat)[3][0]


def is_static(xh1, m, ahat, v, y, hold_speed_mps, hold_deg) -> bool:
    r = _paper(
        P_STATIC, xh1, m, ahat, y, v, speed2=hold_speed_mps**2, cos=math.cos(math.radians(hold_deg))
    )[4]
    return bool(r)


# -- the sample streams --------------------------------------------------------------------
(
    S_RESET,
    S_APPEND_V,
    S_APPEND_B,
    S_MEAN,
    S_VEL_AT,
    S_BEAR_AT,
    S_BREAKPOINTS,
    S_HORIZON,
    S_CAN_WAIT,
    S_TRIM,
    S_EXTRAP_VAR,
    S_EXTRAP,
    S_TREND,
    S_CHORD,
    S_DISPLACEMENT,
    S_SHAPE_VAR,
) = range(16)


@njit(cache=True)
def streams_call(
    op, q, vbuf, bbuf, t, t1, vec, linear, mba, mva, max_buffer, min_interval, out
):  # pragma: no cover - compiled
    """The streams' kernels on ``(q, vbuf, bbuf)``; ``out`` a vector result."""
    if op == 1:
        streams.append_velocity(q, vbuf, t, vec)
    elif op == 2:
        streams.append_bearing(q, bbuf, t, vec)
    elif op == 3:
        streams.set_interval_mean(q, vbuf, t, vec)
    elif op == 4:
        streams.velocity_at(q, vbuf, t, linear, mva, out)
    elif op == 5:
        return 1.0 if streams.bearing_at(q, bbuf, t, linear, mba, out) else 0.0
    elif op == 6:
        return float(streams.breakpoints(q, vbuf, bbuf, t, t1, min_interval, mba, out))
    elif op == 7:
        return streams.horizon(q, vbuf, bbuf, mba, mva, max_buffer, t != 0.0)
    elif op == 8:
        return 1.0 if streams.can_wait(q, vbuf, bbuf, mba, max_buffer) else 0.0
    elif op == 9:
        streams.trim(q, vbuf, bbuf, t)
    elif op == 10:
        return streams.extrapolation_var(q, vbuf, t)
    elif op == 11:
        return streams.extrapolation_mps2(q)
    elif op == 12:
        return 1.0 if streams.trend_known(q, vbuf) else 0.0
    elif op == 13:
        return 1.0 if streams.chord_at(q, vbuf, t) else 0.0
    elif op == 14:
        streams.predicted_displacement(q, vbuf, t, t1, linear, mva, out, np.zeros(out.shape[0]))
    elif op == 15:
        return streams.shape_var(q, vbuf, t, mva)
    return 0.0


class Streams:
    """The two sample streams of one observer (``n`` axes) in their kernel arrays."""

    def __init__(
        self,
        n: int = 3,
        *,
        linear: bool = True,
        max_buffer: int = 256,
        max_bearing_age_s: float = 2.0,
        max_velocity_age_s: float = 2.0,
    ) -> None:
        cap = max_buffer + 3
        self.n = n
        self.q = np.zeros(L.Q_COUNT)
        self.vbuf = np.zeros((cap, 2 + 2 * n))
        self.bbuf = np.zeros((cap, 3 + n))
        self.linear = linear
        self.max_buffer = max_buffer
        self.mba, self.mva = max_bearing_age_s, max_velocity_age_s
        reset_streams(self.q)

    def _call(self, op, t=0.0, t1=0.0, vec=None, out=None, min_interval=0.0) -> float:
        return streams_call(
            op,
            self.q,
            self.vbuf,
            self.bbuf,
            float(t),
            float(t1),
            np.zeros(self.n) if vec is None else _f(vec),
            self.linear,
            float(self.mba),
            float(self.mva),
            float(self.max_buffer),
            float(min_interval),
            np.zeros(self.n) if out is None else out,
        )

    def append_velocity(self, t, v) -> None:
        self._call(S_APPEND_V, t, vec=v)

    def append_bearing(self, t, y) -> None:
        self._call(S_APPEND_B, t, vec=y)

    def set_interval_mean(self, t, mean) -> None:
        self._call(S_MEAN, t, vec=mean)

    def velocity_at(self, t) -> list[float]:
        out = np.zeros(self.n)
        self._call(S_VEL_AT, t, out=out)
        return out.tolist()

    def bearing_at(self, t) -> list[float] | None:
        out = np.zeros(self.n)
        return out.tolist() if self._call(S_BEAR_AT, t, out=out) else None

    def breakpoints(self, t0, t1, min_interval_s) -> list[float]:
        out = np.zeros(3 * self.vbuf.shape[0] + 4)
        k = int(self._call(S_BREAKPOINTS, t0, t1, out=out, min_interval=min_interval_s))
        return out[:k].tolist()

    def horizon(self, held: bool = False) -> float:
        """(``max_velocity_age_s`` stands for the observer's ``max_velocity_wait_s``.)"""
        return self._call(S_HORIZON, 1.0 if held else 0.0)

    def can_wait(self) -> bool:
        return bool(self._call(S_CAN_WAIT))

    def trim(self, t_c) -> None:
        self._call(S_TRIM, t_c)

    def shape_var_m2(self, t) -> float:
        """The path's variance inside a telemetry gap at ``t`` (the gap: over
        ``max_velocity_age_s``)."""
        return self._call(S_SHAPE_VAR, t)

    def extrapolation_var_m2(self, t) -> float:
        return self._call(S_EXTRAP_VAR, t)

    @property
    def extrapolation_mps2(self) -> float:
        return self._call(S_EXTRAP)

    @property
    def sparse(self) -> bool:
        return bool(self._call(S_TREND))

    def chord_at(self, t) -> bool:
        return bool(self._call(S_CHORD, t))

    def predicted_displacement(self, t0, t1) -> list[float]:
        out = np.zeros(self.n)
        self._call(S_DISPLACEMENT, t0, t1, out=out)
        return out.tolist()

    @property
    def velocity_dt_s(self) -> float:
        return float(self.q[L.Q_VDT])

    @property
    def velocities(self) -> list[tuple[float, list[float]]]:
        n = self.n
        rows = self.vbuf[: int(self.q[L.Q_NV])]
        return [(float(r[L.VB_T]), r[L.VB_V : L.VB_V + n].tolist()) for r in rows]

    @property
    def bearing_times(self) -> list[float]:
        return self.bbuf[: int(self.q[L.Q_NB]), 0].tolist()


# -- the monitor ---------------------------------------------------------------------------
M_INTERVAL, M_CORRECTION, M_EXCITATION, M_COVERED, M_CORRECTION_REL, M_STATUS = range(6)


@njit(cache=True)
def monitor_call(
    op, win, t0, t1, yy, valid_s, window_s, bucket_s, dx, da, args, out
):  # pragma: no cover - compiled
    n = yy.shape[0]
    if op == 0:
        monitor.add_interval(win, t0, t1, yy, valid_s, window_s, bucket_s)
    elif op == 1:
        monitor.add_correction(win, t1, dx, da, bucket_s)
    elif op == 2:
        return monitor.excitation(win, n, np.zeros((n, n)), np.zeros(n), np.zeros((n, n)))
    elif op == 3:
        return monitor.covered(win)
    elif op == 4:
        return monitor.correction_rel(win, n, t0)
    elif op == 5:
        a = args
        status, since = monitor.next_status(
            int(a[0]),
            a[1],
            a[2],
            a[3] != 0.0,
            a[4],
            a[5],
            a[6],
            a[7],
            a[8],
            a[9] != 0.0,
            a[10],
            a[11],
            a[12],
            a[13],
            a[14],
            a[15],
            a[16],
            a[17] != 0.0,
        )
        out[0], out[1] = status, since
    return 0.0


class Window:
    """The monitor's excitation window of ``n`` axes over ``window_s`` in ``buckets``."""

    def __init__(self, n: int, window_s: float, buckets: int) -> None:
        self.n = n
        self.window_s = window_s
        self.bucket_s = window_s / buckets
        self.win = np.zeros((buckets + 2, 3 + n * n + 2 * n))

    def _call(self, op, t0=0.0, t1=0.0, yy=None, valid=0.0, dx=None, da=None) -> float:
        n = self.n
        return monitor_call(
            op,
            self.win,
            float(t0),
            float(t1),
            np.zeros((n, n)) if yy is None else _f(yy),
            float(valid),
            float(self.window_s),
            float(self.bucket_s),
            np.zeros(n) if dx is None else _f(dx),
            np.zeros(n) if da is None else _f(da),
            np.zeros(16),
            np.zeros(2),
        )

    def held(self, t0: float, t1: float, y) -> None:
        """A bearing ``y`` (or none) held over ``[t0, t1]``."""
        if y is None:
            self._call(M_INTERVAL, t0, t1)
        else:
            y = np.asarray(y, dtype=float)
            self._call(M_INTERVAL, t0, t1, yy=np.outer(y, y) * (t1 - t0), valid=t1 - t0)

    def add_correction(self, t: float, dx, da) -> None:
        self._call(M_CORRECTION, 0.0, t, dx=dx, da=da)

    def excitation(self) -> float:
        return self._call(M_EXCITATION)

    def covered_s(self) -> float:
        return self._call(M_COVERED)

    def correction_rel(self, range_m: float) -> float:
        return self._call(M_CORRECTION_REL, range_m)

    @property
    def buckets_in_use(self) -> int:
        return int(self.win[-1, 0])


def next_status(
    status: int,
    since: float,
    t: float,
    *,
    started: bool,
    b_age: float,
    v_age: float,
    exc: float,
    covered: float,
    corr: float,
    settled: bool,
    max_bearing_age_s: float,
    max_velocity_age_s: float,
    window_s: float,
    window_full_s: float,
    excitation_min: float,
    converged_tol: float,
    sd_rel: float = 0.0,
    ranged: bool = False,
) -> tuple[int, float]:
    """:func:`mav_observer.core.kernels.monitor.next_status` (an age NaN: no sample)."""
    args = np.array(
        [
            status,
            since,
            t,
            started,
            b_age,
            v_age,
            exc,
            covered,
            corr,
            settled,
            max_bearing_age_s,
            max_velocity_age_s,
            window_s,
            window_full_s,
            excitation_min,
            converged_tol,
            sd_rel,
            ranged,
        ],
        dtype=float,
    )
    out = np.zeros(2)
    monitor_call(
        M_STATUS,
        np.zeros((3, 4)),
        0.0,
        0.0,
        np.zeros((1, 1)),
        0.0,
        1.0,
        1.0,
        np.zeros(1),
        np.zeros(1),
        args,
        out,
    )
    return int(out[0]), float(out[1])


# -- the learners --------------------------------------------------------------------------
LR_LATENCY, LR_ADVANCE, LR_SETTLING, LR_WHITENESS = range(4)


@njit(cache=True)
def learners_call(
    op, st, prev, ts, xs, avs, vs, ys, sig2, max_s, trace
):  # pragma: no cover - compiled
    """Feed the learner ``st`` row by row: the latency (``trace`` its value after each),
    the settling (``xs[i] = (tau, learning_for)``; ``trace`` settled after each), the
    innovations' correlation (``ys`` the innovations, ``prev`` its previous one); or
    ``advance`` (``ys[0]`` by ``sig2`` s into ``prev``)."""
    if op == 1:
        learners.advance(ys[0], xs[0], avs[0], vs[0], sig2, prev)
        return
    for i in range(ts.shape[0]):
        if op == 0:
            learners.latency_observe(st, ts[i], xs[i], avs[i], vs[i], ys[i], sig2, max_s)
            trace[i] = st[L.L_TAU]
        elif op == 2:
            ok = learners.settling_update(st, ts[i], xs[i, 0], xs[i, 1])
            trace[i] = 1.0 if ok else 0.0
        elif op == 3:
            learners.whiteness_add(st, prev, ts[i], ys[i])


class Latency:
    """The bearings' latency learnt (``layout.L_*`` scalars)."""

    def __init__(self, max_s: float = 0.5) -> None:
        self.lat = np.zeros(L.L_COUNT)
        for i in (L.L_T, L.L_T0, L.L_B_T0):
            self.lat[i] = math.nan
        self.max_s = max_s

    def feed(self, t, x, a, v, y, sig2) -> np.ndarray:
        """Observe each row; returns the latency in use after each (s)."""
        t = _f(t)
        trace = np.zeros(t.shape[0])
        learners_call(
            LR_LATENCY,
            self.lat,
            np.zeros(1),
            t,
            _f(x),
            _f(a),
            _f(v),
            _f(y),
            float(sig2),
            float(self.max_s),
            trace,
        )
        return trace

    @property
    def tau_s(self) -> float:
        return float(self.lat[L.L_TAU])

    @property
    def tau_fit_s(self) -> float:
        return float(self.lat[L.L_TAU_FIT])


def advance(y, x, a, v, tau) -> np.ndarray:
    out = np.zeros(len(y))
    learners_call(
        LR_ADVANCE,
        np.zeros(1),
        out,
        np.zeros(1),
        _f(x)[None],
        _f(a)[None],
        _f(v)[None],
        _f(y)[None],
        float(tau),
        0.0,
        np.zeros(1),
    )
    return out


class Settling:
    """Whether the latency learnt has settled (``layout.T_*`` scalars)."""

    def __init__(self) -> None:
        self.st = np.zeros(L.T_COUNT)
        self.st[L.T_REF] = math.nan

    def update(self, t: float, tau: float, learning_for: float) -> bool:
        trace = np.zeros(1)
        learners_call(
            LR_SETTLING,
            self.st,
            np.zeros(1),
            np.array([float(t)]),
            np.array([[float(tau), float(learning_for)]]),
            np.zeros((1, 1)),
            np.zeros((1, 1)),
            np.zeros((1, 1)),
            0.0,
            0.0,
            trace,
        )
        return bool(trace[0])


def whiteness_feed(wh: np.ndarray, prev: np.ndarray, t, z) -> None:
    """Innovations ``z`` (rows) at times ``t`` into the correlation's scalars ``wh`` and
    previous innovation ``prev`` (views of an observer's arrays, updated in place)."""
    z = _f(z)
    learners_call(
        LR_WHITENESS,
        wh,
        prev,
        _f(t),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        np.zeros((1, 1)),
        z,
        0.0,
        0.0,
        np.zeros(1),
    )
