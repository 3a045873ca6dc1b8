"""The observer: velocity and bearing samples in, estimates of the relative position ``x``
and the constant velocity term ``a`` out (the paper's model ``x' = v + a``, ``y = x/|x|``;
conventions in :mod:`mav_observer.core.samples`).

:class:`BiasObserver` checks each sample and hands it to the compiled core in one call
(:mod:`mav_observer.core.kernels.observer`), which holds the whole state in arrays
(:mod:`mav_observer.core.state`): the sample streams, the estimator (the filter bank by
default, ``docs/estimator.md``; the paper's observer, ``docs/observer.md``), the monitor
and what is learnt online. How samples become the continuous equations' inputs, the
committed state and the static hold: ``docs/observer.md``. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from math import isnan
from typing import Any

import numpy as np

from mav_observer.core import compiled
from mav_observer.core import state as state_mod
from mav_observer.core.config import (
    AUTO,
    BEARING_NOISE_FLOOR_DEG,
    BEARING_NOISE_PRIOR_DEG,
    DEFAULT_RANGE_GUESS_M,
    ESTIMATORS,
    INTERPOLATIONS,
    MODES,
    VELOCITY_NOISE_PRIOR_MPS,
    ObserverConfig,
    outlier_nis,
)
from mav_observer.core.kernels import layout as L
from mav_observer.core.samples import (
    BearingSample,
    Correlation,
    Estimate,
    NoiseLevels,
    Status,
    VelocitySample,
    _check_time,
    _frozen_vector,
)
from mav_observer.errors import ConfigError, InvalidSampleError, StateError

__all__ = [
    "AUTO",
    "BEARING_NOISE_FLOOR_DEG",
    "BEARING_NOISE_PRIOR_DEG",
    "DEFAULT_RANGE_GUESS_M",
    "ESTIMATORS",
    "INTERPOLATIONS",
    "MODES",
    "STATE_SCHEMA",
    "VELOCITY_NOISE_PRIOR_MPS",
    "BiasObserver",
    "ObserverConfig",
    "outlier_nis",
]

STATE_SCHEMA = state_mod.STATE_SCHEMA
#: The statuses by their code in the kernels (``layout.STALE`` ...).
_STATUS = (Status.STALE, Status.NOT_OBSERVABLE, Status.CONVERGING, Status.CONVERGED)
#: The scalar columns of an estimate row, in the order :meth:`BiasObserver._row_estimate`
#: unpacks them; the vectors follow.
_ROW = (L.E_T, L.E_RANGE, L.E_EXCITATION, L.E_COND, L.E_STATUS, L.E_CORRECTED,
        L.E_BEARING_AGE, L.E_VELOCITY_AGE, L.E_CORRECTION_REL, L.E_RANGE_STD, L.E_NIS,
        L.E_HAS_COV)  # fmt: skip
_ROW_SCALARS = len(_ROW)
assert tuple(range(_ROW_SCALARS)) == _ROW and _ROW_SCALARS == L.E_FIXED


class BiasObserver:
    """One observer: feed it :class:`VelocitySample` and :class:`BearingSample`, read
    :class:`Estimate`. A rejected sample raises :class:`InvalidSampleError` and leaves the
    observer exactly as it was."""

    def __init__(self, config: ObserverConfig | None = None, *, committed: bool = False) -> None:
        """``committed``: besides the live estimates, keep the estimate at each bearing's time
        once the state is committed through it (the velocity around it known: at most one
        velocity interval later), read with :meth:`take_committed`; bearings are then given
        with :meth:`add_bearing_values` (``replay``'s default, ``docs/cli.md``)."""
        self.config = config if config is not None else ObserverConfig()
        if not isinstance(self.config, ObserverConfig):
            raise ConfigError(f"config must be an ObserverConfig, got {type(config).__name__}")
        self._k = compiled.kernels()
        self._committed_mode = committed
        self._n = self.config.n
        self._st = state_mod.new_state(self.config, committed)
        self._buf = self._st.buf
        n2 = 2 * self._n
        self._s_out = np.zeros(n2)
        self._p_out = np.zeros((n2, n2))
        self._none = np.zeros(self._n)  # (an input an operation does not read)
        self._no_range = np.array([math.nan, 0.0])  # a bearing without a measured range
        self._live_row = self._st.out[-1]
        n, x0 = self._n, L.E_FIXED
        self._slices = tuple(slice(x0 + k * n, x0 + (k + 1) * n) for k in range(4))
        self._estimate: Estimate | None = None
        #: the committed estimates at bearing times not yet taken (``committed=True``)
        self._committed: list[Estimate] = []
        #: re-acquisitions seen, the time of the open one (NaN: none), the time since
        #: re-acquiring until converged again summed, the latest estimate's time
        self._reacq = [0.0, math.nan, 0.0, math.nan]
        self._bank = self._st.cfg[L.O_KIND] == L.KIND_BANK

    def reset(self) -> None:
        """Forget everything: back to the configured initial state, not started."""
        state_mod.reset(self._st, self.config)
        self._estimate = None
        self._committed = []
        self._reacq = [0.0, math.nan, 0.0, math.nan]

    def _account(self, est: Estimate) -> Estimate:
        """Time spent re-acquiring: from a re-seeding to the next ``converged`` estimate."""
        r = self._reacq
        n = self._st.s[L.OFF_BS + L.B_RESEEDS] if self._bank else 0.0
        if n != r[0]:
            r[0] = n
            if math.isnan(r[1]):
                r[1] = est.t_s
        if not math.isnan(r[1]) and est.status is Status.CONVERGED:
            r[2] += max(est.t_s - r[1], 0.0)
            r[1] = math.nan
        r[3] = est.t_s
        return est

    @property
    def reacquiring_s(self) -> float:
        """Time (s) its estimates spent re-acquiring: from each re-seeding (the bearings
        stopped agreeing with the estimate) to its next ``converged`` estimate, or to the
        latest estimate while still re-acquiring."""
        r = self._reacq
        return r[2] + (0.0 if math.isnan(r[1]) else max(r[3] - r[1], 0.0))

    # -- public properties ----------------------------------------------------------
    @property
    def started(self) -> bool:
        """True once both streams have delivered and integration has begun."""
        return not math.isnan(self._st.s[L.S_T_C])

    @property
    def committed_t_s(self) -> float | None:
        """Time (s) of the committed state, the data horizon (``None`` before start)."""
        t = float(self._st.s[L.S_T_C])
        return None if math.isnan(t) else t

    @property
    def estimate(self) -> Estimate | None:
        """The latest estimate produced (by a bearing update or :meth:`predict`)."""
        return self._estimate

    def _output(self) -> bool:
        """The committed estimate into ``_s_out`` and its covariance into ``_p_out``."""
        k = self._k
        has = k.run(k.OP_OUTPUT, self._buf, 0.0, self._none, self._none)
        d2 = 2 * self._n
        o = int(self._st.cfg[L.O_WK_OBS])
        wk = self._st.wk
        self._s_out[:] = wk[o : o + d2]
        self._p_out[:] = wk[o + d2 : o + d2 + d2 * d2].reshape(d2, d2)
        return bool(has)

    @property
    def x_m(self) -> list[float]:
        """``xhat`` of the committed state (m), a copy."""
        self._output()
        return self._s_out[: self._n].tolist()

    @property
    def a_mps(self) -> list[float]:
        """``ahat`` of the committed state (m/s), a copy."""
        self._output()
        return self._s_out[self._n :].tolist()

    @property
    def covariance(self) -> np.ndarray | None:
        """Covariance of ``[xhat, ahat]`` at the committed time ((2n, 2n), m and m/s), for an
        estimator that has one (``None`` for the paper's observer)."""
        return self._p_out.copy() if self._output() else None

    def predicted_displacement_m(self, t0_s: float, t1_s: float) -> list[float] | None:
        """The integral of ``v`` (the paper's, ``-u``) from ``t0_s`` to ``t1_s`` (m) as the
        estimates are predicted with it: the velocity samples, and past the latest the held
        velocity or, for intervals known from the positions, the latest trend
        (``docs/frames.md``, "Velocity from the positions"); ``None`` before any velocity.
        ``x`` moves by it plus ``a`` times the span."""
        st = self._st
        if st.s[L.OFF_Q + L.Q_NV] == 0:
            return None
        k = self._k
        t1 = np.array([float(t1_s)] * self._n)
        k.run(k.OP_DISPLACEMENT, self._buf, float(t0_s), t1, t1)
        return self._st.out[0, : self._n].tolist()

    @property
    def status(self) -> Status:
        """The status of the latest estimate (``stale`` before any)."""
        return _STATUS[int(self._st.s[L.S_STATUS])]

    @property
    def settled(self) -> bool:
        """True once what the estimator learns no longer moves its estimate for long (the
        learnt bearings' latency has settled once); no estimate is ``converged`` before."""
        s, cfg = self._st.s, self._st.cfg
        if cfg[L.O_KIND] != L.KIND_BANK or not math.isnan(cfg[L.O_LATENCY_S]):
            return True
        return bool(s[L.S_SETTLED])

    @property
    def latency_learning_since_s(self) -> float | None:
        """When (s) the bearings' latency began to be learnt (``None``: not yet, or told)."""
        t = float(self._st.s[L.OFF_LAT + L.L_T0])
        return None if isnan(t) else t

    @property
    def hypotheses(self) -> int:
        """The filter bank's hypotheses alive (0 before the start or for the paper's)."""
        if self._st.cfg[L.O_KIND] != L.KIND_BANK or not self._st.s[L.S_STARTED]:
            return 0
        return int(self._st.s[L.OFF_BS + L.B_F])

    @property
    def counts(self) -> dict[str, int]:
        """Samples accepted per stream."""
        s = self._st.s
        return {"velocity": int(s[L.S_N_VELOCITY]), "bearing": int(s[L.S_N_BEARING])}

    @property
    def buffered(self) -> dict[str, int]:
        """Samples held per stream: the interpolation anchors and those waiting for the other
        stream (bounded by ``max_buffer``)."""
        s = self._st.s
        return {"velocity": int(s[L.OFF_Q + L.Q_NV]), "bearing": int(s[L.OFF_Q + L.Q_NB])}

    @property
    def reacquisitions(self) -> int:
        """Times the filter bank started again from its Riccati observer because its
        bearings stopped agreeing with it (0 for the paper's observer)."""
        bank = self._st.cfg[L.O_KIND] == L.KIND_BANK
        return int(self._st.s[L.OFF_BS + L.B_RESEEDS]) if bank else 0

    def bearing_noise_var(self) -> float | None:
        """The bearing noise variance in use (rad^2 per tangent axis, learnt or told) alone,
        cheap enough for every bearing; ``None`` for the paper's observer."""
        cfg, s = self._st.cfg, self._st.s
        if cfg[L.O_KIND] != L.KIND_BANK:
            return None
        bp = cfg[L.O_BANK :]
        if not bp[L.P_LEARN_NOISE] or not s[L.S_STARTED]:
            return float(bp[L.P_SIGMA_RAD]) ** 2
        v = float(s[L.OFF_BS + L.B_NOISE_BETA] / s[L.OFF_BS + L.B_NOISE_ALPHA])
        return min(max(v, float(bp[L.P_NOISE_MIN_RAD]) ** 2), float(bp[L.P_NOISE_MAX_RAD]) ** 2)

    def noise(self) -> NoiseLevels | None:
        """The noise levels in use (learnt or told) and the robust update's counts, for the
        filter bank; ``None`` for the paper's observer."""
        cfg, s = self._st.cfg, self._st.s
        var = self.bearing_noise_var()
        if var is None:
            return None
        bp = cfg[L.O_BANK :]
        bs = s[L.OFF_BS : L.OFF_BS + L.B_COUNT]
        vel = told_v = float(cfg[L.O_VELOCITY_NOISE_MPS])
        if math.isnan(told_v):
            vn = s[L.OFF_VN : L.OFF_VN + L.V_COUNT]
            w = vn[L.V_W] + vn[L.V_WP]
            prior = float(cfg[L.O_VELOCITY_NOISE_PRIOR_MPS])
            vel = math.sqrt((vn[L.V_S] + vn[L.V_SP]) / w) if w > 0.0 else prior
        told_l = float(cfg[L.O_LATENCY_S])
        tau = float(s[L.OFF_LAT + L.L_TAU]) if math.isnan(told_l) else told_l
        learn_walk = bool(bp[L.P_LEARN_WALK])
        q_a = float(bs[L.B_WALK_Q]) if learn_walk else float(bp[L.P_Q_A])
        return NoiseLevels(
            bearing_noise_deg=math.degrees(math.sqrt(var)),
            bearing_noise_learnt=bool(bp[L.P_LEARN_NOISE]),
            velocity_noise_mps=float(vel),
            velocity_noise_learnt=math.isnan(told_v),
            bearings=int(bs[L.B_BEARINGS]),
            outliers=int(bs[L.B_OUTLIERS]),
            reacquisitions=int(bs[L.B_RESEEDS]),
            reacquiring_s=self.reacquiring_s,
            bearing_latency_s=tau,
            bearing_latency_learnt=math.isnan(told_l),
            bias_walk_mps_per_sqrt_s=math.sqrt(q_a),
            bias_walk_learnt=learn_walk,
            innovation_corr=self._correlation(),
        )

    def _correlation(self) -> Correlation | None:
        """The innovations' lag-1 correlation so far (``None`` before 30 pairs)."""
        wh = self._st.s[L.OFF_WH : L.OFF_WH + L.W_COUNT].tolist()
        pairs, c0 = wh[L.W_N], wh[L.W_C0]
        if pairs < 30.0 or not c0 > 0.0:  # (kernels.learners.WH_MIN_PAIRS)
            return None
        lag1 = max(-1.0, min(1.0, wh[L.W_C1] / c0))
        mean_dt = wh[L.W_DT] / pairs
        tau: float | None
        if lag1 <= 0.0:
            tau = None
        elif lag1 >= 1.0:
            tau = math.inf
        else:
            tau = -mean_dt / math.log(lag1)
        var_ratio = c0 / pairs / (self._n - 1)
        return Correlation(lag1=lag1, corr_time_s=tau, var_ratio=var_ratio, pairs=pairs)

    # the paper's state
    def _paper(self, name: str) -> None:
        if self._st.cfg[L.O_KIND] != L.KIND_PAPER:
            raise StateError(
                f"{name} belongs to the paper's observer, this one is {self.config.estimator}"
            )

    @property
    def zs_mps(self) -> np.ndarray:
        """The paper's dual state ``zs = ahat + M^-1 xh1`` of the committed state (m/s)."""
        self._paper("zs_mps")
        return np.array(self.a_mps) + np.linalg.solve(self.m_s, self.xh1_m)

    @property
    def xh1_m(self) -> np.ndarray:
        """The first filter ``xh1`` of the committed state (m)."""
        self._paper("xh1_m")
        return self._st.vec[L.R_XH1].copy()

    @property
    def m_s(self) -> np.ndarray:
        """The matrix ``M`` of the committed state (s)."""
        self._paper("m_s")
        return self._st.vec[L.R_M : L.R_M + self._n].copy()

    # -- input ----------------------------------------------------------------------
    def _fail(self, code: int, kind: str, t_s: float) -> None:
        s, st = self._st.s, self._st
        if code == L.ERR_VELOCITY_BACKWARDS:
            prev = st.vbuf[int(s[L.OFF_Q + L.Q_NV]) - 1, 0]
            raise InvalidSampleError(
                f"velocity t_s={t_s} is before the previous velocity sample t_s={prev}: "
                "time went backwards"
            )
        if code == L.ERR_BEARING_BACKWARDS:
            prev = st.bbuf[int(s[L.OFF_Q + L.Q_NB]) - 1, 0]
            raise InvalidSampleError(
                f"bearing t_s={t_s} is before the previous bearing sample t_s={prev}: "
                "time went backwards"
            )
        if code == L.ERR_BEARING_TOO_OLD:
            raise InvalidSampleError(
                f"bearing t_s={t_s} is older than the observer's committed time "
                f"t_s={self.committed_t_s} (it arrived more than max_bearing_age_s late)"
            )
        if code == L.ERR_BEFORE_COMMITTED:
            raise InvalidSampleError(
                f"predict t_s={t_s} is before the observer's committed time "
                f"t_s={self.committed_t_s}"
            )
        raise InvalidSampleError(
            f"{kind} t_s={t_s} refused: the sample buffer is full ({self.buffered})"
        )

    def _take_rows(self, k: int) -> None:
        """The ``k`` committed estimates the kernel wrote into ``out``."""
        if k > 0 and self._committed_mode:
            out = self._st.out
            self._committed.extend(self._account(self._row_estimate(out[i])) for i in range(k))

    def _row_estimate(self, row: np.ndarray) -> Estimate:
        """An estimate from a row of ``out`` (``layout.E_*``, in :data:`_ROW` order): its
        arrays are read-only views of a private copy (it runs at every bearing)."""
        r = row.copy()
        r.setflags(write=False)
        t, rng, exc, cond, status, corrected, b_age, v_age, corr, r_std, nis, has_cov = r[
            :_ROW_SCALARS
        ].tolist()
        sx, sa, ssx, ssa = self._slices
        return tuple.__new__(Estimate, (
            t, r[sx], r[sa], rng, exc, cond, _STATUS[int(status)], corrected != 0.0,
            None if isnan(b_age) else b_age, None if isnan(v_age) else v_age, corr,
            r[ssx] if has_cov else None, r[ssa] if has_cov else None,
            r_std if has_cov else None, None if isnan(nis) else nis,
        ))  # fmt: skip

    def _live(self) -> Estimate:
        est = self._row_estimate(self._live_row)
        if not self._committed_mode:
            self._account(est)
        self._estimate = est
        return est

    def _velocity(self, t: float, v: np.ndarray, mean: np.ndarray | None) -> None:
        k = self._k
        if mean is None:
            code = k.run(k.OP_VELOCITY, self._buf, t, v, v)
        else:
            code = k.run(k.OP_VELOCITY_MEAN, self._buf, t, v, mean)
        if code < 0:
            self._fail(code, "velocity", t)
        if code:
            self._take_rows(code)

    def _bearing(
        self, t: float, y: np.ndarray, live: bool, range_m: float | None, range_std_m: float
    ) -> None:
        k = self._k
        op = k.OP_BEARING_LIVE if live else k.OP_BEARING
        w = self._no_range if range_m is None else np.array([range_m, range_std_m**2])
        code = k.run(op, self._buf, t, y, w)
        if code < 0:
            self._fail(code, "bearing", t)
        if code:
            self._take_rows(code)

    def _check_dim(self, dim: int, name: str, t_s: float) -> None:
        if dim != self._n:
            raise InvalidSampleError(
                f"{name} at t_s={t_s} has dimension {dim}, the observer has n={self._n}"
            )

    def update_velocity(self, sample: VelocitySample) -> None:
        """Accept a velocity sample (the paper's ``v``; for a vehicle minus its velocity)."""
        if not isinstance(sample, VelocitySample):
            raise InvalidSampleError(f"expected a VelocitySample, got {type(sample).__name__}")
        v = sample.v_mps
        if v.shape[0] != self._n:
            self._check_dim(v.shape[0], "velocity v_mps", sample.t_s)
        self._velocity(sample.t_s, np.array(v), None)

    def update_bearing(self, sample: BearingSample) -> Estimate:
        """Accept a bearing sample and return the estimate at its time."""
        if not isinstance(sample, BearingSample):
            raise InvalidSampleError(f"expected a BearingSample, got {type(sample).__name__}")
        y = sample.y
        if y.shape[0] != self._n:
            self._check_dim(y.shape[0], "bearing y", sample.t_s)
        self._bearing(sample.t_s, np.array(y), True, sample.range_m, sample.range_std_m)
        return self._live()

    def update_velocity_values(
        self,
        t_s: float,
        v_mps: Sequence[float],
        interval_mean_mps: Sequence[float] | None = None,
    ) -> None:
        """:meth:`update_velocity` for a caller that already checked the sample (finite
        floats, the observer's dimension): no sample object is built.

        ``interval_mean_mps``: the mean of ``v`` (m/s, the paper's sign) over the interval
        from the previous velocity sample to this one, when it is known better than the
        average of the two samples (for a vehicle, from the change of its position: see
        ``docs/frames.md``, "Velocity from the positions"). The velocity on that interval is
        then the linear interpolation of the two samples shifted by a constant so that its
        mean is that (the samples' shape, the positions' displacement: on a smooth turn the
        shape is far closer than a straight line, and the displacement is exact)."""
        mean = None if interval_mean_mps is None else np.array(interval_mean_mps, dtype=float)
        self._velocity(float(t_s), np.array(v_mps, dtype=float), mean)

    def update_bearing_values(
        self, t_s: float, y: Sequence[float], range_m: float | None = None, range_std_m: float = 1.0
    ) -> Estimate:
        """:meth:`update_bearing` for a caller that already checked the sample (finite
        floats, unit length, the observer's dimension; a range positive and finite)."""
        self._bearing(float(t_s), np.array(y, dtype=float), True, range_m, range_std_m)
        return self._live()

    def add_bearing_values(
        self, t_s: float, y: Sequence[float], range_m: float | None = None, range_std_m: float = 1.0
    ) -> None:
        """Accept a checked bearing (as :meth:`update_bearing_values`) without a live
        estimate at its time: with ``committed=True`` its estimate comes, with those of the
        other bearings, from :meth:`take_committed` once the velocity around it is known."""
        self._bearing(float(t_s), np.array(y, dtype=float), False, range_m, range_std_m)

    def take_committed(self) -> list[Estimate]:
        """The estimates at the bearing times the state has been committed through since the
        previous call, in time order (``committed=True``; else always empty). Each is the
        filtered estimate at its bearing, that bearing applied, with the velocity
        interpolated around it: nothing after the next velocity sample is used."""
        out, self._committed = self._committed, []
        return out

    def commit_pending(self) -> list[Estimate]:
        """At the end of the data: commit through the latest bearing even though no velocity
        follows it (the latest velocity held, as a live estimate would have it) and return
        :meth:`take_committed`."""
        k = self._k
        self._take_rows(k.run(k.OP_COMMIT_PENDING, self._buf, 0.0, self._none, self._none))
        return self.take_committed()

    def predict(self, t_s: float) -> Estimate:
        """Estimate at ``t_s`` from the data so far.

        Integrates what the samples received determine (up to the data horizon, as any later
        update would), then predicts the rest (``xhat' = v + ahat``, not committed). Once the
        latest bearing is older than ``max_bearing_age_s`` the status is ``stale``.
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise InvalidSampleError(f"t_s={t_s!r} is not finite")
        k = self._k
        code = k.run(k.OP_PREDICT, self._buf, t, self._none, self._none)
        if code < 0:
            self._fail(code, "predict", t)
        self._take_rows(code)
        return self._live()

    def resume(self, t_s: float, dx_m: Sequence[float], v_mps: Sequence[float]) -> None:
        """Carry the observer across a gap in its data (a service restart) to ``t_s``.

        The estimate moves by ``dx_m`` (m), the change of ``x`` over the gap known from
        elsewhere: for a vehicle and a target that stays put in the autopilot's local frame,
        minus the vehicle's displacement in that frame (``ahat`` is not integrated over the
        gap: where the local position is GPS-true, ``a`` is the velocity's error, which
        does not move the target in that frame). The velocity ``v_mps`` (the paper's ``v``)
        holds from ``t_s``. What the observer had learnt, its excitation window and its
        status carry over (shifted in time by the gap). Raises :class:`StateError` if the
        observer never started or ``t_s`` is before its committed time,
        :class:`InvalidSampleError` for a non-finite or wrong-sized argument.
        """
        t_c = self.committed_t_s
        if t_c is None:
            raise StateError("resume: the observer has not started, there is nothing to carry")
        t = _check_time(t_s)
        if t < t_c:
            raise StateError(f"resume t_s={t} is before the committed time t_s={t_c}")
        dx = _frozen_vector("dx_m", dx_m, t)
        v = _frozen_vector("v_mps", v_mps, t)
        if len(dx) != self._n or len(v) != self._n:
            raise InvalidSampleError(f"resume: dx_m and v_mps must have dimension n={self._n}")
        k = self._k
        k.run(k.OP_RESUME, self._buf, t, np.array(dx), np.array(v))
        self._estimate = None

    # -- persistence ----------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The whole observer as a JSON-serialisable dictionary; :meth:`from_dict` restores
        it exactly (floats round-trip through JSON bit for bit)."""
        return {
            "schema": STATE_SCHEMA,
            "config": self.config.to_dict(),
            "arrays": state_mod.to_dict(self._st),
            "estimate": None if self._estimate is None else self._estimate.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any], *, committed: bool = False) -> BiasObserver:
        """Restore an observer saved by :meth:`to_dict` (``committed`` as in the constructor);
        a bad field is a :class:`StateError` naming it."""
        if not isinstance(d, dict):
            raise StateError(f"observer state must be a dictionary, got {type(d).__name__}")
        if d.get("schema") != STATE_SCHEMA:
            raise StateError(f"observer state schema {d.get('schema')!r} is not {STATE_SCHEMA}")
        try:
            config = ObserverConfig.from_dict(d["config"])
        except ConfigError as exc:
            raise StateError(f"config: {exc}") from exc
        except KeyError as exc:
            raise StateError("observer state has no 'config'") from exc
        obs = cls(config, committed=committed)
        state_mod.restore(obs._st, d.get("arrays"), config)
        if obs._bank:  # the re-seedings before the save are not this run's to time
            obs._reacq[0] = obs._st.s[L.OFF_BS + L.B_RESEEDS]
        est = d.get("estimate")
        if est is not None:
            obs._estimate = _estimate_from_dict(est)
        return obs


def _optional_array(v: Any) -> np.ndarray | None:
    if v is None:
        return None
    arr = np.array(v, dtype=float)
    arr.setflags(write=False)
    return arr


def _estimate_from_dict(e: Any) -> Estimate:
    try:
        return Estimate(
            t_s=float(e["t_s"]),
            x_m=_optional_array(e["x_m"]),  # type: ignore[arg-type]
            a_mps=_optional_array(e["a_mps"]),  # type: ignore[arg-type]
            range_m=float(e["range_m"]),
            excitation=float(e["excitation"]),
            cond_m=float(e["cond_m"]),
            status=Status(e["status"]),
            corrected=bool(e["corrected"]),
            bearing_age_s=None if e["bearing_age_s"] is None else float(e["bearing_age_s"]),
            velocity_age_s=None if e["velocity_age_s"] is None else float(e["velocity_age_s"]),
            correction_rel=float(e["correction_rel"]),
            x_std_m=_optional_array(e.get("x_std_m")),
            a_std_mps=_optional_array(e.get("a_std_mps")),
            range_std_m=None if e.get("range_std_m") is None else float(e["range_std_m"]),
            nis=None if e.get("nis") is None else float(e["nis"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise StateError(f"observer state 'estimate' is malformed: {exc!r}") from exc
