"""A fleet: two or three emitted vehicles watching one fixed ground target on the WGS84 earth.

The truth lives on WGS84. An anchor (the emitter's default origin) carries a tangent-plane
NED frame in which the target (40, 30, 0 m) and each vehicle's flight are laid out, each
converted exactly (pymap3d) to latitude, longitude and altitude. Each vehicle ``k`` then
reports as its own ArduPilot would:

* its EKF origin ``O_k`` is its take-off point: the latitude and longitude where it starts,
  at the target's altitude (the ground);
* LOCAL_POSITION_NED is ArduPilot's local frame from ``O_k`` (:func:`ardupilot_local`, the
  exact inverse of :func:`sim.emitter.ardupilot_offset`): GLOBAL_POSITION_INT, placed from it
  by ``ardupilot_offset``, carries the true position (to the message's 1e-7 deg);
* its velocity is the true one in its own NED (at its own position) minus its own velocity
  error (a wind-like bias), so the paper's ``a`` is minus that error;
* its gimbal's line of sight is physical: target minus vehicle in the vehicle's own NED,
  exact through ECEF (so it is *not* the difference of the two reported local positions:
  ArduPilot's sphere stretches north by about 0.3 % at the anchor's latitude);
* it has its own system id, boot clock, noise seed and, optionally, a SYSTEM_TIME Unix time
  that is off (``clock_offsets_s``) and a loss mid-run (``drop``).

Layouts (:data:`FLEETS`, :func:`make_fleet`): ``fleet_hover`` (still, 50 m from the target
horizontally, 20 m up, at azimuths 0, ``separation_deg``, 2 ``separation_deg`` seen from the
target) and ``fleet_moving`` (slow 8 m circles around those points). Outputs: tlogs, the
fleet's truth and one true ray per bearing (:func:`write_tlogs`), or live links
(:func:`run_live`).
"""

from __future__ import annotations

import heapq
import json
import math
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d

from mav_observer.mavlink.dialect import connect
from sim import truth as truth_file
from sim.emitter import (
    LOCATION_SCALING_FACTOR,
    ORIGIN_ALT_M,
    ORIGIN_LAT_DEG,
    ORIGIN_LON_DEG,
    Emission,
    Emitter,
    EmitterConfig,
    TlogWriter,
    _drain,
    ardupilot_offset,
)
from sim.scenarios import Scenario
from sim.vehicle import Vehicle, VehicleState

Geodetic = tuple[float, float, float]

FLEETS = ("fleet_hover", "fleet_moving")
#: Where the target is in the anchor's NED frame (m), as in the single-vehicle emitter.
TARGET_ANCHOR_NED_M = (40.0, 30.0, 0.0)
#: Each vehicle's hover point: this far from the target horizontally and this high above it.
STANDOFF_M, HEIGHT_M = 50.0, 20.0
#: ``fleet_moving``: the circle each vehicle flies around its hover point.
CIRCLE_RADIUS_M, CIRCLE_RATE_RAD_S = 8.0, 0.12
SYSIDS = (1, 2, 3)
BOOT_AT_START_S = (120.0, 157.0, 211.0)
VEL_ERRORS_NED_MPS = ((2.0, -1.0, 0.0), (-1.0, 1.5, 0.0), (0.5, 2.0, 0.0))


def ardupilot_local(origin: Geodetic, point: Geodetic) -> np.ndarray:
    """The point (lat deg, lon deg, alt m) in ArduPilot's local NED frame from ``origin``: the
    exact inverse of :func:`sim.emitter.ardupilot_offset` (1e-7 deg times
    ``LOCATION_SCALING_FACTOR``, east by the cosine of the latitude half-way)."""
    lat0, lon0, alt0 = origin
    dlat_e7 = (point[0] - lat0) * 1e7
    dlon_e7 = math.remainder(point[1] - lon0, 360.0) * 1e7
    scale = max(math.cos(math.radians(lat0 + 0.5e-7 * dlat_e7)), 0.01)
    return np.array(
        [
            dlat_e7 * LOCATION_SCALING_FACTOR,
            dlon_e7 * LOCATION_SCALING_FACTOR * scale,
            alt0 - point[2],
        ]
    )


def ned_to_ecef_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """The rotation whose columns are the north, east and down axes at a geodetic point, in
    ECEF."""
    p, lam = math.radians(lat_deg), math.radians(lon_deg)
    sp, cp, sl, cl = math.sin(p), math.cos(p), math.sin(lam), math.cos(lam)
    return np.array([[-sp * cl, -sl, -cp * cl], [-sp * sl, cl, -cp * sl], [cp, 0.0, -sp]])


def _geodetic(ned: Sequence[float], at: Geodetic) -> Geodetic:
    lat, lon, alt = pymap3d.ned2geodetic(ned[0], ned[1], ned[2], *at)
    return float(lat), float(lon), float(alt)


@dataclass(frozen=True, kw_only=True)
class FleetVehicle(Vehicle):
    """One vehicle of a fleet (see the module docstring). ``scenario`` lays its flight out in
    the anchor's NED frame (target minus vehicle, ``a`` minus its velocity error) and gives
    the attitude through :class:`~sim.vehicle.Vehicle`; :meth:`state` swaps in the exact
    geodesy. ``target_pos0_ned_m`` is the target in the anchor's frame."""

    anchor_geodetic: Geodetic
    origin_geodetic: Geodetic
    target_geodetic: Geodetic

    def geodetic(self, t: float) -> Geodetic:
        """The true position (lat deg, lon deg, alt m) at ``t``."""
        p = np.asarray(self.target_pos0_ned_m, dtype=float) - self.scenario.x(t)
        return _geodetic(p, self.anchor_geodetic)

    def state(self, t: float) -> VehicleState:
        # the base gives the anchor-frame flight and the attitude (the anchor's and the
        # vehicle's NED differ by microradians here, far below the attitude's meaning)
        s = super().state(t)
        here = _geodetic(s.pos_ned_m, self.anchor_geodetic)
        los = np.array(pymap3d.geodetic2ned(*self.target_geodetic, *here), dtype=float)
        turn = ned_to_ecef_rotation(*here[:2]).T @ ned_to_ecef_rotation(*self.anchor_geodetic[:2])
        vel = turn @ s.vel_true_ned_mps
        return replace(
            s,
            pos_ned_m=ardupilot_local(self.origin_geodetic, here),
            vel_true_ned_mps=vel,
            vel_meas_ned_mps=vel - self.scenario.vel_error_mps,
            rel_pos_ned_m=los,
            target_pos_ned_m=ardupilot_local(self.origin_geodetic, self.target_geodetic),
        )


@dataclass(frozen=True)
class FleetMember:
    """One vehicle's emitter and what sets it apart. ``drop_after_s``: it sends nothing from
    then on (simulated seconds; ``None``: never lost)."""

    sysid: int
    emitter: Emitter
    origin_geodetic: Geodetic
    vel_error_ned_mps: tuple[float, float, float]
    clock_offset_s: float = 0.0
    drop_after_s: float | None = None

    @property
    def vehicle(self) -> FleetVehicle:
        v = self.emitter.vehicle
        assert isinstance(v, FleetVehicle)
        return v

    def emissions(self) -> Iterator[Emission]:
        """Its messages in order, up to its drop; the same on every call (a fresh emitter, so
        the noise restarts from the seed)."""
        em = self.emitter
        for e in Emitter(em.scenario, em.config, em.vehicle).emissions():
            if self.drop_after_s is not None and e.t_emit_s >= self.drop_after_s:
                return
            yield e


@dataclass(frozen=True)
class Fleet:
    name: str
    members: tuple[FleetMember, ...]
    anchor_geodetic: Geodetic
    target_geodetic: Geodetic
    target_anchor_ned_m: tuple[float, float, float]
    bearing_noise_deg: float
    duration_s: float

    def member(self, sysid: int) -> FleetMember:
        for m in self.members:
            if m.sysid == sysid:
                return m
        raise KeyError(f"no vehicle with sysid {sysid} in fleet {self.name}")

    def emissions(self) -> Iterator[tuple[FleetMember, Emission]]:
        """Every member's messages merged in time (the members share the true start time)."""

        def tagged(m: FleetMember) -> Iterator[tuple[FleetMember, Emission]]:
            return ((m, e) for e in m.emissions())

        yield from heapq.merge(*(tagged(m) for m in self.members), key=lambda me: me[1].t_emit_s)

    def truth(self) -> dict[str, Any]:
        """The fleet's fixed truth (``fleet_truth.json``)."""
        members = []
        for m in self.members:
            cfg = m.emitter.config
            members.append(
                {
                    "sysid": m.sysid,
                    "origin_geodetic": list(m.origin_geodetic),
                    "vel_error_ned_mps": list(m.vel_error_ned_mps),
                    "bias_ned_mps": [float(v) for v in m.emitter.scenario.a_mps],
                    "target_local_ned_m": [
                        float(v) for v in ardupilot_local(m.origin_geodetic, self.target_geodetic)
                    ],
                    "clock_offset_s": m.clock_offset_s,
                    "boot_at_start_s": cfg.boot_at_start_s,
                    "drop_after_s": m.drop_after_s,
                    "seed": cfg.seed,
                    "tlog": f"vehicle_{m.sysid}.tlog",
                }
            )
        return {
            "fleet": self.name,
            "anchor_geodetic": list(self.anchor_geodetic),
            "target_geodetic": list(self.target_geodetic),
            "target_anchor_ned_m": list(self.target_anchor_ned_m),
            "bearing_noise_deg": self.bearing_noise_deg,
            "duration_s": self.duration_s,
            "t0_unix_s": self.members[0].emitter.config.t0_unix_s,
            "members": members,
        }


def _flight(
    name: str,
    hover_rel_ned_m: np.ndarray,
    radius_m: float,
    phase: float,
    vel_error: np.ndarray,
    duration_s: float,
) -> Scenario:
    """Target minus vehicle in the anchor's frame: ``hover_rel_ned_m`` less a horizontal circle
    of ``radius_m`` at :data:`CIRCLE_RATE_RAD_S` (0: a hover); the target static, ``a`` minus
    the velocity error."""
    om = CIRCLE_RATE_RAD_S

    def x_of_t(t: np.ndarray) -> np.ndarray:
        th = om * t + phase
        circle = np.column_stack((np.cos(th), np.sin(th), np.zeros_like(t)))
        return hover_rel_ned_m - radius_m * circle

    def xdot_of_t(t: np.ndarray) -> np.ndarray:
        th = om * t + phase
        return radius_m * om * np.column_stack((np.sin(th), -np.cos(th), np.zeros_like(t)))

    return Scenario(
        name=name,
        n=3,
        duration_s=duration_s,
        a_mps=-vel_error,
        x_of_t=x_of_t,
        xdot_of_t=xdot_of_t,
        description=f"{name}: target at {hover_rel_ned_m.tolist()} m, circle {radius_m} m",
    )


def make_fleet(
    name: str,
    *,
    vehicles: int = 2,
    seed: int = 0,
    duration_s: float = 30.0,
    bearing_noise_deg: float = 0.5,
    bearing_hz: float = 10.0,
    position_hz: float = 10.0,
    attitude_hz: float = 20.0,
    separation_deg: float = 75.0,
    drop: tuple[int, float] | None = None,
    clock_offsets_s: Mapping[int, float] | None = None,
) -> Fleet:
    """A fleet from :data:`FLEETS` of ``vehicles`` (1 to 3; sysids 1, 2, 3). ``drop=(sysid,
    t_s)``: that vehicle sends nothing from ``t_s`` on. ``clock_offsets_s={sysid: s}``: that
    vehicle's SYSTEM_TIME Unix time is off by ``s``. Member ``k`` (0-based) is seeded
    ``seed * 10 + k``."""
    if name not in FLEETS:
        raise ValueError(f"fleet must be one of {FLEETS}, got {name!r}")
    if vehicles not in (1, 2, 3):
        raise ValueError(f"vehicles must be 1, 2 or 3, got {vehicles}")
    sysids = SYSIDS[:vehicles]
    offsets = dict(clock_offsets_s or {})
    unknown = [s for s in (*offsets, *([drop[0]] if drop else [])) if s not in sysids]
    if unknown:
        raise ValueError(f"no vehicle with sysid {unknown[0]} (the fleet has {list(sysids)})")
    anchor: Geodetic = (ORIGIN_LAT_DEG, ORIGIN_LON_DEG, ORIGIN_ALT_M)
    target_ned = np.asarray(TARGET_ANCHOR_NED_M, dtype=float)
    target = _geodetic(target_ned, anchor)
    radius = CIRCLE_RADIUS_M if name == "fleet_moving" else 0.0
    members = []
    for k, sysid in enumerate(sysids):
        az = math.radians(k * separation_deg)
        # target minus hover point: the vehicle sits at the azimuth seen from the target
        hover_rel = np.array([-STANDOFF_M * math.cos(az), -STANDOFF_M * math.sin(az), HEIGHT_M])
        vel_error = np.asarray(VEL_ERRORS_NED_MPS[k], dtype=float)
        scenario = _flight(name, hover_rel, radius, 2.0 * math.pi * k / 3, vel_error, duration_s)
        start = _geodetic(target_ned - scenario.x(0.0), anchor)
        origin = (start[0], start[1], target[2])  # the take-off point, level with the target
        vehicle = FleetVehicle(
            scenario,
            target_pos0_ned_m=TARGET_ANCHOR_NED_M,
            anchor_geodetic=anchor,
            origin_geodetic=origin,
            target_geodetic=target,
        )
        offset = float(offsets.get(sysid, 0.0))
        config = EmitterConfig(
            bearing="gimbal",
            sysid=sysid,
            duration_s=duration_s,
            attitude_hz=attitude_hz,
            position_hz=position_hz,
            bearing_hz=bearing_hz,
            bearing_noise_deg=bearing_noise_deg,
            boot_at_start_s=BOOT_AT_START_S[k],
            seed=seed * 10 + k,
            origin_geodetic=origin,
            system_time_offset_s=offset,
        )
        members.append(
            FleetMember(
                sysid=sysid,
                emitter=Emitter(scenario, config, vehicle=vehicle),
                origin_geodetic=origin,
                vel_error_ned_mps=VEL_ERRORS_NED_MPS[k],
                clock_offset_s=offset,
                drop_after_s=drop[1] if drop and drop[0] == sysid else None,
            )
        )
    return Fleet(
        name=name,
        members=tuple(members),
        anchor_geodetic=anchor,
        target_geodetic=target,
        target_anchor_ned_m=TARGET_ANCHOR_NED_M,
        bearing_noise_deg=bearing_noise_deg,
        duration_s=duration_s,
    )


def ray(member: FleetMember, truth: Mapping[str, Any]) -> dict[str, Any]:
    """One line of ``fleet_rays_truth.jsonl`` from a bearing's truth record: the vehicle's
    true position, the true unit line of sight in its own NED and the range."""
    rel = np.asarray(truth["rel_pos_ned_m"], dtype=float)
    rng = float(np.linalg.norm(rel))
    lat, lon, alt = ardupilot_offset(*member.origin_geodetic, *truth["vehicle_pos_ned_m"])
    return {
        "t_unix_s": truth["t_unix_s"],
        "sysid": member.sysid,
        "vehicle_geodetic": [float(lat), float(lon), float(alt)],
        "los_ned": [float(v) for v in rel / rng],
        "range_m": rng,
    }


def write_tlogs(fleet: Fleet, directory: Path | str) -> list[Path]:
    """Write ``vehicle_<sysid>.tlog`` (stamped with the common true Unix time) and its
    ``vehicle_<sysid>.truth.jsonl`` (:mod:`sim.truth`) per member, ``fleet_truth.json`` and
    ``fleet_rays_truth.jsonl`` (one true ray per bearing sent) into ``directory``; returns
    the paths written."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    tlogs = {m.sysid: out / f"vehicle_{m.sysid}.tlog" for m in fleet.members}
    truths = {m.sysid: out / f"vehicle_{m.sysid}.truth.jsonl" for m in fleet.members}
    rays_path, fleet_path = out / "fleet_rays_truth.jsonl", out / "fleet_truth.json"
    writers = {s: TlogWriter(p) for s, p in tlogs.items()}
    truth_fhs = {s: open(p, "w", encoding="utf-8") for s, p in truths.items()}  # noqa: SIM115
    try:
        with open(rays_path, "w", encoding="utf-8") as rays:
            for m, e in fleet.emissions():
                writers[m.sysid].write(m.emitter.unix_s(e.t_emit_s), e.frame)
                if e.truth is not None:
                    truth_fhs[m.sysid].write(truth_file.dumps(e.truth) + "\n")
                    rays.write(json.dumps(ray(m, e.truth)) + "\n")
    finally:
        for w in writers.values():
            w.close()
        for fh in truth_fhs.values():
            fh.close()
    fleet_path.write_text(json.dumps(fleet.truth(), indent=2) + "\n", encoding="utf-8")
    return [*tlogs.values(), *truths.values(), fleet_path, rays_path]


def run_live(
    fleet: Fleet, to: Sequence[str], *, speed: float | None = 1.0, stop: Any = None
) -> None:
    """Send every member's messages, merged in time, each to its own pymavlink output
    (``to[i]`` for the i-th member, e.g. ``udpout:127.0.0.1:14551``). ``speed``: 1 real time,
    ``None`` or 0 as fast as possible; ``stop``: an object with ``is_set()`` to end early."""
    if len(to) != len(fleet.members):
        raise ValueError(f"{len(fleet.members)} vehicles need as many outputs, got {len(to)}")
    conns: dict[int, Any] = {}
    try:
        for m, url in zip(fleet.members, to, strict=True):
            conns[m.sysid] = connect(url, source_system=m.sysid)
        wall0 = time.monotonic()
        poll_at = 0.0
        for m, e in fleet.emissions():
            if stop is not None and stop.is_set():
                break
            if speed:
                delay = wall0 + e.t_emit_s / speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            now = time.monotonic()
            if now >= poll_at:  # a server link (udpin, tcpin) learns its peers in recv()
                for c in conns.values():
                    _drain(c)
                poll_at = now + 0.05
            conns[m.sysid].write(e.frame)
    finally:
        for c in conns.values():
            c.close()


__all__ = [
    "FLEETS",
    "Fleet",
    "FleetMember",
    "FleetVehicle",
    "ardupilot_local",
    "make_fleet",
    "ned_to_ecef_rotation",
    "run_live",
    "write_tlogs",
]
