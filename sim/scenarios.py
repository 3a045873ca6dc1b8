"""Named truth scenarios for the observer (pure: no I/O, no clock).

A :class:`Scenario` gives, at any time ``t`` (s, vectorised over arrays of times), the true
relative position ``x(t)`` (target minus vehicle, metres) and its rate ``x'(t)``, with the
true constant term ``a``. The velocity the observer is given is the paper's ``v = x' - a``,
that is minus the vehicle's measured velocity (see ``docs/observer.md``).

Drone scenarios are in a local NED frame (north, east, down): a vehicle 10 m *above* a
target has ``x = (.., .., +10)``. Their velocity error ``wind`` is the constant ``b`` in
"true vehicle velocity = measured + b", so for a static target ``a = -b``; a target moving at
``w`` gives ``a = w - b``.

Use :func:`make` with a name from :data:`SCENARIOS`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Vec = tuple[float, ...]


@dataclass(frozen=True)
class Scenario:
    """A truth generator. ``x_of_t`` and ``xdot_of_t`` map an array of times (shape (T,))
    to arrays of shape (T, n)."""

    name: str
    n: int
    duration_s: float
    a_mps: np.ndarray
    x_of_t: Callable[[np.ndarray], np.ndarray]
    xdot_of_t: Callable[[np.ndarray], np.ndarray]
    description: str = ""
    #: The target's own constant velocity ``w`` (m/s); the vehicle's velocity error is then
    #: ``b = w - a``. Zero: a static target, ``a = -b``.
    target_vel_mps: np.ndarray | None = None

    @property
    def w_mps(self) -> np.ndarray:
        return np.zeros(self.n) if self.target_vel_mps is None else self.target_vel_mps

    @property
    def vel_error_mps(self) -> np.ndarray:
        """``b``: true vehicle velocity minus measured (wind-like), ``w - a``."""
        return self.w_mps - self.a_mps

    def x(self, t: np.ndarray | float) -> np.ndarray:
        """True relative position (m) at ``t``; shape (n,) for a scalar ``t``."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        out = self.x_of_t(tt)
        return out[0] if np.ndim(t) == 0 else out

    def xdot(self, t: np.ndarray | float) -> np.ndarray:
        """True ``dx/dt = v + a`` (m/s) at ``t``."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        out = self.xdot_of_t(tt)
        return out[0] if np.ndim(t) == 0 else out

    def v(self, t: np.ndarray | float) -> np.ndarray:
        """The known velocity term ``v = x' - a`` (m/s): minus the measured vehicle velocity."""
        return self.xdot(t) - self.a_mps

    def y(self, t: np.ndarray | float) -> np.ndarray:
        """True bearing ``x / |x|``."""
        x = self.x(t)
        return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _pause_phase(
    t: np.ndarray, pause: tuple[float, float] | None, ramp_s: float = 4.0
) -> tuple[np.ndarray, np.ndarray]:
    """Motion phase (s) and its rate for a vehicle that pauses: from ``start_s`` it slows
    down over ``ramp_s`` (raised-cosine speed profile), holds still for ``duration_s``, then
    speeds up again over ``ramp_s`` and carries on from where it stopped.
    ``pause = (start_s, duration_s)``; ``None`` is uniform motion."""
    if pause is None:
        return t, np.ones_like(t)
    start, dur = pause
    r = ramp_s
    t1, t2, t3 = start + r, start + r + dur, start + 2.0 * r + dur
    half = 0.5 * r  # phase gained over one ramp
    u = np.clip(t - start, 0.0, r)
    down_phase = 0.5 * u + r / (2.0 * np.pi) * np.sin(np.pi * u / r)
    w = np.clip(t - t2, 0.0, r)
    up_phase = 0.5 * w - r / (2.0 * np.pi) * np.sin(np.pi * w / r)
    phase = np.where(
        t < start,
        t,
        np.where(
            t < t2,
            start + down_phase,
            np.where(t < t3, start + half + up_phase, t - (t3 - start) + 2 * half),
        ),
    )
    rate = np.where(
        t < start,
        1.0,
        np.where(
            t < t1,
            0.5 * (1.0 + np.cos(np.pi * u / r)),
            np.where(t < t2, 0.0, np.where(t < t3, 0.5 * (1.0 - np.cos(np.pi * w / r)), 1.0)),
        ),
    )
    return phase, rate


def paper(duration_s: float = 300.0) -> Scenario:
    """The paper's Section 4: ``x(t) = (cos 0.5t, sin 0.5t, 3)``, ``a = (0.33, 0.66, 0.99)``,
    ``v + a = (-0.5 sin 0.5t, 0.5 cos 0.5t, 0)``; gains k = 0.5, k* = 5; xh1 = 0, M = I,
    zs = 0."""

    def x_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack((np.cos(0.5 * t), np.sin(0.5 * t), np.full_like(t, 3.0)))

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack((-0.5 * np.sin(0.5 * t), 0.5 * np.cos(0.5 * t), np.zeros_like(t)))

    return Scenario(
        name="paper",
        n=3,
        duration_s=duration_s,
        a_mps=np.array([0.33, 0.66, 0.99]),
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description="Le Bras et al. 2015, Section 4: target circling 3 m above a camera",
    )


def orbit(
    radius_m: float = 15.0,
    height_m: float = 10.0,
    lap_s: float = 40.0,
    wind_ned_mps: Vec = (3.0, -2.0, 0.0),
    duration_s: float = 300.0,
    pause: tuple[float, float] | None = None,
) -> Scenario:
    """A vehicle circling a fixed ground target at ``radius_m``, ``height_m`` above it, one lap
    per ``lap_s``; its measured velocity misses a constant ``wind_ned_mps`` (so
    ``a = -wind``). ``pause=(start_s, duration_s)`` makes it slow down (4 s), hover in place
    for ``duration_s`` and speed up again (4 s)."""
    omega = 2.0 * np.pi / lap_s
    wind = np.asarray(wind_ned_mps, dtype=float)

    def x_of_t(t: np.ndarray) -> np.ndarray:
        ph, _ = _pause_phase(t, pause)
        th = omega * ph
        return np.column_stack(
            (-radius_m * np.cos(th), -radius_m * np.sin(th), np.full_like(t, height_m))
        )

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        ph, rate = _pause_phase(t, pause)
        th = omega * ph
        s = radius_m * omega * rate
        return np.column_stack((s * np.sin(th), -s * np.cos(th), np.zeros_like(t)))

    return Scenario(
        name="orbit",
        n=3,
        duration_s=duration_s,
        a_mps=-wind,
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description=f"orbit R {radius_m} m, {height_m} m up, {lap_s} s lap, wind {wind.tolist()}",
    )


def hover(
    rel_pos_ned_m: Vec = (20.0, 10.0, 10.0),
    wind_ned_mps: Vec = (2.0, -1.0, 0.0),
    duration_s: float = 60.0,
) -> Scenario:
    """A vehicle hovering still, the target at ``rel_pos_ned_m`` from it; its measured velocity
    misses ``wind_ned_mps``. Bearings alone cannot tell the range (no motion); a range
    measured with them can."""
    x0 = np.asarray(rel_pos_ned_m, dtype=float)
    wind = np.asarray(wind_ned_mps, dtype=float)
    return Scenario(
        name="hover",
        n=3,
        duration_s=duration_s,
        a_mps=-wind,
        x_of_t=lambda t: np.tile(x0, (len(t), 1)),
        xdot_of_t=lambda t: np.zeros((len(t), 3)),
        description=f"hover, target at {x0.tolist()} m, wind {wind.tolist()}",
    )


def moving_target(
    target_vel_ned_mps: Vec = (1.5, 0.5, 0.0),
    wind_ned_mps: Vec = (0.0, 0.0, 0.0),
    standoff_m: float = 15.0,
    height_m: float = 10.0,
    weave_m: float = 15.0,
    weave_period_s: float = 20.0,
    duration_s: float = 300.0,
) -> Scenario:
    """A target driving at constant velocity; the vehicle follows it ``standoff_m`` behind
    (south-west), ``height_m`` above, weaving sideways ``weave_m`` and bobbing in range and
    height. ``a = target velocity - wind``."""
    w = np.asarray(target_vel_ned_mps, dtype=float)
    b = np.asarray(wind_ned_mps, dtype=float)
    om = 2.0 * np.pi / weave_period_s

    def offset(t: np.ndarray) -> np.ndarray:  # target minus vehicle, apart from the drift
        return np.column_stack(
            (
                standoff_m + 0.3 * weave_m * np.sin(0.5 * om * t),
                weave_m * np.sin(om * t),
                height_m + 0.25 * weave_m * np.sin(0.7 * om * t + 1.0),
            )
        )

    def offset_dot(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (
                0.3 * weave_m * 0.5 * om * np.cos(0.5 * om * t),
                weave_m * om * np.cos(om * t),
                0.25 * weave_m * 0.7 * om * np.cos(0.7 * om * t + 1.0),
            )
        )

    return Scenario(
        name="moving_target",
        n=3,
        duration_s=duration_s,
        a_mps=w - b,
        x_of_t=offset,
        xdot_of_t=offset_dot,
        description=f"target at {w.tolist()} m/s followed by a weaving vehicle",
        target_vel_mps=w,
    )


def straight_pass(
    speed_mps: float = 5.0,
    miss_distance_m: float = 20.0,
    height_m: float = 15.0,
    start_m: float = 80.0,
    pass_s: float = 32.0,
    wind_ned_mps: Vec = (1.0, 0.5, 0.0),
    duration_s: float = 120.0,
) -> Scenario:
    """A straight, level flight north past a fixed target (closest approach ``miss_distance_m``
    east of it, ``height_m`` above), lasting ``pass_s``, then a hover in place until the end:
    weak excitation, then none."""
    b = np.asarray(wind_ned_mps, dtype=float)

    def x_of_t(t: np.ndarray) -> np.ndarray:
        tp = np.minimum(t, pass_s)
        north = -start_m + speed_mps * tp
        return np.column_stack(
            (-north, np.full_like(t, -miss_distance_m), np.full_like(t, height_m))
        )

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        moving = np.where(t < pass_s, 1.0, 0.0)
        return np.column_stack((-speed_mps * moving, np.zeros_like(t), np.zeros_like(t)))

    return Scenario(
        name="straight_pass",
        n=3,
        duration_s=duration_s,
        a_mps=-b,
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description="straight pass (weak excitation) then hover (none)",
    )


def planar(
    radius_m: float = 12.0,
    centre_m: Vec = (10.0, 0.0),
    period_s: float = 30.0,
    a_mps: Vec = (0.4, -0.3),
    duration_s: float = 300.0,
) -> Scenario:
    """A 2-D case (n = 2): the relative position loops on an ellipse around ``centre_m``."""
    c = np.asarray(centre_m, dtype=float)
    om = 2.0 * np.pi / period_s

    def x_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (c[0] + radius_m * np.cos(om * t), c[1] + 0.6 * radius_m * np.sin(om * t))
        )

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (-radius_m * om * np.sin(om * t), 0.6 * radius_m * om * np.cos(om * t))
        )

    return Scenario(
        name="planar",
        n=2,
        duration_s=duration_s,
        a_mps=np.asarray(a_mps, dtype=float),
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description="2-D loop around an offset centre",
    )


def figure8(
    duration_s: float = 300.0,
    period_s: float = 60.0,
    half_width_m: float = 16.0,
    half_height_m: float = 8.0,
    centre_ne_m: tuple[float, float] = (22.0, 6.0),
    height_m: float = 12.0,
    wind_ned_mps: tuple[float, float, float] = (2.0, -1.0, 0.0),
) -> Scenario:
    """A figure-8 (lemniscate of Gerono) ``height_m`` above a ground target whose centre is
    ``centre_ne_m`` from the target; one figure per ``period_s``; constant velocity error
    ``wind_ned_mps`` (``a = -wind``)."""
    om = 2.0 * math.pi / period_s
    cn, ce = centre_ne_m
    wind = np.asarray(wind_ned_mps, dtype=float)

    def x_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (
                cn + half_width_m * np.sin(om * t),
                ce + half_height_m * np.sin(2 * om * t),
                np.full_like(t, height_m),
            )
        )

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (
                half_width_m * om * np.cos(om * t),
                2 * om * half_height_m * np.cos(2 * om * t),
                np.zeros_like(t),
            )
        )

    return Scenario(
        name="figure8",
        n=3,
        duration_s=duration_s,
        a_mps=-wind,
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description=f"figure-8 {2 * half_width_m:g} x {2 * half_height_m:g} m, {period_s:g} s",
    )


def weave(
    duration_s: float = 300.0,
    height_m: float = 15.0,
    wind_ned_mps: tuple[float, float, float] = (1.0, 1.5, 0.0),
) -> Scenario:
    """A vehicle weaving above a ground target (north 10 +- 8 m, east +- 6 m, 15 m up)."""
    wind = np.asarray(wind_ned_mps, dtype=float)
    w1, w2 = 2 * math.pi / 37.0, 2 * math.pi / 23.0

    def x_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (10.0 + 8.0 * np.sin(w1 * t), 6.0 * np.sin(w2 * t), np.full_like(t, height_m))
        )

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        return np.column_stack(
            (8.0 * w1 * np.cos(w1 * t), 6.0 * w2 * np.cos(w2 * t), np.zeros_like(t))
        )

    return Scenario(
        name="weave",
        n=3,
        duration_s=duration_s,
        a_mps=-wind,
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description="weaving above a ground target",
    )


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "paper": paper,
    "orbit": orbit,
    "moving_target": moving_target,
    "straight_pass": straight_pass,
    "planar": planar,
    "figure8": figure8,
    "weave": weave,
    "hover": hover,
}


def make(name: str, **params: object) -> Scenario:
    """Build the named scenario; ``params`` override its defaults."""
    try:
        factory = SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; choose from {sorted(SCENARIOS)}") from None
    return factory(**params)
