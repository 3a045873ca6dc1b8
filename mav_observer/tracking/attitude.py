"""The vehicle's attitude over time: a short history on the autopilot clock, interpolated
between samples and extrapolated past the latest with its rates.

Pure: no I/O and no MAVLink; :class:`~mav_observer.tracking.tracker.Tracker` fills it from
ATTITUDE (or ATTITUDE_QUATERNION) and asks it for the attitude at a bearing's own time.
Angles are ZYX Euler (roll, pitch, yaw) in rad, body FRD relative to NED; times in s.
"""

from __future__ import annotations

import math
from collections import deque


class AttitudeHistory:
    """Recent vehicle attitudes ``(t_s, roll, pitch, yaw)`` on the autopilot clock, bounded,
    with the latest Euler angle rates (rad/s) for extrapolation."""

    def __init__(self, maxlen: int = 128) -> None:
        self._h: deque[tuple[float, float, float, float]] = deque(maxlen=maxlen)
        self._rates: tuple[float, float, float] | None = None
        #: the stream's typical interval (s), a running mean of the intervals up to 2 s
        self.interval_s = 0.0

    @property
    def has_rates(self) -> bool:
        """True once the latest attitude has rates to extrapolate with."""
        return self._rates is not None

    @property
    def latest_t_s(self) -> float | None:
        """Time of the latest attitude (s), ``None`` before any."""
        return self._h[-1][0] if self._h else None

    def add(
        self,
        t: float,
        roll: float,
        pitch: float,
        yaw: float,
        body_rates: tuple[float, float, float] | None = None,
    ) -> None:
        """Add an attitude; ``body_rates`` (p, q, r in rad/s, FRD body frame) when the message
        has them (ATTITUDE's rollspeed, pitchspeed, yawspeed), else the rates come from the
        difference with the previous attitude."""
        h = self._h
        if h and t < h[-1][0]:
            return  # older than what we have: keep the history ordered
        if h and t == h[-1][0]:
            h.pop()
        if h and 0.0 < t - h[-1][0] <= 2.0:
            dt = t - h[-1][0]
            self.interval_s = dt if self.interval_s == 0.0 else 0.9 * self.interval_s + 0.1 * dt
        rates = None
        if body_rates is not None and all(map(math.isfinite, body_rates)) and any(body_rates):
            rates = euler_rates(roll, pitch, body_rates)
        elif h and 0.0 < t - h[-1][0] <= 2.0:
            a = h[-1]
            dt = t - a[0]
            rates = (
                (roll - a[1]) / dt,
                (pitch - a[2]) / dt,
                math.remainder(yaw - a[3], 2 * math.pi) / dt,
            )
        self._rates = rates
        h.append((t, roll, pitch, yaw))

    def at(self, t: float, max_age_s: float) -> tuple[float, float, float] | None:
        """Attitude at ``t``: interpolated between the samples around it (yaw unwrapped) when
        they are at most ``2 max_age_s`` or 2.5 stream intervals apart (a 1 Hz ATTITUDE of an
        old telemetry link is interpolated); after the latest one, extrapolated with its
        rates for at most ``max_age_s`` (held when no rate is known); else the nearest one
        within ``max_age_s``; ``None`` if there is none."""
        h = self._h
        if not h:
            return None
        last = h[-1]
        if t >= last[0]:
            dt = t - last[0]
            if dt > max_age_s:
                return None
            r = self._rates
            if r is None or dt == 0.0:
                return last[1:]
            return (last[1] + r[0] * dt, last[2] + r[1] * dt, last[3] + r[2] * dt)
        for i in range(len(h) - 2, -1, -1):
            a = h[i]
            if a[0] <= t:
                b = h[i + 1]
                if b[0] - a[0] > max(2 * max_age_s, 2.5 * self.interval_s):
                    near = a if t - a[0] <= b[0] - t else b
                    return near[1:] if abs(near[0] - t) <= max_age_s else None
                f = (t - a[0]) / (b[0] - a[0])
                dyaw = math.remainder(b[3] - a[3], 2 * math.pi)
                return (
                    a[1] + f * (b[1] - a[1]),
                    a[2] + f * (b[2] - a[2]),
                    a[3] + f * dyaw,
                )
        first = h[0]
        return first[1:] if first[0] - t <= max_age_s else None


def euler_rates(
    roll: float, pitch: float, body_rates: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Rates of (roll, pitch, yaw) (rad/s) from the body rates ``(p, q, r)`` (rad/s, FRD)
    at that attitude (ZYX Euler angles; singular at pitch +-90 deg, where the yaw rate is
    taken as ``r``)."""
    p, q, r = body_rates
    sr, cr = math.sin(roll), math.cos(roll)
    cp = math.cos(pitch)
    if abs(cp) < 1e-3:
        return (p, q, r)
    tp = math.sin(pitch) / cp
    return (p + (q * sr + r * cr) * tp, q * cr - r * sr, (q * sr + r * cr) / cp)


__all__ = ["AttitudeHistory", "euler_rates"]
