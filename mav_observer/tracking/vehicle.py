"""What the tracker keeps per vehicle (clocks, attitude, positions, cameras, origin, targets),
and a message's time on the vehicle's autopilot clock (:mod:`~mav_observer.tracking.clocks`)."""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mav_observer.core.drift import PositionDrift
from mav_observer.core.targets import Targets
from mav_observer.geo import geodesy
from mav_observer.geo.frames import Vec3
from mav_observer.geo.geodesy import Origin
from mav_observer.geo.gimbal_frame import GimbalFrameDetector
from mav_observer.tracking.attitude import AttitudeHistory
from mav_observer.tracking.clocks import ClockMap
from mav_observer.tracking.directions import Skip

#: LOCAL_POSITION_NED positions kept to interpolate the vehicle's position at a committed
#: estimate's time.
POSITION_HISTORY = 32
#: A component whose clock offset (arrival - time_boot_ms) is within this of the autopilot's
#: is on the autopilot's clock (s): its time_boot_ms is used as it is.
SAME_CLOCK_TOL_S = 0.05


@dataclass
class WaitingBearing:
    """A bearing message waiting for the vehicle attitude of its time."""

    t_boot_s: float
    t_arrival_s: float
    msg: Any
    stage: Callable[..., None]
    needs_attitude: bool


@dataclass
class Vehicle:
    sysid: int
    #: the observers of this vehicle's targets (:mod:`mav_observer.core.targets`)
    targets: Targets
    clocks: dict[Any, ClockMap] = field(default_factory=dict)
    autopilot_compid: int | None = None
    attitude: AttitudeHistory = field(default_factory=AttitudeHistory)
    position: tuple[float, Vec3, Vec3] | None = None  # t, pos, vel (NED)
    #: the latest LOCAL_POSITION_NED ``(t, pos, vel)``, for the vehicle's position at a
    #: committed estimate's time (``publish = "committed"``)
    positions: deque[tuple[float, Vec3, Vec3]] = field(
        default_factory=lambda: deque(maxlen=POSITION_HISTORY)
    )
    #: per target, ``(t_boot_s, t_arrival_s)`` of the bearings whose committed estimate has
    #: not been published yet (``publish = "committed"``)
    arrivals: dict[str, deque[tuple[float, float]]] = field(default_factory=dict)
    velocity: tuple[float, list[float]] | None = None  # latest (t, v) on the autopilot clock
    #: latest gimbal or mount attitude: ``(t, R_ned_cam)``, or ``(t, (q, flags, yaw,
    #: delta_yaw))`` from a gimbal, turned into the matrix only when a tracked point needs it
    camera_attitude: tuple[float, Any] | None = None
    fov: dict[int, tuple[float, float]] = field(default_factory=dict)
    #: the latest range from a rangefinder on the gimbal not fused yet: ``(t, m, std m)``
    gimbal_range: tuple[float, float, float] | None = None
    home: Vec3 | None = None
    #: messages of this vehicle skipped, by reason (the tracker's ``skipped`` sums all)
    skipped: Counter[str] = field(default_factory=Counter)
    #: the latest time_boot_ms per (message type, component): a repeat is a duplicate
    last_time_ms: dict[tuple[str, int], int] = field(default_factory=dict)
    #: bearing messages waiting for the attitude of their time, in arrival order
    waiting: deque[WaitingBearing] = field(default_factory=deque)
    #: components found to be on the autopilot's clock
    same_clock: set[Any] = field(default_factory=set)
    #: the latest autopilot time seen (s) and its arrival time (s)
    latest_boot: tuple[float, float] | None = None
    #: the drift between LOCAL_POSITION_NED's positions and integrated velocity
    #: (:mod:`mav_observer.core.drift`)
    drift: PositionDrift = field(default_factory=PositionDrift)
    #: the local frame's origin on WGS84 (:mod:`mav_observer.geo.geodesy`), once known
    origin: Origin | None = None
    #: SYSTEM_TIME's Unix time minus its time_boot_ms (s), when the autopilot knows the time
    unix_minus_boot_s: float | None = None
    #: the mean over GLOBAL_POSITION_INT's pairs while they place the origin
    origin_mean: geodesy.OriginMean | None = None
    #: what placed the origin: (source, lat deg, lon deg, alt m, the point's local NED m)
    origin_fix: tuple[str, float, float, float, Vec3] | None = None
    #: the autopilot's local frame as its pairs told it (``None``: not yet told)
    local_frame: str | None = None
    #: the pairs' vote on it while it is not told (``local_frame = "auto"``)
    frame_vote: geodesy.FrameVote | None = None
    #: the latest LOCAL_POSITION_NED's time_boot_ms and position, and the latest
    #: GLOBAL_POSITION_INT's time_boot_ms and (lat deg, lon deg, alt m): a pair at the same
    #: time_boot_ms places the origin when nothing better has
    lpn_ms: tuple[int, Vec3] | None = None
    gpi_ms: tuple[int, tuple[float, float, float]] | None = None
    #: per gimbal device id, what the data say its angles are relative to
    #: (``gimbal_angles = "auto"``)
    gimbal_frames: dict[int, GimbalFrameDetector] = field(default_factory=dict)


def gimbal_target(device: int) -> str:
    """The target a gimbal device's bearings go to: ``gimbal`` for device 1 (or 0, no id),
    ``gimbalN`` for device N (a second gimbal keeps its own estimate)."""
    return "gimbal" if device <= 1 else f"gimbal{device}"


def gimbal_device(target: str) -> int | None:
    """The gimbal device id of a target named after it (:func:`gimbal_target`'s inverse),
    or ``None`` for another target."""
    if target == "gimbal":
        return 1
    if target.startswith("gimbal") and target[6:].isdigit():
        return int(target[6:])
    return None


def autopilot_time(
veh: Vehicle, key: Any, boot_s: float, arrival: float,
note: Callable[[Vehicle, str], None], reboot: Callable[[Vehicle, str], None],
) -> float:  # fmt: skip
    """Boot time of a timed message from clock ``key`` moved onto the autopilot clock;
    ``reboot`` resets the vehicle when its autopilot's clock restarts, ``note`` counts an
    event."""
    if not math.isfinite(boot_s):
        raise Skip("non_finite", "time")
    clock = veh.clocks.get(key)
    if clock is None:
        clock = veh.clocks[key] = ClockMap()
    event = clock.update(boot_s, arrival)
    if event in ("out_of_order", "clock_unconfirmed", "time_jump"):
        raise Skip(event, f"clock {key}: time_boot_ms {boot_s:.3f} s refused ({event})")
    is_autopilot = key == veh.autopilot_compid
    if event == "clock_jump" and 0.0 < clock.jump_s <= clock.gap_max_s:
        # the same clock after a telemetry gap (a sped-up simulator's recorder stalled): the
        # observers predict across it
        note(veh, f"clock_gap_{key}" if not is_autopilot else "autopilot_clock_gap")
        event = None
    if event in ("reboot", "clock_jump"):
        if is_autopilot:
            reboot(veh, event)
            veh.clocks[key] = clock  # keep the restarted mapping
        else:
            note(veh, f"clock_restart_{key}")
            veh.same_clock.discard(key)
    if is_autopilot:
        lb = veh.latest_boot
        if lb is None or boot_s >= lb[0]:
            veh.latest_boot = (boot_s, arrival)
        return boot_s
    if key in veh.same_clock:
        return boot_s
    ap = veh.clocks.get(veh.autopilot_compid)
    if ap is None or ap.offset_s is None:
        raise Skip("no_time_base", "no autopilot clock yet")
    if abs(clock.offset_s - ap.offset_s) <= SAME_CLOCK_TOL_S:  # type: ignore[operator]
        # its time_boot_ms agrees with the autopilot's (ArduPilot stamps its own gimbal
        # messages so; a companion synchronised by MAVLink's TIMESYNC): use it as it is,
        # from now on, so that the tlog's timestamp jitter and jumps cannot move it
        veh.same_clock.add(key)
        note(veh, "component_on_autopilot_clock")
        return boot_s
    return ap.to_boot(clock.to_arrival(boot_s))


def arrival_on_autopilot_clock(veh: Vehicle, arrival: float) -> float:
    """A message with no time field: its arrival time on the autopilot clock, through
    the autopilot clock's latency-free offset; where that disagrees by more than 0.5 s
    with the time since the latest autopilot message (the arrival clock jumped: a tlog
    written across a clock change), from the latest autopilot message instead."""
    ap = veh.clocks.get(veh.autopilot_compid)
    if ap is None or ap.offset_s is None or veh.latest_boot is None:
        raise Skip("no_time_base", "no autopilot clock yet")
    tb = ap.to_boot(arrival)
    boot_l, arr_l = veh.latest_boot
    since = arrival - arr_l
    if abs(tb - (boot_l + since)) <= 0.5:
        return tb
    if -0.5 <= since <= 2.0:
        return boot_l + max(since, 0.0)
    raise Skip("time_jump", f"arrival {arrival:.3f} s is {since:.1f} s from the autopilot's")
