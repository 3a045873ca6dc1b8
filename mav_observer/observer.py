"""Estimators of position and velocity bias from a single direction, in R^n.

:class:`BiasObserver` turns separately arriving, irregularly timed velocity and bearing
samples into estimates of the relative position ``x`` and the constant velocity term ``a``
(see :mod:`mav_observer.samples` for the conventions). It owns the sample handling
(:class:`~mav_observer.streams.SampleStreams`), the monitor and status
(:mod:`mav_observer.monitor`) and the persistence, written once around any estimator of the
registry (:data:`mav_observer.estimators.REGISTRY`, ``ObserverConfig.estimator``):

* ``riccati`` (default): a bank of extended Kalman filters supervised by a Riccati observer,
  with a covariance (:mod:`mav_observer.estimators.riccati`, ``docs/estimator.md``):
  predicted between sample times, updated at each bearing sample;
* ``paper``: the observer of Le Bras, Hamel, Mahony and Samson (2015), exact
  (:mod:`mav_observer.estimators.paper`), integrated as described below.

Pure: no I/O, no clock; time is whatever the samples carry.

How samples become inputs of the continuous equations
------------------------------------------------------
* Between two consecutive samples of a stream the input is **linearly interpolated**
  (a bearing is interpolated along the chord and re-normalised), as long as the two are at
  most the stream's maximum age apart; otherwise the earlier value is held.
  ``interpolation="hold"`` holds each sample from its time to the next instead (zero-order
  hold: simpler, markedly less accurate).
* After the latest sample of a stream its value is **held**: a bearing for at most
  ``max_bearing_age_s``, after which there is no correction term (the observer only
  predicts, ``xhat' = v + ahat``); a velocity indefinitely, the status saying ``stale`` once
  it is older than ``max_velocity_age_s``.
* The observer keeps a **committed state** at the latest time both streams cover (the data
  horizon), integrated with interpolated inputs. Estimates at later times (the time of a
  bearing whose velocity has not arrived yet, or :meth:`BiasObserver.predict`) are computed
  from it with held inputs and are never committed, so late-arriving samples still count.
* **Static-geometry hold** (``static_hold``, on by default, off in
  :meth:`ObserverConfig.paper`): when the observer's own estimate of the relative velocity
  ``v + ahat`` is below ``hold_speed_mps`` and the bearing agrees with the estimate's
  direction (within ``hold_innovation_deg``), the state is held instead of integrated.
  The bearing then only confirms the estimate: range and the bias along the line of sight
  are not observable, and integrating would turn any residual bias error into a range drift
  that grows without bound (and ``M`` with it). This is the observer's analogue of an
  inertial navigator's zero-velocity update; any motion or bearing change ends it at once.
* A stream that goes silent does not hold up the other: when the bearing is older than its
  maximum age, the horizon follows the velocity (and vice versa).

Each interval between breakpoints is integrated in ``discrete.substep_count`` sub-steps with
inputs frozen at the sub-step midpoints, closed-form for ``xh1`` and ``M``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from mav_observer import discrete, riccati
from mav_observer.config import (
    AUTO,
    BEARING_NOISE_FLOOR_DEG,
    BEARING_NOISE_PRIOR_DEG,
    DEFAULT_RANGE_GUESS_M,
    INTERPOLATIONS,
    MODES,
    VELOCITY_NOISE_PRIOR_MPS,
    ObserverConfig,
    estimator_names,
    outlier_nis,
)
from mav_observer.errors import ConfigError, InvalidSampleError, StateError
from mav_observer.estimators import REGISTRY, Estimator, PaperEstimator
from mav_observer.estimators.riccati import CHORD_NOISE_MPS
from mav_observer.monitor import ExcitationWindow, StatusMemory, next_status
from mav_observer.samples import (
    BearingSample,
    Estimate,
    NoiseLevels,
    Status,
    VelocitySample,
    _check_time,
    _frozen_vector,
)
from mav_observer.streams import MIN_INTERVAL_S, Sample, SampleStreams

__all__ = [
    "AUTO",
    "BEARING_NOISE_FLOOR_DEG",
    "BEARING_NOISE_PRIOR_DEG",
    "CHORD_NOISE_MPS",
    "DEFAULT_RANGE_GUESS_M",
    "DIAGNOSTICS_PERIOD_S",
    "ESTIMATORS",
    "INTERPOLATIONS",
    "MIN_INTERVAL_S",
    "MODES",
    "STATE_SCHEMA",
    "VELOCITY_NOISE_PRIOR_MPS",
    "BiasObserver",
    "ObserverConfig",
    "outlier_nis",
]

#: The estimators of the registry, the default first.
ESTIMATORS = estimator_names()
#: The excitation level describes the geometry over the monitor's window (seconds): it is
#: evaluated again at most this often (s of observer time), not for every estimate.
DIAGNOSTICS_PERIOD_S = 0.5
#: Version of the dictionary written by :meth:`BiasObserver.to_dict`.
STATE_SCHEMA = 2


def _stds(
    pxx: list[float], p: list[float], x: list[float], rng: float, n: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """From the position covariance ``pxx`` (flat n x n, m^2) and the whole one ``p`` (flat
    2n x 2n): the standard deviations of ``x`` (m) and ``a`` (m/s), read-only arrays, and the
    variance along ``x`` of range ``rng`` (m^2; along ``x`` itself if ``rng`` is 0)."""
    if n == 3:
        x_std = np.array(
            [math.sqrt(max(pxx[0], 0.0)), math.sqrt(max(pxx[4], 0.0)), math.sqrt(max(pxx[8], 0.0))]
        )
        a_std = np.array(
            [math.sqrt(max(p[21], 0.0)), math.sqrt(max(p[28], 0.0)), math.sqrt(max(p[35], 0.0))]
        )
        if rng > 0.0:
            u0, u1, u2 = x[0] / rng, x[1] / rng, x[2] / rng
        else:
            u0, u1, u2 = x
        var_r = (
            u0 * (pxx[0] * u0 + pxx[1] * u1 + pxx[2] * u2)
            + u1 * (pxx[3] * u0 + pxx[4] * u1 + pxx[5] * u2)
            + u2 * (pxx[6] * u0 + pxx[7] * u1 + pxx[8] * u2)
        )
    else:
        d = 2 * n
        x_std = np.array([math.sqrt(max(pxx[(n + 1) * i], 0.0)) for i in range(n)])
        a_std = np.array([math.sqrt(max(p[(d + 1) * (n + i)], 0.0)) for i in range(n)])
        u = [c / rng for c in x] if rng > 0.0 else x
        var_r = sum(u[i] * sum(pxx[n * i + j] * u[j] for j in range(n)) for i in range(n))
    x_std.setflags(write=False)
    a_std.setflags(write=False)
    return x_std, a_std, var_r


def _add_outer(acc: list[float], y: list[float], w: float) -> None:
    """``acc += w y y^T`` in place (flat, row-major)."""
    if len(y) == 3:
        y0, y1, y2 = y[0] * w, y[1] * w, y[2] * w
        acc[0] += y0 * y[0]
        acc[1] += y0 * y[1]
        acc[2] += y0 * y[2]
        acc[3] += y1 * y[0]
        acc[4] += y1 * y[1]
        acc[5] += y1 * y[2]
        acc[6] += y2 * y[0]
        acc[7] += y2 * y[1]
        acc[8] += y2 * y[2]
        return
    k = 0
    for p in y:
        for q in y:
            acc[k] += w * p * q
            k += 1


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
        self._thresholds = self.config.thresholds()
        self._keep_committed = committed
        self.reset()

    def reset(self) -> None:
        """Forget everything: back to the configured initial state, not started."""
        cfg = self.config
        self._est: Estimator = REGISTRY[cfg.estimator](cfg)
        self._t_c: float | None = None
        self._streams = SampleStreams(
            max_bearing_age_s=cfg.max_bearing_age_s,
            max_velocity_age_s=cfg.max_velocity_age_s,
            linear=cfg.interpolation == "linear",
            max_buffer=cfg.max_buffer,
        )
        self._window = ExcitationWindow(cfg.n, cfg.window_s, cfg.window_buckets)
        self._memory = StatusMemory()
        self._estimate: Estimate | None = None
        self._diag: tuple[float, float] | None = None  # t_s, excitation
        self._cond: tuple[float | None, float] | None = None  # committed t_s, cond
        self._counts = {"velocity": 0, "bearing": 0}
        #: the committed estimates at bearing times not yet taken (``committed=True``)
        self._committed: list[Estimate] = []

    # -- public properties ----------------------------------------------------------
    @property
    def estimator(self) -> Estimator:
        """The estimator at the committed time (read it; stepping it is the observer's job)."""
        return self._est

    @property
    def started(self) -> bool:
        """True once both streams have delivered and integration has begun."""
        return self._t_c is not None

    @property
    def committed_t_s(self) -> float | None:
        """Time (s) of the committed state, the data horizon (``None`` before start)."""
        return self._t_c

    @property
    def estimate(self) -> Estimate | None:
        """The latest estimate produced (by a bearing update or :meth:`predict`)."""
        return self._estimate

    @property
    def a_mps(self) -> list[float]:
        """``ahat`` of the committed state (m/s), a copy."""
        return list(self._est.output(self._streams).a_mps)

    @property
    def covariance(self) -> np.ndarray | None:
        """Covariance of ``[xhat, ahat]`` at the committed time ((2n, 2n), m and m/s), for an
        estimator that has one (``None`` for the paper's observer)."""
        p = self._est.output(self._streams).p
        if p is None:
            return None
        d = 2 * self.config.n
        return np.array(p, dtype=float).reshape(d, d)

    def predicted_displacement_m(self, t0_s: float, t1_s: float) -> list[float] | None:
        """The integral of ``v`` (the paper's, ``-u``) from ``t0_s`` to ``t1_s`` (m) as the
        estimates are predicted with it: the velocity samples, and past the latest the held
        velocity or, for intervals known from the positions, the latest trend
        (``docs/frames.md``, "Velocity from the positions"); ``None`` before any velocity.
        ``x`` moves by it plus ``a`` times the span."""
        if not self._streams.velocities:
            return None
        return self._streams.predicted_displacement(t0_s, t1_s)

    @property
    def status(self) -> Status:
        """The status of the latest estimate (``stale`` before any)."""
        return self._memory.status

    @property
    def counts(self) -> dict[str, int]:
        """Samples accepted per stream."""
        return dict(self._counts)

    @property
    def buffered(self) -> dict[str, int]:
        """Samples held per stream: the interpolation anchors and those waiting for the other
        stream (bounded by ``max_buffer``)."""
        return {"velocity": len(self._streams.velocities), "bearing": len(self._streams.bearings)}

    @property
    def reacquisitions(self) -> int:
        """Times the estimator started again (the riccati estimator from its Riccati
        observer) because its bearings stopped agreeing with it (0 for the paper's
        observer)."""
        return self._est.reacquisitions

    def noise(self) -> NoiseLevels | None:
        """The noise levels in use (learnt or told) and the robust update's counts, for the
        riccati estimator; ``None`` for the paper's observer."""
        return self._est.noise(self._streams)

    def _paper(self, name: str) -> PaperEstimator:
        if not isinstance(self._est, PaperEstimator):
            raise StateError(
                f"{name} belongs to the paper's observer, this one is {self.config.estimator}"
            )
        return self._est

    @property
    def zs_mps(self) -> np.ndarray:
        """The paper's dual state ``zs`` of the committed state (m/s)."""
        return self._paper("zs_mps").zs_mps

    @property
    def xh1_m(self) -> np.ndarray:
        """The first filter ``xh1`` of the committed state (m)."""
        return self._paper("xh1_m").xh1_m

    @property
    def m_s(self) -> np.ndarray:
        """The matrix ``M`` of the committed state (s)."""
        return self._paper("m_s").m_s

    # -- input ----------------------------------------------------------------------
    def _check_dim(self, dim: int, name: str, t_s: float) -> None:
        if dim != self.config.n:
            raise InvalidSampleError(
                f"{name} at t_s={t_s} has dimension {dim}, the observer has n={self.config.n}"
            )

    def _accept(self, kind: str, t_s: float, vec: list[float]) -> None:
        """Append a validated sample to its stream and advance; on failure, undo."""
        streams = self._streams
        streams.append(kind, t_s, vec, self._t_c)
        try:
            self._advance(lazy=kind == "velocity")
        except Exception:
            streams.pop(kind)
            raise
        self._counts[kind] += 1
        if kind == "velocity":
            self._est.observe_velocity(t_s, vec)

    def update_velocity(self, sample: VelocitySample) -> None:
        """Accept a velocity sample (the paper's ``v``; for a vehicle minus its velocity)."""
        if not isinstance(sample, VelocitySample):
            raise InvalidSampleError(f"expected a VelocitySample, got {type(sample).__name__}")
        self._check_dim(sample.dim, "velocity v_mps", sample.t_s)
        self._accept("velocity", sample.t_s, sample.v_mps.tolist())

    def update_bearing(self, sample: BearingSample) -> Estimate:
        """Accept a bearing sample and return the estimate at its time."""
        if not isinstance(sample, BearingSample):
            raise InvalidSampleError(f"expected a BearingSample, got {type(sample).__name__}")
        self._check_dim(sample.dim, "bearing y", sample.t_s)
        self._accept("bearing", sample.t_s, sample.y.tolist())
        return self._estimate_at(sample.t_s)

    def update_velocity_values(
        self,
        t_s: float,
        v_mps: list[float],
        interval_mean_mps: list[float] | None = None,
    ) -> None:
        """:meth:`update_velocity` for a caller that already checked the sample (finite
        floats, the observer's dimension): no sample object is built.

        ``interval_mean_mps``: the mean of ``v`` (m/s, the paper's sign) over the interval
        from the previous velocity sample to this one, when it is known better than the
        average of the two samples (for a vehicle, from the change of its position: see
        ``docs/frames.md``, "Velocity from the positions"). The velocity on that interval is
        then the linear interpolation of the two samples shifted by a constant so that its
        mean is that (the samples' shape, the positions' displacement: on a smooth turn the shape
        is far closer than a straight line, and the displacement is exact)."""
        self._accept("velocity", t_s, v_mps)
        if interval_mean_mps is not None:
            self._streams.set_interval_mean(t_s, interval_mean_mps)

    def update_bearing_values(self, t_s: float, y: list[float]) -> Estimate:
        """:meth:`update_bearing` for a caller that already checked the sample (finite
        floats, unit length, the observer's dimension)."""
        self._accept("bearing", t_s, y)
        return self._estimate_at(t_s)

    def add_bearing_values(self, t_s: float, y: list[float]) -> None:
        """Accept a checked bearing (as :meth:`update_bearing_values`) without a live
        estimate at its time: with ``committed=True`` its estimate comes, with those of the
        other bearings, from :meth:`take_committed` once the velocity around it is known."""
        self._accept("bearing", t_s, y)

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
        streams = self._streams
        if self._t_c is not None and streams.bearings:
            t_end = streams.bearings[-1][0]
            if t_end > self._t_c:
                self._commit_to(t_end)
                streams.trim(t_end)
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
        if self._t_c is not None and t < self._t_c:
            raise InvalidSampleError(
                f"predict t_s={t} is before the observer's committed time t_s={self._t_c}"
            )
        self._advance()
        if self._t_c is not None and t < self._t_c:  # the data already reaches past t
            raise InvalidSampleError(
                f"predict t_s={t} is before the observer's committed time t_s={self._t_c}"
            )
        return self._estimate_at(t)

    # -- integration ----------------------------------------------------------------
    def _start_if_ready(self) -> None:
        if self._t_c is not None:
            return
        streams = self._streams
        streams.keep_latest()
        if not streams.ready:
            return
        t_b, y = streams.bearings[-1]
        self._est.start(t_b, y, streams)
        self._t_c = streams.start_time()
        if self._keep_committed and self._t_c == t_b:  # started at this bearing: its estimate
            self._committed.append(self._estimate_at(t_b, committed=True))
        streams.trim(self._t_c)

    def _advance(self, *, lazy: bool = False) -> None:
        """Integrate the committed state up to the data horizon. Computes first, then
        commits: if the maths raised, nothing would have changed. ``lazy`` (a velocity
        sample): leave it to the next bearing unless the bearing is stale or a buffer full."""
        self._start_if_ready()
        if self._t_c is None:
            return
        streams = self._streams
        if lazy and streams.can_wait():
            return
        horizon = streams.horizon()
        if horizon > self._t_c:
            self._commit_to(horizon)
            streams.trim(horizon)

    def _commit_to(self, horizon: float) -> None:
        """Step the committed state to ``horizon`` and commit it (with ``committed=True``,
        bearing by bearing, keeping the estimate at each). Computes every piece before
        committing any: if the maths raised, nothing would have changed."""
        t0: float = self._t_c  # type: ignore[assignment]
        stops = [horizon]
        bearing_times: set[float] = set()
        if self._keep_committed:
            bearing_times = {t for t, _ in self._streams.bearings if t0 < t <= horizon}
            stops = sorted(bearing_times | {horizon})
        pieces = []
        est = self._est
        for t1 in stops:
            est, intervals, corrections = self._step(est, t0, t1)
            pieces.append((t1, est, intervals, corrections))
            t0 = t1
        for t1, est, intervals, corrections in pieces:
            self._est = est
            self._t_c = t1
            self._window.add_interval(*intervals)
            if corrections is not None:
                self._window.add_correction(*corrections)
            if t1 in bearing_times:
                self._committed.append(self._estimate_at(t1, committed=True))

    def _step(
        self, start: Estimator, t0: float, t1: float
    ) -> tuple[Estimator, tuple[Any, ...], tuple[Any, ...] | None]:
        """Step a copy of the estimator ``start`` from ``t0`` to ``t1``: sub-steps of
        prediction with the inputs at their midpoints between the breakpoints, an update at
        each bearing sample in ``(t0, t1]``. Returns it with what the monitor's window must
        account over ``[t0, t1]``: the integral of ``y y^T`` over the time with a usable
        bearing and that time, and the correction applied (``None`` if none)."""
        n = self.config.n
        streams = self._streams
        before = start.output(streams)
        est = start.copy()
        bearings = streams.bearings_between(t0, t1)
        openloop = [0.0] * n
        yy = [0.0] * (n * n)
        valid = 0.0
        corrected = False
        continuous = est.continuous
        for a, b in itertools.pairwise(streams.breakpoints(t0, t1, est.min_interval_s)):
            span = b - a
            if span <= 0.0:
                continue
            y_mid = streams.bearing_at(0.5 * (a + b))
            n_sub = est.substeps(span, y_mid is not None)
            hs = span / n_sub
            for i in range(n_sub):
                tm = a + (i + 0.5) * hs
                v = streams.velocity_at(tm)
                if y_mid is None:
                    y = None
                elif n_sub == 1:
                    y = y_mid
                else:
                    y = streams.bearing_at(tm)
                moved = est.predict(tm, hs, v, y, streams)
                for j in range(n):
                    openloop[j] += moved[j]
                if y is not None:
                    valid += hs
                    _add_outer(yy, y, hs)
                    corrected = corrected or continuous
            y = bearings.get(b)
            if y is not None:
                est.update(b, y, streams)
                corrected = True
        after = est.output(streams)
        intervals = (t0, t1, yy if valid > 0.0 else None, valid)
        corrections = None
        if corrected:
            x0, x1 = before.x_m, after.x_m
            dx = [x1[j] - x0[j] - openloop[j] for j in range(n)]
            da = [after.a_mps[j] - before.a_mps[j] for j in range(n)]
            corrections = (t1, dx, da)
        return est, intervals, corrections

    # -- output ---------------------------------------------------------------------
    def _estimate_at(self, t: float, *, committed: bool = False) -> Estimate:
        """The estimate at ``t`` (at or after the committed time); ``committed``: at the
        committed time, the bearing there just applied (its age 0, the velocity's the time
        since the latest velocity sample at or before it)."""
        cfg = self.config
        n = cfg.n
        streams = self._streams
        started = self._t_c is not None
        est = self._est
        out = est.output(streams)
        xhat = out.x_m
        a_now = out.a_mps
        dt = 0.0
        pxx_pred = None
        if started and t > self._t_c:  # type: ignore[operator]
            # beyond the committed state: a prediction, xhat' = v + ahat (exact for the
            # linear velocity, never committed). The bearings since are applied when the
            # velocity around them is known, at the next commit.
            dt = t - self._t_c  # type: ignore[operator]
            d = streams.predicted_displacement(self._t_c, t)  # type: ignore[arg-type]
            xhat = [xhat[j] + d[j] + dt * a_now[j] for j in range(n)]
            ev = streams.extrapolation_var_m2(t)
            if ev > 0.0 and out.p is not None:
                # a sparse stream's trend continued: its uncertainty, and the bearing at
                # this time (if it is one's) corrects the position published
                pred = np.array(est.position_cov(dt, streams)).reshape(n, n) + ev * np.eye(n)
                tb, yb = streams.bearings[-1]
                noise = est.noise(streams) if tb == t else None
                if noise is not None:
                    x_new, pred = riccati.position_update(
                        np.array(xhat),
                        pred,
                        np.array(yb),
                        math.radians(noise.bearing_noise_deg) ** 2,
                        outlier_nis(n - 1) if cfg.robust else math.inf,
                    )
                    xhat = x_new.tolist()
                pxx_pred = pred.ravel().tolist()
        rng = math.sqrt(discrete.dot(xhat, xhat))
        b_age: float | None
        if committed:
            b_age = 0.0
            tv = max((tv for tv, _ in streams.velocities if tv <= t), default=None)
            v_age = None if tv is None else t - tv
        else:
            b_age = t - streams.bearings[-1][0] if streams.bearings else None
            v_age = t - streams.velocities[-1][0] if streams.velocities else None
        if self._diag is None or not 0.0 <= t - self._diag[0] < DIAGNOSTICS_PERIOD_S:
            self._diag = (t, self._window.excitation())
        excitation = self._diag[1]
        if self._cond is None or self._cond[0] != self._t_c:  # of the committed state
            self._cond = (self._t_c, est.cond())
        cond = self._cond[1]
        covered = self._window.covered_s()
        corr = self._window.correction_rel(rng)
        self._memory = next_status(
            self._memory,
            t_s=t,
            started=started,
            bearing_age_s=b_age,
            velocity_age_s=v_age,
            excitation=excitation,
            covered_s=covered,
            correction_rel=corr,
            th=self._thresholds,
            settled=est.settled,
        )
        corrected = started and b_age is not None and b_age <= cfg.max_bearing_age_s
        x_out = np.array(xhat)
        a_out = np.array(a_now)
        x_out.setflags(write=False)
        a_out.setflags(write=False)
        x_std = a_std = range_std = None
        nis = est.nis() if started else None
        p = out.p
        if p is not None and started:
            # on lists: numpy's per-call cost is most of what small arrays cost
            pl = pxx_pred if pxx_pred is not None else est.position_cov(dt, streams)
            x_std, a_std, var_r = _stds(pl, p, xhat, rng, n)  # type: ignore[arg-type]
            range_std = math.sqrt(max(var_r, 0.0))
        estimate = Estimate(
            t_s=t,
            x_m=x_out,
            a_mps=a_out,
            range_m=rng,
            excitation=excitation,
            cond_m=cond,
            status=self._memory.status,
            corrected=bool(corrected),
            bearing_age_s=b_age,
            velocity_age_s=v_age,
            correction_rel=corr,
            x_std_m=x_std,
            a_std_mps=a_std,
            range_std_m=range_std,
            nis=nis,
        )
        self._estimate = estimate
        return estimate

    def resume(self, t_s: float, dx_m: Sequence[float], v_mps: Sequence[float]) -> None:
        """Carry the observer across a gap in its data (a service restart) to ``t_s``.

        The estimate moves by ``dx_m`` (m), the change of ``x`` over the gap known from
        elsewhere: for a vehicle and a target that stays put in the autopilot's local frame,
        minus the vehicle's displacement in that frame (``ahat`` is not integrated over the
        gap: where the local position is GPS-true, ``a`` is the velocity's error, which
        does not move the target in that frame). The
        velocity ``v_mps`` (the paper's ``v``) holds from ``t_s``. The gains' matrix, the
        excitation window and the status carry over unchanged (shifted in time by the gap):
        what the observer had learnt stays learnt. Raises :class:`StateError` if the observer
        never started or ``t_s`` is before its committed time, :class:`InvalidSampleError` for
        a non-finite or wrong-sized argument.
        """
        if self._t_c is None:
            raise StateError("resume: the observer has not started, there is nothing to carry")
        t = _check_time(t_s)
        if t < self._t_c:
            raise StateError(f"resume t_s={t} is before the committed time t_s={self._t_c}")
        n = self.config.n
        dx = _frozen_vector("dx_m", dx_m, t).tolist()
        v = _frozen_vector("v_mps", v_mps, t).tolist()
        if len(dx) != n or len(v) != n:
            raise InvalidSampleError(f"resume: dx_m and v_mps must have dimension n={n}")
        gap = t - self._t_c
        self._est.shift(dx)
        self._t_c = t
        # the last bearing, now too old to be used, keeps the horizon
        self._streams.restart_velocity(t, v)
        self._window.shift(gap)
        since = self._memory.observable_since_s
        self._memory = StatusMemory(self._memory.status, None if since is None else since + gap)
        self._diag = None
        self._cond = None
        self._estimate = None

    # -- persistence ----------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The whole observer as a JSON-serialisable dictionary; :meth:`from_dict` restores
        it exactly (floats round-trip through JSON bit for bit). The estimator's own state
        sits beside the observer's (the paper's ``xh1``, ``m``, ``ahat``; the riccati
        estimator's ``kalman`` and ``velocity_noise``)."""
        streams = self._streams
        return {
            "schema": STATE_SCHEMA,
            "config": self.config.to_dict(),
            "t_c": self._t_c,
            "bearings": [[t, list(y)] for t, y in streams.bearings],
            "velocities": [[t, list(v)] for t, v in streams.velocities],
            "velocity_dt_s": streams.velocity_dt_s,
            "extrapolation": list(streams.extrap),
            "window": self._window.to_dict(),
            "memory": {
                "status": str(self._memory.status),
                "observable_since_s": self._memory.observable_since_s,
            },
            "counts": dict(self._counts),
            "estimate": None if self._estimate is None else self._estimate.to_dict(),
            "excitation_cache": None if self._diag is None else list(self._diag),
            **self._est.to_dict(),
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
        n = config.n
        t_c = d.get("t_c")
        if t_c is not None:
            t_c = _field_float(d, "t_c")
        obs._t_c = t_c
        streams = obs._streams
        streams.bearings = _field_samples(d, "bearings", n, unit=True)
        streams.velocities = _field_samples(d, "velocities", n, unit=False)
        streams.velocity_dt_s = _velocity_dt(d, streams.velocity_dt_s)
        if d.get("extrapolation") is not None:  # (absent from states saved before it)
            streams.extrap = _extrapolation(d["extrapolation"])
        obs._window = ExcitationWindow.from_dict(n, _field(d, "window", dict))
        mem = _field(d, "memory", dict)
        try:
            status = Status(mem["status"])
            since = mem["observable_since_s"]
            since = None if since is None else float(since)
        except (KeyError, ValueError, TypeError) as exc:
            raise StateError(f"memory: {exc!r}") from exc
        obs._memory = StatusMemory(status, since)
        counts = _field(d, "counts", dict)
        obs._counts = {
            "velocity": int(counts.get("velocity", 0)),
            "bearing": int(counts.get("bearing", 0)),
        }
        est = d.get("estimate")
        if est is not None:
            obs._estimate = _estimate_from_dict(est)
        diag = d.get("excitation_cache")
        if diag is not None:
            try:
                t_d, e_d = (float(v) for v in diag)
            except (TypeError, ValueError) as exc:
                raise StateError(
                    f"observer state 'excitation_cache' is malformed: {diag!r}"
                ) from exc
            obs._diag = (t_d, e_d)
        obs._est.restore(d, started=t_c is not None)
        return obs


def _extrapolation(raw: Any) -> list[float]:
    """A saved sparse stream's extrapolation sums: four finite numbers >= 0."""
    try:
        vals = [float(v) for v in raw]
    except (TypeError, ValueError) as exc:
        raise StateError(f"observer state 'extrapolation' is malformed: {raw!r}") from exc
    if len(vals) != 4 or not all(math.isfinite(v) and v >= 0.0 for v in vals):
        raise StateError(
            f"observer state 'extrapolation' must be four finite numbers >= 0, got {raw!r}"
        )
    return vals


def _velocity_dt(d: dict[str, Any], default: float) -> float:
    """The velocity's sample interval of a saved state: its own field, or where states
    saved before the estimators were split kept it (``kalman.velocity_dt``)."""
    raw = d.get("velocity_dt_s")
    if raw is None and isinstance(d.get("kalman"), dict):
        raw = d["kalman"].get("velocity_dt")
    if raw is None:
        return default
    if isinstance(raw, bool) or not isinstance(raw, (int, float)) or not 0.0 < raw <= 1.0:
        raise StateError(f"observer state 'velocity_dt_s' must be in (0, 1] s, got {raw!r}")
    return float(raw)


def _field(d: dict[str, Any], key: str, typ: type) -> Any:
    if key not in d:
        raise StateError(f"observer state has no {key!r}")
    if not isinstance(d[key], typ):
        raise StateError(f"observer state {key!r} must be a {typ.__name__}, got {d[key]!r}")
    return d[key]


def _field_float(d: dict[str, Any], key: str) -> float:
    val = d.get(key)
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
        raise StateError(f"observer state {key!r} must be a finite number, got {val!r}")
    return float(val)


def _field_samples(d: dict[str, Any], key: str, n: int, *, unit: bool) -> list[Sample]:
    raw = _field(d, key, list)
    out: list[Sample] = []
    for item in raw:
        if not isinstance(item, Sequence) or len(item) != 2:
            raise StateError(f"observer state {key!r} holds a malformed sample {item!r}")
        try:
            s = BearingSample(item[0], item[1]) if unit else VelocitySample(item[0], item[1])
        except InvalidSampleError as exc:
            raise StateError(f"observer state {key!r}: {exc}") from exc
        vec = s.y if unit else s.v_mps  # type: ignore[union-attr]
        if vec.shape != (n,):
            raise StateError(f"observer state {key!r} holds a sample of dimension {vec.shape[0]}")
        # keep the stored bits exactly (a BearingSample could re-normalise)
        out.append((float(item[0]), [float(c) for c in item[1]]))
    return out


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
            x_m=np.array(e["x_m"], dtype=float),
            a_mps=np.array(e["a_mps"], dtype=float),
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
