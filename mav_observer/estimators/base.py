"""The estimator interface: what :class:`~mav_observer.observer.BiasObserver` asks of an
estimator of ``x`` (relative position, m) and ``a`` (constant velocity term, m/s) in the
model ``x' = v + a``, ``y = x / |x|`` (the paper's signs; for a vehicle ``v`` is minus its
velocity, see :mod:`mav_observer.samples`).

The observer owns the samples (:class:`~mav_observer.streams.SampleStreams`), the monitor,
the status and the persistence, and drives an estimator through the intervals between the
sample times:

1. :meth:`Estimator.start` at the first time both streams have data, with the latest bearing;
2. for each interval between breakpoints, :meth:`Estimator.substeps` sub-steps of
   :meth:`Estimator.predict` with the inputs frozen at each sub-step's midpoint (the
   estimator may read more of them, :class:`Inputs`);
3. :meth:`Estimator.update` with each bearing sample, at its time;
4. :meth:`Estimator.output` for the estimate (and covariance) at the committed time.

Every step runs on :meth:`Estimator.copy` and is committed by replacing the original, so a
step that raises changes nothing. Lists of floats cross the interface (the per-sample path
is too short for numpy to pay), a covariance as a flat row-major list.

A new estimator is one module implementing :class:`Estimator` and one line in
:data:`mav_observer.estimators.REGISTRY`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

from mav_observer.samples import NoiseLevels


class Inputs(Protocol):
    """What an estimator may read of the samples while it steps (a read-only view of
    :class:`~mav_observer.streams.SampleStreams`)."""

    #: the velocity's latest sample interval (s)
    velocity_dt_s: float

    def velocity_at(self, t: float) -> list[float]: ...

    def bearing_at(self, t: float) -> list[float] | None: ...

    def chord_at(self, t: float) -> bool: ...

    @property
    def sparse(self) -> bool: ...


@dataclass(frozen=True)
class Output:
    """An estimator's estimate at its current time: ``x_m`` (m) and ``a_mps`` (m/s) as lists,
    ``p`` the covariance of ``[x, a]`` ((2n, 2n), m and m/s; flat, row-major: the entry
    ``(i, j)`` at ``2 n i + j``) or ``None`` when the estimator has none."""

    x_m: list[float]
    a_mps: list[float]
    p: list[float] | None


class Estimator(Protocol):
    """One estimator of ``x`` and ``a``; see the module docstring for the call sequence."""

    #: the registry's name of the estimator
    name: ClassVar[str]
    #: True if it corrects continuously from the interpolated bearing inside
    #: :meth:`predict` (the paper's observer), False if only at the bearing samples in
    #: :meth:`update` (a Kalman filter): the monitor counts a step as corrected accordingly
    continuous: ClassVar[bool]

    @property
    def min_interval_s(self) -> float:
        """Breakpoints closer than this (s) merge (0: every sample time is a breakpoint)."""
        ...

    @property
    def started(self) -> bool:
        """True once :meth:`start` has run."""
        ...

    @property
    def settled(self) -> bool:
        """True once nothing the estimator learns still moves its estimate for long (the
        bearings' latency, when learnt, has settled once): until then the monitor calls no
        estimate ``converged``."""
        ...

    def start(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        """Begin at ``t_s`` from the bearing ``y`` (unit vector) of time ``t_s`` or before."""
        ...

    def copy(self) -> Estimator:
        """An independent copy to step on. Its open-loop reference (see :meth:`predict`) is
        this state's bias."""
        ...

    def substeps(self, span_s: float, corrected: bool) -> int:
        """How many sub-steps an interval of ``span_s`` (s) takes, ``corrected`` when a
        bearing is in force over it."""
        ...

    def predict(
        self, t_s: float, h_s: float, v_mps: list[float], y: list[float] | None, inputs: Inputs
    ) -> list[float]:
        """Propagate over the sub-step of ``h_s`` (s) centred on ``t_s`` with the velocity
        ``v_mps`` (m/s) and the bearing ``y`` (or ``None``: none in force) of its midpoint
        held. Returns the open-loop displacement (m): what the model alone moved ``x`` by,
        without the bearing's correction (the monitor's correction is the rest)."""
        ...

    def update(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        """The bearing sample ``y`` (unit vector) of time ``t_s``."""
        ...

    def output(self, inputs: Inputs) -> Output:
        """The estimate at the current time (cached until the state changes)."""
        ...

    def position_cov(self, dt_s: float, inputs: Inputs) -> list[float] | None:
        """The covariance of ``x`` (m^2; ``(n, n)`` flat, row-major) predicted ``dt_s`` ahead
        with the velocity held, or ``None`` without a covariance."""
        ...

    def cond(self) -> float:
        """The condition number of the position's information (1 before the start)."""
        ...

    def nis(self) -> float | None:
        """The recent normalised innovation squared per degree of freedom, if any."""
        ...

    def noise(self, inputs: Inputs) -> NoiseLevels | None:
        """The noise levels in use and the robust update's counts, if the estimator has
        any."""
        ...

    @property
    def reacquisitions(self) -> int:
        """Times it started again because its bearings stopped agreeing with it."""
        ...

    def observe_velocity(self, t_s: float, v_mps: list[float]) -> None:
        """A velocity sample accepted (for an estimator that learns its noise)."""
        ...

    def shift(self, dx_m: list[float]) -> None:
        """Move the position estimate by ``dx_m`` (m), across a gap in the data."""
        ...

    def to_dict(self) -> dict[str, Any]:
        """The state as JSON-serialisable entries of the observer's saved state."""
        ...

    def restore(self, d: dict[str, Any], started: bool) -> None:
        """Restore from the saved state ``d`` (the observer's whole dictionary) of an
        observer that had ``started``; a bad field is a :class:`StateError` naming it."""
        ...
