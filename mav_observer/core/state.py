"""One observer's state as the arrays its compiled kernels work on, and its saved form.

:func:`new_state` makes the arrays of an :class:`~mav_observer.core.config.ObserverConfig`
(their layout: :mod:`mav_observer.core.kernels.layout`); :func:`to_dict` and
:func:`restore` save and restore them, checked. No numba here: making or saving a state does
not load the compiled estimator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mav_observer.core.config import (
    AUTO,
    MAX_BEARING_LATENCY_S,
    VELOCITY_NOISE_PRIOR_MPS,
    ObserverConfig,
)
from mav_observer.core.kernels import layout as L
from mav_observer.errors import StateError

#: Version of the saved state (:meth:`~mav_observer.core.observer.BiasObserver.to_dict`).
STATE_SCHEMA = 3
#: The arrays a saved state holds (the settings are saved as the configuration).
SAVED = ("s", "vec", "fs", "fp", "vbuf", "bbuf", "win")


@dataclass
class ObserverState:
    """The arrays of one observer (``kernels.layout``): views of one buffer ``buf``, which
    is what the kernels take."""

    buf: np.ndarray
    cfg: np.ndarray
    s: np.ndarray
    vec: np.ndarray
    fs: np.ndarray
    fp: np.ndarray
    vbuf: np.ndarray
    bbuf: np.ndarray
    win: np.ndarray
    out: np.ndarray
    wk: np.ndarray


def config_array(config: ObserverConfig, committed: bool) -> np.ndarray:
    """The settings as the kernels read them (``layout.O_*``, the bank's from ``O_BANK``)."""
    c = config
    bp = c.bank_params().to_array()
    cfg = np.zeros(L.O_BANK + bp.shape[0])
    cfg[L.O_N] = c.n
    cfg[L.O_KIND] = L.KIND_BANK if c.estimator == "riccati" else L.KIND_PAPER
    cfg[L.O_BIASED] = c.mode == "biased"
    cfg[L.O_LINEAR] = c.interpolation == "linear"
    cfg[L.O_MAX_BEARING_AGE_S] = c.max_bearing_age_s
    cfg[L.O_MAX_VELOCITY_AGE_S] = c.max_velocity_age_s
    cfg[L.O_MAX_VELOCITY_WAIT_S] = c.max_velocity_wait_s
    cfg[L.O_MAX_BUFFER] = c.max_buffer
    cfg[L.O_WINDOW_S] = c.window_s
    cfg[L.O_BUCKET_S] = c.window_s / c.window_buckets
    cfg[L.O_WINDOW_FULL_S] = c.window_s * (c.window_buckets - 1) / c.window_buckets
    cfg[L.O_EXCITATION_MIN] = c.excitation_min
    cfg[L.O_CONVERGED_TOL] = c.converged_tol
    cfg[L.O_K] = c.k_per_s
    cfg[L.O_K_STAR] = c.k_star_per_s
    cfg[L.O_STATIC_HOLD] = c.static_hold
    cfg[L.O_HOLD_SPEED2] = c.hold_speed_mps**2
    cfg[L.O_HOLD_COS] = math.cos(math.radians(c.hold_innovation_deg))
    paper_linear = c.estimator == "paper" and c.interpolation == "linear"
    cfg[L.O_MIN_INTERVAL_S] = L.MIN_INTERVAL_S if paper_linear else 0.0
    cfg[L.O_RANGE_GUESS_M] = c.range_guess_m
    cfg[L.O_INITIAL_RANGE_M] = math.nan if c.initial_range_m is None else c.initial_range_m
    told_v = c.velocity_noise_mps
    cfg[L.O_VELOCITY_NOISE_MPS] = math.nan if told_v == AUTO else float(told_v)
    told_l = c.bearing_latency_s
    cfg[L.O_LATENCY_S] = math.nan if told_l == AUTO else float(told_l)
    cfg[L.O_COMMITTED] = committed
    cfg[L.O_MAX_LATENCY_S] = MAX_BEARING_LATENCY_S
    cfg[L.O_VELOCITY_NOISE_PRIOR_MPS] = VELOCITY_NOISE_PRIOR_MPS
    cfg[L.O_WK_EST], cfg[L.O_WK_OBS], _ = _scratch_offsets(c.n, c.hypotheses, capacity(c))
    cfg[L.O_BANK :] = bp
    return cfg


def capacity(config: ObserverConfig) -> int:
    """Rows of each sample buffer: ``max_buffer`` waiting, the anchors, one arriving."""
    return config.max_buffer + 3


def bank_scratch_size(n: int, hypotheses: int) -> int:
    """Floats of scratch one run of the filter bank needs (its filters' updates and merge)."""
    d2 = 2 * n
    return 8 * d2 * d2 + 16 * d2 + 8 * hypotheses + 64


def _scratch_offsets(n: int, hypotheses: int, cap: int) -> tuple[int, int, int]:
    """Where the estimator's and the observer step's scratch start, and the whole size."""
    d2 = 2 * n
    est = bank_scratch_size(n, hypotheses)
    obs = est + 4 * d2 + d2 * d2 + 8
    return est, obs, obs + 3 * cap + 8 + 16 * n + 4 * d2 * d2 + 8 * n * n + 64


def new_state(config: ObserverConfig, committed: bool = False) -> ObserverState:
    """The arrays of a new observer of ``config`` in one buffer, reset (:func:`reset`)."""
    n, hyp = config.n, config.hypotheses
    cap = capacity(config)
    cfg = config_array(config, committed)
    shapes = {
        L.A_CFG: cfg.shape,
        L.A_S: (L.OFF_LOGW + hyp,),
        L.A_VEC: (L.R_FIXED + n, n),
        L.A_FS: (hyp + 3, 2 * n),
        L.A_FP: (hyp + 3, 2 * n, 2 * n),
        L.A_VBUF: (cap, 2 + 2 * n),
        L.A_BBUF: (cap, 3 + n),  # t, y, range (NaN: none) and its variance
        L.A_WIN: (config.window_buckets + 2, 3 + n * n + 2 * n),
        L.A_OUT: (cap + 2, L.E_FIXED + 4 * n),
        L.A_WK: (_scratch_offsets(n, hyp, cap)[2],),
    }
    at = 0
    where = {}
    for a in range(L.A_COUNT):
        where[a] = at
        shape = shapes[a]
        o = L.O_ARRAYS + 4 * a
        cfg[o] = at
        cfg[o + 1 : o + 1 + len(shape)] = shape
        at += math.prod(shape)
    buf = np.zeros(at)
    buf[: cfg.shape[0]] = cfg

    def view(a: int) -> np.ndarray:
        return buf[where[a] : where[a] + math.prod(shapes[a])].reshape(shapes[a])

    st = ObserverState(
        buf=buf, cfg=view(L.A_CFG), s=view(L.A_S), vec=view(L.A_VEC), fs=view(L.A_FS),
        fp=view(L.A_FP), vbuf=view(L.A_VBUF), bbuf=view(L.A_BBUF), win=view(L.A_WIN),
        out=view(L.A_OUT), wk=view(L.A_WK),
    )  # fmt: skip
    reset(st, config)
    return st


def reset_streams(q: np.ndarray) -> None:
    """The sample streams' scalars (``layout.Q_*``) as before any sample."""
    q[:] = 0.0
    q[L.Q_VDT] = L.DEFAULT_VELOCITY_DT_S
    q[L.Q_EX_WP] = L.EXTRAPOLATION_PRIOR_WEIGHT
    q[L.Q_EX_SP] = L.EXTRAPOLATION_PRIOR_WEIGHT * L.EXTRAPOLATION_PRIOR_MPS2**2


def reset(st: ObserverState, config: ObserverConfig) -> None:
    """Back to the configured initial state, not started."""
    for name in SAVED:
        getattr(st, name)[...] = 0.0
    s = st.s
    for i in (L.S_T_C, L.S_SINCE, L.S_DIAG_T, L.S_T_BEARING):
        s[i] = math.nan
    s[L.S_STATUS] = L.STALE
    reset_streams(s[L.OFF_Q : L.OFF_Q + L.Q_COUNT])
    for i in (L.L_T, L.L_T0, L.L_B_T0):
        s[L.OFF_LAT + i] = math.nan
    s[L.OFF_SET + L.T_REF] = math.nan
    s[L.OFF_VN + L.V_WP] = L.VN_PRIOR_SAMPLES
    s[L.OFF_VN + L.V_SP] = L.VN_PRIOR_SAMPLES * VELOCITY_NOISE_PRIOR_MPS**2
    xh1, m, ahat = config.initial_state()
    st.vec[L.R_XH1] = xh1
    st.vec[L.R_AHAT] = ahat
    st.vec[L.R_M : L.R_M + config.n] = m


def to_dict(st: ObserverState) -> dict[str, Any]:
    """The saved arrays, JSON-serialisable (NaN as ``None``; floats round-trip exactly)."""
    out: dict[str, Any] = {}
    for name in SAVED:
        arr = getattr(st, name)
        out[name] = {
            "shape": list(arr.shape),
            "data": [None if math.isnan(v) else v for v in arr.ravel().tolist()],
        }
    return out


def restore(st: ObserverState, d: Any, config: ObserverConfig) -> None:
    """Restore the arrays saved by :func:`to_dict` into ``st`` (made for ``config``): each
    of the right shape, finite or NaN; a bad one is a :class:`StateError` naming it."""
    if not isinstance(d, dict):
        raise StateError(f"observer state 'arrays' must be a table, got {type(d).__name__}")
    for name in SAVED:
        target = getattr(st, name)
        raw = d.get(name)
        try:
            shape = tuple(int(v) for v in raw["shape"])
            data = np.array([math.nan if v is None else float(v) for v in raw["data"]], dtype=float)
        except (KeyError, TypeError, ValueError) as exc:
            raise StateError(f"observer state 'arrays.{name}' is malformed: {exc!r}") from exc
        if shape != target.shape or data.size != target.size:
            raise StateError(
                f"observer state 'arrays.{name}' has shape {shape}, this configuration's is "
                f"{target.shape}"
            )
        if np.any(np.isinf(data)):
            raise StateError(f"observer state 'arrays.{name}' holds an infinite value")
        target[...] = data.reshape(shape)
    s = st.s
    cap = st.vbuf.shape[0]
    nv, nb = s[L.OFF_Q + L.Q_NV], s[L.OFF_Q + L.Q_NB]
    f = s[L.OFF_BS + L.B_F]
    started = s[L.S_STARTED] != 0.0
    bad = (
        not (0 <= nv < cap and 0 <= nb < cap)
        or (started and config.estimator == "riccati" and not 1 <= f <= config.hypotheses)
        or (started and math.isnan(s[L.S_T_C]))
    )
    if bad:
        raise StateError(
            f"observer state 'arrays.s' is inconsistent (samples held {nv:g} and {nb:g}, "
            f"hypotheses {f:g}, started {started})"
        )
