"""A bearing shared between machines: a geodetic ray (``docs/schema.md``, ``docs/fleet.md``).

A vehicle's service publishes each bearing it uses as a ray: where the vehicle was (WGS84
latitude, longitude, altitude AMSL, from its origin and local position), the unit line of
sight in the vehicle's own north-east-down frame, the bearing's noise, the vehicle's measured
velocity, and its time on a common clock. A ray is self-contained: the vehicle's position and
its line of sight are of the same instant on the vehicle's own clock, so a fusion node needs
no clock alignment between vehicles to locate a fixed target. Validated at the boundary
(:func:`ray_from_dict`); no I/O.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from mav_observer.errors import InvalidSampleError
from mav_observer.geo.geodesy import check_geodetic

SCHEMA_VERSION = 1
#: Where a ray's ``t_unix_s`` comes from: the autopilot's SYSTEM_TIME Unix time, else the
#: service's clock when the message arrived.
CLOCKS = ("autopilot", "service")
#: Largest line-of-sight length error accepted before normalising.
LOS_NORM_TOL = 1e-3


class InvalidRayError(InvalidSampleError):
    """A ray was refused; the message names the field and its value."""


@dataclass(frozen=True)
class Ray:
    """One bearing as a geodetic ray (see the module docstring).

    ``key`` is ``"{sysid}/{target}"``; ``sigma_rad`` the bearing noise (1 sigma per tangent
    axis, rad) the vehicle's estimator uses; ``t_boot_s`` the vehicle's boot clock (its own,
    for its velocity bias); ``clock_offset_s`` the autopilot's Unix time minus the service's
    clock, when both are known; ``sent_unix_s`` the service's clock at publication.
    """

    sysid: int
    target: str
    t_unix_s: float
    t_boot_s: float
    clock: str
    lat_deg: float
    lon_deg: float
    alt_m: float
    los_ned: tuple[float, float, float]
    sigma_rad: float
    vel_ned_mps: tuple[float, float, float] | None = None
    range_m: float | None = None
    range_std_m: float | None = None
    clock_offset_s: float | None = None
    sent_unix_s: float | None = None

    @property
    def key(self) -> str:
        return f"{self.sysid}/{self.target}"

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "schema": SCHEMA_VERSION,
            "sysid": self.sysid,
            "target": self.target,
            "t_unix_s": self.t_unix_s,
            "t_boot_s": self.t_boot_s,
            "clock": self.clock,
            "lat_deg": self.lat_deg,
            "lon_deg": self.lon_deg,
            "alt_m": self.alt_m,
            "los_ned": list(self.los_ned),
            "sigma_rad": self.sigma_rad,
            "vel_ned_mps": None if self.vel_ned_mps is None else list(self.vel_ned_mps),
            "range_m": self.range_m,
            "range_std_m": self.range_std_m,
            "clock_offset_s": self.clock_offset_s,
            "sent_unix_s": self.sent_unix_s,
        }
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"))


def _number(d: dict[str, Any], name: str, *, optional: bool = False) -> float | None:
    v = d.get(name)
    if v is None and optional:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InvalidRayError(f"ray {name}={v!r} is not a finite number")
    return float(v)


def _vector(d: dict[str, Any], name: str, *, optional: bool = False) -> tuple[float, ...] | None:
    v = d.get(name)
    if v is None and optional:
        return None
    if not isinstance(v, (list, tuple)) or len(v) != 3:
        raise InvalidRayError(f"ray {name}={v!r} is not a list of 3 numbers")
    out = tuple(_number({"c": c}, "c") for c in v)
    return out  # type: ignore[return-value]


def ray_from_dict(d: Any) -> Ray:
    """A :class:`Ray` from its JSON form, checked: raises :class:`InvalidRayError` naming
    the bad field (a missing or non-finite number, a line of sight that is not a unit vector,
    a non-positive noise, a latitude out of range)."""
    if not isinstance(d, dict):
        raise InvalidRayError(f"ray {d!r} is not an object")
    sysid = d.get("sysid")
    if isinstance(sysid, bool) or not isinstance(sysid, int) or not 1 <= sysid <= 255:
        raise InvalidRayError(f"ray sysid={sysid!r} is not an integer in [1, 255]")
    target = d.get("target")
    if not isinstance(target, str) or not target or "/" in target:
        raise InvalidRayError(f"ray target={target!r} is not a name")
    clock = d.get("clock")
    if clock not in CLOCKS:
        raise InvalidRayError(f"ray clock={clock!r} is not one of {CLOCKS}")
    lat, lon, alt = (_number(d, k) for k in ("lat_deg", "lon_deg", "alt_m"))
    try:
        check_geodetic(lat, lon, alt, "ray")  # type: ignore[arg-type]
    except InvalidSampleError as exc:
        raise InvalidRayError(str(exc)) from None
    los = _vector(d, "los_ned")
    assert los is not None
    n = math.sqrt(sum(c * c for c in los))
    if abs(n - 1.0) > LOS_NORM_TOL:
        raise InvalidRayError(f"ray los_ned={list(los)} is not a unit vector (|los|={n:.6g})")
    sigma = _number(d, "sigma_rad")
    if not 0.0 < sigma < 1.0:  # type: ignore[operator]
        raise InvalidRayError(f"ray sigma_rad={sigma!r} is not in (0, 1) rad")
    rng = _number(d, "range_m", optional=True)
    if rng is not None and rng <= 0.0:
        raise InvalidRayError(f"ray range_m={rng!r} is not positive")
    rstd = _number(d, "range_std_m", optional=True)
    if rstd is not None and rstd <= 0.0:
        raise InvalidRayError(f"ray range_std_m={rstd!r} is not positive")
    return Ray(
        sysid=sysid,
        target=target,
        t_unix_s=_number(d, "t_unix_s"),  # type: ignore[arg-type]
        t_boot_s=_number(d, "t_boot_s"),  # type: ignore[arg-type]
        clock=clock,
        lat_deg=lat,  # type: ignore[arg-type]
        lon_deg=lon,  # type: ignore[arg-type]
        alt_m=alt,  # type: ignore[arg-type]
        los_ned=(los[0] / n, los[1] / n, los[2] / n),
        sigma_rad=sigma,  # type: ignore[arg-type]
        vel_ned_mps=_vector(d, "vel_ned_mps", optional=True),  # type: ignore[arg-type]
        range_m=rng,
        range_std_m=rstd,
        clock_offset_s=_number(d, "clock_offset_s", optional=True),
        sent_unix_s=_number(d, "sent_unix_s", optional=True),
    )


def ray_from_json(text: str | bytes) -> Ray:
    """A :class:`Ray` from a JSON payload; raises :class:`InvalidRayError` on bad JSON."""
    try:
        d = json.loads(text)
    except (ValueError, UnicodeDecodeError) as exc:
        raise InvalidRayError(f"ray payload is not JSON: {exc}") from None
    return ray_from_dict(d)
