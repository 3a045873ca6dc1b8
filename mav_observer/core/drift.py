"""The velocity's drift from the vehicle's positions, and the bias published against it.

An autopilot's LOCAL_POSITION_NED carries a velocity and a position that its GNSS (or other
fixes) keeps true; the velocity wanders off the position's change. Over a short interval the
position's change, less the mean drift between the two, is the displacement the estimator
should integrate (``docs/frames.md``, "Velocity from the positions"): it does not accumulate
the velocity's wander, and a constant drift is the estimator's ``a`` to take up.

:class:`PositionDrift` learns that drift for one vehicle, hands out each interval's mean
velocity, finds position jumps (an EKF reset), and gives the bias ``a`` as published: the
estimator's ``a`` moved from the drift learnt once to the drift over every interval since.
:func:`position_at` moves a position fix on to a bearing's time the way the estimate did.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from mav_observer.core.batch_fit import RESET_GATE_M, RESET_GATE_MPS2
from mav_observer.core.samples import Estimate

if TYPE_CHECKING:
    from mav_observer.core.observer import BiasObserver

#: Two positions closer than this (s) give the displacement between them, at any rate: across
#: a telemetry gap of any length the position's change is the displacement, where the
#: velocity interpolated over the gap would miss every turn made in it.
SPARSE_VELOCITY_MAX_S = math.inf
#: An interval longer than this (s) teaches neither the drift nor the reset test: over a gap,
#: the velocity's trapezoid is off the positions by the turns made in it, not by the drift.
DRIFT_INTERVAL_MAX_S = 5.0
#: The mean drift is learnt over this much (s) of intervals, then kept: a drift that went on
#: following the velocity's slow wander would hand the estimator a varying ``a``, which its
#: model does not have (``docs/frames.md``).
DRIFT_LEARN_S = 1.0
#: A correction of the published bias smaller than this on every axis (m/s) is not applied:
#: below the record's resolution.
BIAS_CORRECTION_MIN_MPS = 1e-6

Vec3 = Sequence[float]


class PositionDrift:
    """The drift between one vehicle's positions and its integrated velocity (NED, m/s).

    * ``learnt_mps``: the drift taken out of every interval (learnt over the first
      :data:`DRIFT_LEARN_S`, then kept), with ``learnt_over_s`` of intervals seen;
    * ``sums_m``, ``span_s``: every interval kept so far, the sums of ``dp - trapezoid(u)``
      and of ``dt``: the long-run drift;
    * ``correction_mps``: what :meth:`published` adds to the estimator's ``a``, ``None``
      while the drift is being learnt or the correction is negligible;
    * ``deviation_mps``: the previous interval's deviation from the drift (``None``: no
      such interval just before).
    """

    __slots__ = ("correction_mps", "deviation_mps", "learnt_mps", "learnt_over_s", "span_s",
                 "sums_m")  # fmt: skip

    def __init__(self) -> None:
        self.learnt_mps = [0.0, 0.0, 0.0]
        self.learnt_over_s = 0.0
        self.sums_m = [0.0, 0.0, 0.0]
        self.span_s = 0.0
        self.correction_mps: list[float] | None = None
        self.deviation_mps: list[float] | None = None

    def interval(
        self, t0_s: float, p0_m: Vec3, u0_mps: Vec3, t_s: float, p_m: Vec3, u_mps: Vec3
    ) -> tuple[list[float] | None, bool]:
        """One interval between two position and velocity fixes (NED; the autopilot's
        velocity ``u``): ``(mean, reset)``. ``mean`` is the paper's ``v = -u`` averaged over
        the interval, from the position's change less the learnt drift, or ``None`` (no
        usable interval: a position jump); an interval longer than
        :data:`DRIFT_INTERVAL_MAX_S` (a telemetry gap) gives its mean and teaches nothing.
        ``reset`` is true for a jump: more than ``0.5 m + 5 m/s^2 dt^2`` off the velocity's
        trapezoid, drift removed, and as much off the previous interval's deviation (a step,
        not a velocity that disagrees with the position for seconds)."""
        dt = t_s - t0_s
        if not 0.0 < dt <= SPARSE_VELOCITY_MAX_S:
            self.deviation_mps = None
            return None, False
        drift, seen_s = self.learnt_mps, self.learnt_over_s
        if dt > DRIFT_INTERVAL_MAX_S:
            self.deviation_mps = None
            return [-((p_m[j] - p0_m[j]) / dt - drift[j]) for j in range(3)], False
        resid = [(p_m[j] - p0_m[j]) - 0.5 * (u0_mps[j] + u_mps[j]) * dt for j in range(3)]
        dev = [resid[j] / dt - drift[j] for j in range(3)]
        before = self.deviation_mps or [0.0, 0.0, 0.0]
        self.deviation_mps = dev
        off = math.sqrt(sum(d * d for d in dev)) * dt
        step = math.sqrt(sum((d - b) ** 2 for d, b in zip(dev, before, strict=True))) * dt
        gate = RESET_GATE_M + RESET_GATE_MPS2 * dt * dt
        w = dt / (seen_s + dt) if seen_s < DRIFT_LEARN_S else 0.0
        # every interval teaches the drift, a jump's share clipped to the gate, so that a
        # reset moves it little and a large constant error is still learnt
        clip = min(1.0, gate / off) if off > 0.0 else 1.0
        self.learnt_mps = [drift[j] + w * clip * dev[j] for j in range(3)]
        self.learnt_over_s = seen_s + dt
        if off > gate and step > gate:
            return None, True
        sums = [self.sums_m[j] + resid[j] for j in range(3)]
        self.sums_m, self.span_s = sums, self.span_s + dt
        drift = self.learnt_mps
        corr = [drift[j] - sums[j] / self.span_s for j in range(3)]
        big = self.span_s > DRIFT_LEARN_S and max(map(abs, corr)) >= BIAS_CORRECTION_MIN_MPS
        self.correction_mps = corr if big else None
        return [-((p_m[j] - p0_m[j]) / dt - drift[j]) for j in range(3)], False

    def published(self, est: Estimate) -> Estimate:
        """``est`` as published: its bias ``a`` against the velocity's long-run drift from
        the positions rather than the drift learnt once and taken out of the intervals
        (which the estimator's ``a`` took up)."""
        corr = self.correction_mps
        if corr is None:
            return est
        a = est.a_mps + corr  # a new array, read-only as the estimate's are
        a.setflags(write=False)
        return est.with_a(a)


def position_at(
    fix: tuple[float, Vec3, Vec3] | None,
    obs: BiasObserver | None,
    est: Estimate,
    t_s: float,
    max_age_s: float,
) -> tuple[float, float, float] | None:
    """The vehicle's position (NED, m) at ``t_s`` from the position fix ``(t, p, u)``,
    moved on the way the estimate was; ``None`` without a fix within ``max_age_s``."""
    if fix is None:
        return None
    tp, p, u = fix
    dt = t_s - tp
    if abs(dt) > max_age_s:
        return None
    # by minus the observer's predicted displacement of x less ``a`` dt: ``a`` is the
    # velocity's error where the target stands still, so the velocity as measured would move
    # the vehicle off the path the estimate integrated (docs/frames.md)
    a0, a1, a2 = est.a_mps.tolist()
    disp = None if obs is None else obs.predicted_displacement_m(tp, t_s)
    if disp is None:
        disp = [-u[0] * dt, -u[1] * dt, -u[2] * dt]
    return (p[0] - disp[0] - a0 * dt, p[1] - disp[1] - a1 * dt, p[2] - disp[2] - a2 * dt)
