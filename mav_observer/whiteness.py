"""Are the bearings' errors white? The correlation of successive innovations (pure).

The estimator's covariance, and so ``target_h_std_m``, is honest only while the bearing
errors are what its model says: independent from one bearing to the next. A filter that is
right has white innovations (the bearing minus the direction it predicted). A systematic
error that wanders over seconds (a servo mount's lag behind the vehicle's tilt, a gimbal
misaligned with the autopilot, a tracker that slides along its target) makes successive
innovations alike, and the filter, taking each bearing as new information, becomes
over-confident: on the shared SITL log (``ardupilot_sitl_servo_mount_roi.tlog``) the
innovations' lag-1 correlation ends at 0.99 (correlated over 16 s), and only
74 % of the errors over its last third lie within twice ``target_h_std_m``; on every emitter
stream it is below 0.1 (``docs/geolocation.md``, "When the sigma is not to be trusted").

:class:`InnovationCorrelation` measures it: the lag-1 correlation of the innovation vectors
(tangent to the predicted direction, in units of the bearing noise in use), summed with
exponential forgetting over ``memory_s`` of bearing time, the correlation time it implies
for an AR(1) error, and the innovations' size against the noise in use (correlated
innovations far below it, as noise-free bearings leave under the learnt noise's floor, are
covered by it: :attr:`Correlation.systematic` needs both). A diagnostic only: the estimate
does not use it (inflating the bearing noise by the AR(1) factor it implies was tried on the
SITL log and made the estimate worse: its median error over the last third went from 0.96 m
to 1.8 m with the variance's factor capped at 2, to 6.9 m capped at 4). No I/O, no clock:
times are the bearings' own.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from mav_observer.errors import ConfigError

#: Successive bearings further apart than this (s) are not compared (a dropout).
MAX_GAP_S = 2.0
#: No correlation is reported from fewer (forgotten) pairs than this.
MIN_PAIRS = 30.0
#: An innovation larger than this many times the running RMS is left out (a gross error
#: would otherwise dominate the sums), once :data:`MIN_PAIRS` pairs are in.
CLIP_RMS = 5.0
#: A lag-1 correlation at or above this is reported as a warning (replay's summary) ...
WARN_LAG1 = 0.5
#: ... when the innovations are not much smaller than the noise in use: their mean square
#: per tangent direction at least this fraction of its variance (noise-free emitter bearings
#: leave innovations correlated but at 0.02 of the learnt noise's floor, which then covers
#: them: no warning).
WARN_VAR_RATIO = 0.25


@dataclass(frozen=True, slots=True)
class Correlation:
    """``lag1``: the correlation of successive innovations, -1 to 1 (0: white);
    ``corr_time_s``: the correlation time of an AR(1) error with that lag-1 correlation at
    the mean interval between the bearings compared (s; ``None`` at or below 0, ``inf`` at
    1); ``var_ratio``: the innovations' mean square per tangent direction over the bearing
    noise variance in use (about 1 when the noise in use is the bearings'); ``pairs``: the
    (forgotten) number of pairs it comes from."""

    lag1: float
    corr_time_s: float | None
    var_ratio: float
    pairs: float

    @property
    def systematic(self) -> bool:
        """The bearing errors are systematic, and not small against the noise in use:
        ``lag1 >= WARN_LAG1`` and ``var_ratio >= WARN_VAR_RATIO``."""
        return self.lag1 >= WARN_LAG1 and self.var_ratio >= WARN_VAR_RATIO

    def describe(self) -> str:
        """One line for people (replay's summary, the service's log): the figures and
        the verdict, ``WARNING: ...`` when :attr:`systematic`."""
        over = (
            ""
            if self.corr_time_s is None
            else " (correlated over ever longer)"
            if math.isinf(self.corr_time_s)
            else f" (correlated over {self.corr_time_s:.2g} s)"
        )
        head = (
            f"innovations from one bearing to the next: correlation {self.lag1:.2f}{over}, "
            f"{math.sqrt(self.var_ratio):.2g} times the noise in use"
        )
        if not self.systematic:
            return f"{head}: " + (
                "white, as the covariance assumes"
                if self.lag1 < WARN_LAG1
                else "correlated but small against the noise in use, which covers them"
            )
        return (
            f"WARNING: {head}: the bearing errors are systematic (a servo mount's lag, "
            "a misaligned gimbal, a tracker sliding on its target), not noise; "
            "target_h_std_m is likely too small "
            "(docs/geolocation.md, 'When the sigma is not to be trusted')"
        )


class InnovationCorrelation:
    """The lag-1 correlation of a stream of innovation vectors, with forgetting.

    ``memory_s``: the time constant of the forgetting (s of bearing time, > 0)."""

    def __init__(self, memory_s: float = 60.0) -> None:
        if not memory_s > 0.0 or not math.isfinite(memory_s):
            raise ConfigError(f"memory_s must be finite and > 0, got {memory_s!r}")
        self.memory_s = float(memory_s)
        self._prev: tuple[float, float, float, float] | None = None  # z and its square
        self._t_prev_s = 0.0
        self._c0 = 0.0  # sum of (|e_k|^2 + |e_k-1|^2) / 2
        self._c1 = 0.0  # sum of e_k . e_k-1
        self._n = 0.0  # pairs
        self._dt = 0.0  # sum of the intervals
        self._sq = 0.0  # sum of |e_k|^2 over the bearings kept
        self._m = 0.0  # bearings kept

    def add(self, t_s: float, z: Sequence[float]) -> None:
        """One innovation ``z`` at the bearing time ``t_s`` (s, in time order): a vector of
        three components tangent to the predicted direction (rad) divided by the bearing
        noise's standard deviation in use (rad), dimensionless. Plain floats: it runs at
        every bearing."""
        z0, z1, z2 = z
        sq = z0 * z0 + z1 * z1 + z2 * z2
        if not math.isfinite(sq):
            self._prev = None
            return
        m = self._m
        if self._n >= MIN_PAIRS and sq * m > CLIP_RMS * CLIP_RMS * self._sq:
            self._prev = None  # a gross error: neither compared nor a neighbour
            return
        t_prev = t_s if m == 0.0 else self._t_prev_s  # (the first: nothing to age)
        dt = t_s - t_prev
        rho = math.exp(-dt / self.memory_s) if dt > 0.0 else 1.0  # (across gaps too)
        self._sq = rho * self._sq + sq
        self._m = rho * m + 1.0
        prev = self._prev
        if prev is not None and 0.0 <= dt <= MAX_GAP_S:
            p0, p1, p2, psq = prev
            self._c0 = rho * self._c0 + 0.5 * (sq + psq)
            self._c1 = rho * self._c1 + z0 * p0 + z1 * p1 + z2 * p2
            self._n = rho * self._n + 1.0
            self._dt = rho * self._dt + dt
        elif rho != 1.0:
            self._c0 *= rho
            self._c1 *= rho
            self._n *= rho
            self._dt *= rho
        self._prev = (z0, z1, z2, sq)
        if t_s > t_prev or m == 0.0:
            self._t_prev_s = t_s

    def gap(self) -> None:
        """The stream is interrupted (no innovation of the kind measured): the next one is
        not compared with the last."""
        self._prev = None

    def correlation(self) -> Correlation | None:
        """The correlation so far, or ``None`` before :data:`MIN_PAIRS` pairs."""
        if self._n < MIN_PAIRS or not self._c0 > 0.0:
            return None
        lag1 = max(-1.0, min(1.0, self._c1 / self._c0))
        mean_dt = self._dt / self._n
        if lag1 <= 0.0:
            tau: float | None = None
        elif lag1 >= 1.0:
            tau = math.inf
        else:
            tau = -mean_dt / math.log(lag1)
        var_ratio = self._c0 / self._n / 2.0  # (two tangent directions)
        return Correlation(lag1=lag1, corr_time_s=tau, var_ratio=var_ratio, pairs=self._n)

    def copy(self) -> InnovationCorrelation:
        """An independent copy."""
        other = object.__new__(InnovationCorrelation)
        other.__dict__.update(self.__dict__)
        return other
