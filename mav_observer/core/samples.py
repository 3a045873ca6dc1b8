"""The small immutable records that carry data between the parts of mav-observer.

Conventions (the paper's, see ``docs/observer.md``):

* ``x`` is the relative position the observer estimates. For a vehicle looking at a target
  in the local NED frame, ``x = p_target - p_vehicle`` in metres.
* ``v`` is the *known* part of ``dx/dt``. For a vehicle it is **minus** the vehicle's
  measured velocity: ``v = -u``. It is in the same frame as ``x``, in m/s.
* ``a`` is the unknown constant part of ``dx/dt`` (m/s): target velocity minus the vehicle's
  velocity error.
* ``y = x / |x|`` is the bearing, a unit vector in the same frame.

Construction validates: a sample that exists is finite, of a supported dimension, and (for a
bearing) a unit vector. Arrays are copied and made read-only so a sample cannot change after
it was accepted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import NamedTuple

import numpy as np

from mav_observer.errors import InvalidSampleError

#: A bearing whose norm is within this relative distance of 1 is normalised silently;
#: farther from unit length it is rejected as "far from unit".
BEARING_NORM_TOL = 0.01

#: Smallest supported dimension (the paper's n >= 2).
MIN_DIM = 2


def _frozen_vector(name: str, value: object, t_s: float) -> np.ndarray:
    """Return ``value`` as a read-only 1-D float64 copy, or raise naming ``name``."""
    if type(value) is tuple and len(value) >= MIN_DIM and all(type(c) is float for c in value):
        # fast path for a tuple of plain floats (the MAVLink adapters): check in Python
        if not all(math.isfinite(c) for c in value):
            raise InvalidSampleError(
                f"{name}={list(value)} at t_s={t_s} contains a non-finite value"
            )
        arr = np.array(value)
        arr.setflags(write=False)
        return arr
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidSampleError(f"{name}={value!r} at t_s={t_s} is not a numeric vector") from exc
    if arr.ndim != 1 or arr.shape[0] < MIN_DIM:
        raise InvalidSampleError(
            f"{name} must be a vector of dimension >= {MIN_DIM}, got shape {arr.shape} at t_s={t_s}"
        )
    if not np.all(np.isfinite(arr)):
        raise InvalidSampleError(f"{name}={arr.tolist()} at t_s={t_s} contains a non-finite value")
    arr.setflags(write=False)
    return arr


def _check_time(t_s: object) -> float:
    if isinstance(t_s, bool) or not isinstance(t_s, (int, float, np.floating, np.integer)):
        raise InvalidSampleError(f"t_s={t_s!r} is not a number")
    t = float(t_s)
    if not math.isfinite(t):
        raise InvalidSampleError(f"t_s={t} is not finite")
    return t


@dataclass(frozen=True, eq=False, slots=True)
class VelocitySample:
    """The known velocity term ``v`` (m/s) at time ``t_s`` (s, on the observer's time base).

    For a vehicle this is minus its measured velocity (``v = -vel_ned_mps``); see the module
    docstring for the sign convention.
    """

    t_s: float
    v_mps: np.ndarray

    def __post_init__(self) -> None:
        t = _check_time(self.t_s)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "v_mps", _frozen_vector("v_mps", self.v_mps, t))

    @property
    def dim(self) -> int:
        return int(self.v_mps.shape[0])


@dataclass(frozen=True, eq=False, slots=True)
class BearingSample:
    """A measured direction ``y`` (unit vector, dimensionless) from the observer's origin
    (the vehicle) towards ``x`` (the target), at time ``t_s`` (s).

    A ``y`` whose norm is within :data:`BEARING_NORM_TOL` of 1 is normalised; zero-length or
    farther-from-unit vectors are rejected. Use :meth:`from_vector` to build a bearing from
    any non-zero direction vector (a line of sight in camera units, say).

    ``range_m``: the distance to the target measured with the bearing (a rangefinder on the
    gimbal, m; positive and finite), ``range_std_m`` its standard deviation (m): the target is
    then observable without any motion.
    """

    t_s: float
    y: np.ndarray
    range_m: float | None = None
    range_std_m: float = 1.0

    def __post_init__(self) -> None:
        t = _check_time(self.t_s)
        y = _frozen_vector("y", self.y, t)
        norm = float(np.linalg.norm(y))
        if norm == 0.0:
            raise InvalidSampleError(f"bearing y={y.tolist()} at t_s={t} has zero length")
        if abs(norm - 1.0) > BEARING_NORM_TOL:
            raise InvalidSampleError(
                f"bearing y={y.tolist()} at t_s={t} is far from unit length (|y|={norm:.6g}, "
                f"tolerance {BEARING_NORM_TOL})"
            )
        if norm != 1.0:
            y = y / norm
            y.setflags(write=False)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "y", y)
        if self.range_m is not None:
            r, sd = float(self.range_m), float(self.range_std_m)
            if not (math.isfinite(r) and r > 0.0 and math.isfinite(sd) and sd > 0.0):
                raise InvalidSampleError(
                    f"bearing at t_s={t}: range_m={self.range_m} and range_std_m="
                    f"{self.range_std_m} must be positive and finite"
                )
            object.__setattr__(self, "range_m", r)
            object.__setattr__(self, "range_std_m", sd)

    @classmethod
    def from_vector(cls, t_s: float, direction: object) -> BearingSample:
        """Bearing along any finite, non-zero ``direction`` vector (normalised here)."""
        t = _check_time(t_s)
        if isinstance(direction, tuple | list) and all(type(c) is float for c in direction):
            # fast path for plain floats (the MAVLink adapters): no numpy until the end
            n2 = sum(c * c for c in direction)
            if len(direction) < MIN_DIM or not (n2 > 0.0 and math.isfinite(n2)):
                raise InvalidSampleError(
                    f"direction={list(direction)} at t_s={t} has no usable length or dimension"
                )
            inv = 1.0 / math.sqrt(n2)
            y = np.array([c * inv for c in direction])
        else:
            d = _frozen_vector("direction", direction, t)
            norm = math.sqrt(float(d @ d))
            if not norm > 0.0 or not math.isfinite(norm):
                raise InvalidSampleError(f"direction={d.tolist()} at t_s={t} has no usable length")
            y = d / norm
        y.setflags(write=False)
        obj = object.__new__(cls)  # already validated: skip __post_init__
        object.__setattr__(obj, "t_s", t)
        object.__setattr__(obj, "y", y)
        return obj

    @property
    def dim(self) -> int:
        return int(self.y.shape[0])


class Status(StrEnum):
    """What an estimate is worth; the rules are in :mod:`mav_observer.core.kernels.monitor`."""

    CONVERGING = "converging"
    CONVERGED = "converged"
    NOT_OBSERVABLE = "not observable"
    STALE = "stale"


class Estimate(NamedTuple):
    """The observer's output at time ``t_s`` (s).

    * ``x_m``: estimated relative position ``xhat`` (m), target minus vehicle.
    * ``a_mps``: estimated constant velocity term ``ahat`` (m/s); zeros in bias-free mode.
    * ``range_m``: ``|xhat|`` (m).
    * ``excitation``: smallest eigenvalue of the time-average of ``Pi_y`` over the monitor's
      window, in [0, (n-1)/n]; 0 means the bearing did not move.
    * ``cond_m``: 2-norm condition number of the observer matrix ``M`` (of the committed
      state: an estimate ahead of it is a prediction that does not change it meaningfully).
    * ``status``: see :class:`Status`.
    * ``corrected``: False when the last step only predicted (no usable bearing).
    * ``bearing_age_s`` / ``velocity_age_s``: time since the latest sample of each stream.
    * ``correction_rel``: net correction applied over the window, relative to the range
      (the convergence indicator of the monitor).
    * ``x_std_m``, ``a_std_mps``: standard deviation of each component of ``x_m`` (m) and
      ``a_mps`` (m/s), and ``range_std_m`` that of the range along the estimated bearing (m),
      from the estimator's covariance; ``None`` for the paper's observer, which has none.
    * ``nis``: the estimator's normalised innovation squared per degree of freedom, averaged
      over its recent bearings (about 1 when the bearings agree with the model and the noise
      setting; well above 1: more noise than told, or outliers); ``None`` for the paper's
      observer.

    Immutable (a named tuple: made at every bearing, it must be cheap); ``_replace`` makes
    a changed copy.
    """

    t_s: float
    x_m: np.ndarray
    a_mps: np.ndarray
    range_m: float
    excitation: float
    cond_m: float
    status: Status
    corrected: bool
    bearing_age_s: float | None
    velocity_age_s: float | None
    correction_rel: float
    x_std_m: np.ndarray | None = None
    a_std_mps: np.ndarray | None = None
    range_std_m: float | None = None
    nis: float | None = None

    def with_a(self, a_mps: np.ndarray) -> Estimate:
        """This estimate with ``a_mps`` (m/s, a read-only array) in place of its own."""
        return self._replace(a_mps=a_mps)

    def to_dict(self) -> dict[str, object]:  # type: ignore[override]
        """Plain JSON-serialisable form."""
        return {
            "t_s": self.t_s,
            "x_m": self.x_m.tolist(),
            "a_mps": self.a_mps.tolist(),
            "range_m": self.range_m,
            "excitation": self.excitation,
            "cond_m": self.cond_m,
            "status": str(self.status),
            "corrected": self.corrected,
            "bearing_age_s": self.bearing_age_s,
            "velocity_age_s": self.velocity_age_s,
            "correction_rel": self.correction_rel,
            "x_std_m": None if self.x_std_m is None else self.x_std_m.tolist(),
            "a_std_mps": None if self.a_std_mps is None else self.a_std_mps.tolist(),
            "range_std_m": self.range_std_m,
            "nis": self.nis,
        }


#: The innovations' lag-1 correlation (``NoiseLevels.innovation_corr``): at or above this it
#: is reported as a warning (replay's summary, the service's log) ...
WARN_LAG1 = 0.5
#: ... when the innovations are not much smaller than the noise in use: their mean square
#: per tangent direction at least this fraction of its variance (noise-free bearings leave
#: correlated innovations far below the learnt noise's floor, which covers them: no warning).
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


@dataclass(frozen=True, slots=True)
class NoiseLevels:
    """The noise an estimator works with, and what its robust update saw.

    * ``bearing_noise_deg``: bearing noise per tangent direction in use (1 sigma, deg).
    * ``bearing_noise_learnt``: true when learnt online (``bearing_noise_deg = "auto"``),
      false when told.
    * ``velocity_noise_mps``: white velocity noise per axis in use (1 sigma, m/s).
    * ``velocity_noise_learnt``: likewise.
    * ``bearings``: bearings applied; ``outliers``: of them, down-weighted as gross errors;
      ``reacquisitions``: times the estimate was re-seeded after a persistent
      inconsistency (the target moved, the tracker locked onto something else);
      ``reacquiring_s``: the time (s) from each of those to the next ``converged`` estimate.
    * ``bearing_latency_s``: how long the bearings trail the line of sight in use (s),
      ``bearing_latency_learnt``: learnt online or told.
    * ``bias_walk_mps_per_sqrt_s``: the random walk of the bias in use (m/s per square root
      of a second; 0: constant), ``bias_walk_learnt``: learnt online or told.
    * ``innovation_corr``: the lag-1 correlation of successive innovations once the estimate
      is down to one filter, and its correlation time
      and the innovations' size against the noise in use
      (:class:`Correlation`), or ``None`` (too few yet, or an
      estimator without it): near 0 when the bearing errors are white, as the covariance
      assumes; ``Correlation.systematic`` (correlated and not small), the errors are
      systematic and ``target_h_std_m`` is likely too small.
    """

    bearing_noise_deg: float
    bearing_noise_learnt: bool
    velocity_noise_mps: float
    velocity_noise_learnt: bool
    bearings: int
    outliers: int
    reacquisitions: int
    reacquiring_s: float = 0.0
    bearing_latency_s: float = 0.0
    bearing_latency_learnt: bool = False
    bias_walk_mps_per_sqrt_s: float = 0.0
    bias_walk_learnt: bool = False
    innovation_corr: Correlation | None = None

    def to_dict(self) -> dict[str, float | int | bool | None]:
        ic = self.innovation_corr
        return {
            "bearing_noise_deg": self.bearing_noise_deg,
            "bearing_noise_learnt": self.bearing_noise_learnt,
            "velocity_noise_mps": self.velocity_noise_mps,
            "velocity_noise_learnt": self.velocity_noise_learnt,
            "bearings": self.bearings,
            "outliers": self.outliers,
            "reacquisitions": self.reacquisitions,
            "reacquiring_s": round(self.reacquiring_s, 3),
            "bearing_latency_s": self.bearing_latency_s,
            "bearing_latency_learnt": self.bearing_latency_learnt,
            "bias_walk_mps_per_sqrt_s": self.bias_walk_mps_per_sqrt_s,
            "bias_walk_learnt": self.bias_walk_learnt,
            "innovation_lag1": None if ic is None else round(ic.lag1, 4),
            "innovation_corr_time_s": None
            if ic is None or ic.corr_time_s is None or not math.isfinite(ic.corr_time_s)
            else round(ic.corr_time_s, 4),
            "innovation_var_ratio": None if ic is None else round(ic.var_ratio, 4),
        }
