"""A bearing the tracker used, as a geodetic ray for other machines
(:class:`~mav_observer.fleet.rays.Ray`, ``docs/fleet.md``).

The vehicle's position at the bearing's time is its latest LOCAL_POSITION_NED moved on by the
velocity of its last two positions (not by the measured velocity, whose bias is what the
observers estimate), placed on WGS84 through the vehicle's origin and its autopilot's local
frame. The time is the autopilot's SYSTEM_TIME Unix time when it has one, else the service's
clock. No I/O.
"""

from __future__ import annotations

import math

from mav_observer.fleet.rays import Ray
from mav_observer.geo.geodesy import to_geodetic
from mav_observer.tracking.bearings import POSITION_MAX_AGE_S
from mav_observer.tracking.vehicle import Vehicle

#: Two positions this far apart or closer (s) give the velocity that moves the latest one.
MOTION_MAX_SPAN_S = 2.0


def _position_at(veh: Vehicle, t_boot_s: float) -> tuple[float, float, float] | None:
    if veh.position is None:
        return None
    tp, pos, vel = veh.position
    dt = t_boot_s - tp
    if abs(dt) > POSITION_MAX_AGE_S:
        return None
    rate = vel  # fallback: the measured velocity, when there is no earlier position
    if len(veh.positions) >= 2:
        t1, p1, _v1 = veh.positions[-2]
        if 0.0 < tp - t1 <= MOTION_MAX_SPAN_S:
            rate = tuple((a - b) / (tp - t1) for a, b in zip(pos, p1, strict=True))  # type: ignore[assignment]
    return (pos[0] + rate[0] * dt, pos[1] + rate[1] * dt, pos[2] + rate[2] * dt)


def ray_of(
    out: list[Ray],
    veh: Vehicle,
    target: str,
    times: tuple[float, float],
    los_ned: list[float],
    noise_var: float | None,
    range_m: float | None = None,
    range_std_m: float | None = None,
) -> None:
    """Append to ``out`` the ray of a bearing the tracker used at ``times`` (``t_boot_s``,
    ``t_arrival_s``) with its estimator's bearing noise variance (rad^2); nothing without an
    origin or a recent position (a ray must say where the vehicle was on the earth)."""
    t_boot_s, t_arrival_s = times
    sigma_rad = math.nan if noise_var is None else math.sqrt(noise_var)
    if veh.origin is None or not (0.0 < sigma_rad < 1.0):
        return
    pos = _position_at(veh, t_boot_s)
    if pos is None:
        return
    lat, lon, alt = to_geodetic(veh.origin, pos)
    if veh.unix_minus_boot_s is not None:
        t_unix, clock = t_boot_s + veh.unix_minus_boot_s, "autopilot"
        offset: float | None = t_unix - t_arrival_s if math.isfinite(t_arrival_s) else None
    else:
        t_unix, clock, offset = t_arrival_s, "service", None
    vel = None if veh.position is None else tuple(float(c) for c in veh.position[2])
    out.append(
        Ray(
            sysid=veh.sysid,
            target=target,
            t_unix_s=t_unix,
            t_boot_s=t_boot_s,
            clock=clock,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt,
            los_ned=(los_ned[0], los_ned[1], los_ned[2]),
            sigma_rad=sigma_rad,
            vel_ned_mps=vel,  # type: ignore[arg-type]
            range_m=range_m,
            range_std_m=range_std_m if range_m is not None else None,
            clock_offset_s=offset,
        )
    )
