"""The two sample streams of one observer and the inputs they give its estimator.

:class:`SampleStreams` buffers the velocity and bearing samples (times in s, vectors as lists
of floats) and turns them into the inputs of the continuous equations: interpolated between
samples, held after the latest one, the integration's breakpoints, the data horizon. It is
the sample handling written once for every estimator (:mod:`mav_observer.estimators`); the
rules are in :mod:`mav_observer.observer`'s docstring. Pure: no I/O, no clock.
"""

from __future__ import annotations

import math

from mav_observer import discrete
from mav_observer.errors import InvalidSampleError

#: Sample times closer than this to an interval end are not made breakpoints (s), for an
#: estimator that merges them (the paper's, with linear interpolation). The inputs are
#: evaluated at each sub-step's midpoint from the samples around it, so a breakpoint only
#: matters for a kink of the interpolant: merging a sliver of a few ms costs far less than the
#: sub-step it would take (two streams a few ms apart is the usual MAVLink case).
MIN_INTERVAL_S = 0.01
#: The velocity's sample interval (s) assumed before two samples have arrived.
DEFAULT_VELOCITY_DT_S = 0.05

#: The prior of a sparse stream's extrapolation error (m/s^2 per axis: the velocity's drift
#: from its latest trend per second), and how many intervals it weighs.
EXTRAPOLATION_PRIOR_MPS2 = 1.0
EXTRAPOLATION_PRIOR_WEIGHT = 3.0
#: The forgetting time constant (s) of the extrapolation error learnt.
EXTRAPOLATION_MEMORY_S = 60.0

#: ``(t_s, vector)``
Sample = tuple[float, list[float]]


def lerp(p: Sample, q: Sample, t: float) -> list[float]:
    """The linear interpolation of two samples at ``t``."""
    f = (t - p[0]) / (q[0] - p[0])
    a, b = p[1], q[1]
    if len(a) == 3:
        return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])]
    return [x + f * (y - x) for x, y in zip(a, b, strict=True)]


#: A velocity interval at least this long (s) whose mean is known from the positions is a
#: sparse stream's: a prediction past its latest sample continues its trend, with the
#: variance that trend's misses have shown (:meth:`SampleStreams.extrapolation_var_m2`).
#: Below it (10 Hz and more) a prediction holds the latest sample, as short as it is (the
#: trend's extrapolation and the bearing's update of the position it brings cost about
#: 0.4 ms a bearing in the service, for nothing measurable over 0.1 s).
SPARSE_INTERVAL_S = 0.2


def _bracket(buf: list[Sample], t: float) -> tuple[Sample | None, Sample | None]:
    """The latest sample at or before ``t`` and the first one after it."""
    p = None
    for sample in buf:
        if sample[0] <= t:
            p = sample
        else:
            return p, sample
    return p, None


class SampleStreams:
    """The velocity (the paper's ``v``, m/s) and bearing (unit vectors) samples of one
    observer, in time order, and the inputs interpolated from them.

    * ``max_bearing_age_s``, ``max_velocity_age_s``: how long a sample is held, and the
      longest gap interpolated across;
    * ``linear``: interpolate between samples (else hold each one to the next);
    * ``max_buffer``: most samples of one stream kept waiting for the other.
    """

    def __init__(
        self,
        *,
        max_bearing_age_s: float,
        max_velocity_age_s: float,
        linear: bool,
        max_buffer: int,
    ) -> None:
        self.max_bearing_age_s = max_bearing_age_s
        self.max_velocity_age_s = max_velocity_age_s
        self.linear = linear
        self.max_buffer = max_buffer
        self.bearings: list[Sample] = []
        self.velocities: list[Sample] = []
        #: velocity sample time -> the mean velocity (m/s) over the interval that ends at it
        #: (``BiasObserver.update_velocity_values``'s ``interval_mean_mps``)
        self.vel_mean: dict[float, list[float]] = {}
        #: the velocity's latest sample interval (s, at most 1)
        self.velocity_dt_s = DEFAULT_VELOCITY_DT_S
        #: a sparse stream's extrapolation error learnt (:meth:`extrapolation_var_m2`): the
        #: forgetting sums of the weights and of the squared drift rates ((m/s^2)^2), of
        #: the samples and of the prior (which fades ten times faster)
        w0 = EXTRAPOLATION_PRIOR_WEIGHT
        self.extrap = [0.0, 0.0, w0, w0 * EXTRAPOLATION_PRIOR_MPS2**2]

    # -- input ----------------------------------------------------------------------
    def append(self, kind: str, t_s: float, vec: list[float], committed_t_s: float | None) -> None:
        """Append a sample of stream ``kind`` (``"velocity"`` or ``"bearing"``) after checking
        its time: not before the stream's previous sample, and for a bearing not before the
        committed time ``committed_t_s`` (it could no longer be applied). Undo with
        :meth:`pop`."""
        buf = self.velocities if kind == "velocity" else self.bearings
        if buf and t_s < buf[-1][0]:
            raise InvalidSampleError(
                f"{kind} t_s={t_s} is before the previous {kind} sample t_s={buf[-1][0]}: "
                "time went backwards"
            )
        if kind == "bearing" and committed_t_s is not None and t_s < committed_t_s:
            raise InvalidSampleError(
                f"{kind} t_s={t_s} is older than the observer's committed time "
                f"t_s={committed_t_s} (it arrived more than max_{kind}_age_s late)"
            )
        if kind == "velocity" and buf and t_s > buf[-1][0]:
            self.velocity_dt_s = min(1.0, t_s - buf[-1][0])
        buf.append((t_s, vec))

    def pop(self, kind: str) -> None:
        """Remove the latest sample of stream ``kind`` (a rejected one)."""
        (self.velocities if kind == "velocity" else self.bearings).pop()

    def set_interval_mean(self, t_s: float, mean_mps: list[float]) -> None:
        """The mean velocity (m/s) over the interval ending at the velocity sample ``t_s``."""
        buf = self.velocities
        if len(buf) >= 2 and buf[-2][0] < t_s:
            if (  # the prediction before this sample continued the previous one's trend
                len(buf) >= 3
                and buf[-1][0] == t_s
                and buf[-2][0] in self.vel_mean
                and buf[-2][0] - buf[-3][0] >= SPARSE_INTERVAL_S
            ):
                self._learn_extrapolation(t_s, mean_mps)
            self.vel_mean[t_s] = list(mean_mps)

    def _learn_extrapolation(self, t_s: float, mean_mps: list[float]) -> None:
        """Score the prediction the stream gave before the sample at ``t_s`` arrived (its
        latest trend continued, :meth:`predicted_displacement`) against the interval's mean
        ``mean_mps`` (m/s) now known, as a drift rate ``alpha`` of the velocity from its
        trend (the displacement off by ``alpha s^2 / 2`` after ``s``)."""
        (tp, vp), (tv, vl) = self.velocities[-3], self.velocities[-2]
        s = t_s - tv
        v_end, slope, iv = _trend(tp, vp, tv, vl, self.vel_mean[tv])
        pred = _trend_integral(v_end, slope, iv, s)
        n = len(vl)
        err2 = 0.0
        for j in range(n):
            e = pred[j] - s * mean_mps[j]
            err2 += e * e
        sample = 4.0 * err2 / (n * s**4)
        rho = math.exp(-s / EXTRAPOLATION_MEMORY_S)
        w, ss, wp, sp = self.extrap
        rho_p = rho**10
        self.extrap = [rho * w + 1.0, rho * ss + sample, rho_p * wp, rho_p * sp]

    @property
    def extrapolation_mps2(self) -> float:
        """A sparse stream's drift rate from its latest trend learnt (m/s^2 per axis)."""
        w, s, wp, sp = self.extrap
        return math.sqrt((s + sp) / (w + wp))

    def extrapolation_var_m2(self, t: float) -> float:
        """The variance (m^2 per axis) of the displacement predicted to ``t`` beyond the
        latest velocity sample of a sparse stream (its latest interval's mean known from the
        positions, :meth:`predicted_displacement`): ``(alpha s^2 / 2)^2`` after ``s``, with
        ``alpha`` learnt from how far each interval's mean was from the prediction before
        it. 0 for a dense stream or at or before the latest sample (there the velocity
        noise's share is the estimator's).

        A 1 Hz stream braking from 9 m/s to 4.6 m/s put the prediction 0.9 s past its
        latest sample 1.9 m off (the shared log ``bad_zeroholes``): the uncertainty says so,
        and the bearing at that time corrects it (``BiasObserver``)."""
        if not self.vel_mean or not self.velocities:
            return 0.0
        tv = self.velocities[-1][0]
        if t <= tv or not self._trend_known():
            return 0.0
        s = t - tv
        return 0.25 * self.extrapolation_mps2**2 * s**4

    def keep_latest(self) -> None:
        """Before the start only the latest sample of each stream matters."""
        del self.bearings[:-1]
        del self.velocities[:-1]

    @property
    def ready(self) -> bool:
        """True when both streams have a sample."""
        return bool(self.bearings) and bool(self.velocities)

    def start_time(self) -> float:
        """The time from which both streams have data (s)."""
        return max(self.bearings[0][0], self.velocities[0][0])

    def trim(self, t_c: float) -> None:
        """Drop samples no longer needed at committed time ``t_c``: keep the latest one at or
        before it (the interpolation anchor) and everything after it; of the velocities, the
        one before the anchor too (a prediction continues the latest interval's trend)."""
        for buf, extra in ((self.bearings, 0), (self.velocities, 1)):
            keep_from = 0
            for i, (t, _) in enumerate(buf):
                if t <= t_c:
                    keep_from = i
                else:
                    break
            keep_from = max(0, keep_from - extra)
            if keep_from:
                del buf[:keep_from]
        if self.vel_mean and self.velocities:
            first = self.velocities[0][0]
            for t in [t for t in self.vel_mean if t <= first]:
                del self.vel_mean[t]

    def restart_velocity(self, t_s: float, v_mps: list[float]) -> None:
        """After a gap in the data: the velocity ``v_mps`` from ``t_s``, the latest bearing
        kept only to hold the horizon."""
        self.velocities = [(t_s, v_mps)]
        self.vel_mean = {}
        del self.bearings[:-1]

    # -- horizon --------------------------------------------------------------------
    def horizon(self) -> float:
        """The latest time both streams determine (s): the earlier stream's latest sample,
        unless the other has gone stale or a buffer is full."""
        tb = self.bearings[-1][0]
        tv = self.velocities[-1][0]
        if tv > tb + self.max_bearing_age_s:
            horizon = tv  # bearing stale: no future bearing can correct this stretch
        elif tb > tv + self.max_velocity_age_s:
            horizon = tb  # velocity stale: hold it
        else:
            horizon = min(tb, tv)
        if len(self.bearings) > self.max_buffer or len(self.velocities) > self.max_buffer:
            horizon = max(tb, tv)
        return horizon

    def can_wait(self) -> bool:
        """True when a new velocity sample may leave the integration to the next bearing:
        the bearing is not stale and the velocity buffer not full."""
        stale = self.velocities[-1][0] > self.bearings[-1][0] + self.max_bearing_age_s
        return not stale and len(self.velocities) <= self.max_buffer

    def breakpoints(self, t0: float, t1: float, min_interval_s: float) -> list[float]:
        """``t0``, the sample times and bearing expiries between, ``t1``, each once, in order;
        points closer than ``min_interval_s`` to the previous one or to ``t1`` merge."""
        age = self.max_bearing_age_s
        inner = {t for t, _ in self.velocities if t0 < t < t1}
        for t, _ in self.bearings:
            if t0 < t < t1:
                inner.add(t)
            if t0 < t + age < t1:
                inner.add(t + age)
        if not inner:
            return [t0, t1]
        if min_interval_s <= 0.0:
            return [t0, *sorted(inner), t1]
        pts = [t0]
        for t in sorted(inner):
            if t - pts[-1] >= min_interval_s and t1 - t >= min_interval_s:
                pts.append(t)
        pts.append(t1)
        return pts

    def bearings_between(self, t0: float, t1: float) -> dict[float, list[float]]:
        """The bearing samples in ``(t0, t1]`` by time."""
        return {t: y for t, y in self.bearings if t0 < t <= t1}

    # -- inputs ---------------------------------------------------------------------
    def bearing_at(self, t: float) -> list[float] | None:
        """The bearing in force at ``t`` (unit vector), or ``None`` when there is no usable
        one: interpolated between the samples around ``t`` when at most
        ``max_bearing_age_s`` apart, else the earlier one held for at most
        ``max_bearing_age_s``."""
        p, q = _bracket(self.bearings, t)
        if p is None:
            return None
        if q is not None and self.linear and q[0] - p[0] <= self.max_bearing_age_s:
            y = lerp(p, q, t)
            if len(y) == 3:
                inv = 1.0 / math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
                return [y[0] * inv, y[1] * inv, y[2] * inv]
            inv = 1.0 / math.sqrt(discrete.dot(y, y))
            return [c * inv for c in y]
        if t <= p[0] + self.max_bearing_age_s:
            return p[1]
        return None

    def velocity_at(self, t: float) -> list[float]:
        """The velocity at ``t``: interpolated as bearings are, else the latest one held (the
        first one held backwards before it)."""
        p, q = _bracket(self.velocities, t)
        if p is None:
            return (q if q is not None else self.velocities[0])[1]
        if q is not None:
            mean = self.vel_mean.get(q[0]) if self.vel_mean else None
            if mean is not None:  # the interval's mean is known (from the positions): the
                # samples' shape, shifted so that its integral is the positions' change
                v = lerp(p, q, t)
                a, b = p[1], q[1]
                return [v[j] + mean[j] - 0.5 * (a[j] + b[j]) for j in range(len(v))]
            if self.linear and q[0] - p[0] <= self.max_velocity_age_s:
                return lerp(p, q, t)
        return p[1]

    @property
    def sparse(self) -> bool:
        """True when the latest velocity interval's mean came from the positions and it is
        :data:`SPARSE_INTERVAL_S` or longer (a sparse stream: a prediction past it continues
        its trend, :meth:`extrapolation_var_m2`)."""
        return self._trend_known()

    def _trend_known(self) -> bool:
        """See :attr:`sparse`."""
        v = self.velocities
        return (
            len(v) >= 2 and v[-1][0] in self.vel_mean and v[-1][0] - v[-2][0] >= SPARSE_INTERVAL_S
        )

    def chord_at(self, t: float) -> bool:
        """True if the velocity at ``t`` is an interval's mean from the positions."""
        if not self.vel_mean:
            return False
        _, q = _bracket(self.velocities, t)
        return q is not None and q[0] in self.vel_mean

    def predicted_displacement(self, t0: float, t1: float) -> list[float]:
        """The integral of ``v`` from ``t0`` to ``t1`` for a prediction (m): the known
        velocity (linear between samples: its midpoint) up to the latest sample; past it,
        held (where the latest interval's mean is known from the positions, the model's
        velocity at that sample, the samples' shape shifted to the mean), or for a sparse
        stream (such an interval of :data:`SPARSE_INTERVAL_S` or more: velocity samples up
        to seconds apart while the vehicle turns) its latest trend continued for at most one
        interval. Holding a 1 Hz velocity on a figure-8 put the
        estimates published just before the next sample 12 cm off, 8 times the bound
        (``velocity_1hz``)."""
        n = len(self.velocities[-1][1])
        tv = self.velocities[-1][0]
        if t1 <= tv or len(self.velocities) < 2 or tv not in self.vel_mean:
            h = t1 - t0
            v = self.velocity_at(t0 + 0.5 * h)
            return [h * v[j] for j in range(n)]
        out = [0.0] * n
        if t0 < tv:  # the known stretch
            h = tv - t0
            v = self.velocity_at(t0 + 0.5 * h)
            out = [h * v[j] for j in range(n)]
        tp, vp = self.velocities[-2]
        v_end, slope, iv = _trend(tp, vp, tv, self.velocities[-1][1], self.vel_mean[tv])
        if not self._trend_known():  # a dense stream: its model's latest velocity held
            slope = [0.0] * n

        a = _trend_integral(v_end, slope, iv, max(t0 - tv, 0.0))
        b = _trend_integral(v_end, slope, iv, t1 - tv)
        return [out[j] + b[j] - a[j] for j in range(n)]


def _trend(
    tp: float, vp: list[float], tv: float, vl: list[float], mean: list[float]
) -> tuple[list[float], list[float], float]:
    """A sparse stream's trend at its latest sample ``(tv, vl)`` after ``(tp, vp)`` with the
    interval's mean ``mean`` from the positions: the model's velocity at ``tv`` (the samples'
    shape shifted to the mean), its slope (m/s^2) and the interval (s)."""
    iv = tv - tp
    n = len(vl)
    v_end = [vl[j] + mean[j] - 0.5 * (vp[j] + vl[j]) for j in range(n)]
    slope = [(vl[j] - vp[j]) / iv for j in range(n)]
    return v_end, slope, iv


def _trend_integral(v_end: list[float], slope: list[float], iv: float, s: float) -> list[float]:
    """The displacement (m) over ``[0, s]`` past the latest sample of a trend continued for
    at most one interval ``iv`` (s), then held: the integral of ``v_end + slope min(s', iv)``."""
    ramp = 0.5 * s * s if s <= iv else 0.5 * iv * iv + iv * (s - iv)
    return [s * v_end[j] + ramp * slope[j] for j in range(len(v_end))]
