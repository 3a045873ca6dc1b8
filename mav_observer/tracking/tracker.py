"""Route MAVLink messages to one observer per vehicle (sysid) and target.

:class:`Tracker` takes decoded messages with their arrival (or tlog) time, keeps for each
vehicle its clocks (:mod:`~mav_observer.tracking.clocks`), a short attitude history, its
latest position and velocity and its cameras' fields of view, turns bearing messages into
:class:`~mav_observer.core.samples.BearingSample` through the frame chains of
:mod:`~mav_observer.tracking.directions`, and returns an
:class:`~mav_observer.outputs.records.EstimateRecord` for each bearing the observers accept.
A message that cannot be used is counted by reason and skipped; nothing already received is lost.

Roles: this module routes each message to its handler and publishes the records (bearing
readers: ``bearings``; per-vehicle state and clocks: ``vehicle``; origin: ``origin``; rays:
``rays``; drift and published bias: ``core.drift``; observers: ``core.targets``). Replay and
the service run the same loop body, :meth:`Tracker.handle` (``(t, message) -> records``).

Targets and the messages that feed them (``sources``):

==================  =============================================  ====================
source              message                                        target name
==================  =============================================  ====================
``gimbal``          GIMBAL_DEVICE_ATTITUDE_STATUS (boresight)      ``gimbal`` or ``gimbalN``
``camera``          CAMERA_TRACKING_IMAGE_STATUS + gimbal or mount ``camera``
``mount``           MOUNT_ORIENTATION                              ``mount``
``mount_status``    MOUNT_STATUS (ArduPilot)                       ``mount_status``
``landing_target``  LANDING_TARGET                                 ``landing_target_<target_num>``
``home``            synthetic: HOME_POSITION - LOCAL_POSITION_NED  ``home`` (validation only)
==================  =============================================  ====================

``auto`` enables every source but ``home``: each one the stream carries gets its observer.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from mav_observer.core.drift import position_at
from mav_observer.core.observer import BiasObserver
from mav_observer.core.targets import Targets
from mav_observer.errors import InvalidSampleError, MavObserverError
from mav_observer.geo.frames import Vec3, euler_from_dcm, quat_to_dcm
from mav_observer.mavlink import signing
from mav_observer.mavlink.dialect import MSG_ID, type_key
from mav_observer.outputs.records import EstimateRecord
from mav_observer.tracking import directions as adapters
from mav_observer.tracking.bearings import GIMBAL_SOURCES, POSITION_MAX_AGE_S, BearingReaders
from mav_observer.tracking.config import AUTO_SOURCES, PUBLISH, SOURCES, TrackerConfig
from mav_observer.tracking.directions import Skip
from mav_observer.tracking.origin import pair_global_local, place_origin
from mav_observer.tracking.persistence import SavedObservers
from mav_observer.tracking.rays import ray_of
from mav_observer.tracking.vehicle import (
    Vehicle,
    WaitingBearing,
    arrival_on_autopilot_clock,
    autopilot_time,
)

if TYPE_CHECKING:  # (the smoother's sample log is made by a replay that smooths)
    from mav_observer.core.smoother import SampleLog
    from mav_observer.fleet.rays import Ray

log = logging.getLogger(__name__)

__all__ = ["AUTO_SOURCES", "PUBLISH", "SOURCES", "Tracker", "TrackerConfig"]

MAV_AUTOPILOT_INVALID = 8
#: Bearings' arrival times kept per target until their committed estimate is published.
MAX_PENDING_ARRIVALS = 4096
#: LOCAL_POSITION_NED beyond these is nonsense, refused as ``out_of_range``: a speed no
#: aircraft we serve reaches (m/s, per axis) and a local position farther than any flight from
#: its origin (m).
MAX_SPEED_MPS = 300.0
MAX_LOCAL_POSITION_M = 1.0e6
#: Bearings waiting for the vehicle attitude of their own time, per vehicle, at the most.
MAX_WAITING = 64


class _Deferred(Exception):
    """Raised by a handler whose message waits for the attitude of its time."""


class Tracker(BearingReaders, SavedObservers):
    """Turns ``(t_arrival_s, message)`` pairs into estimate records (module docstring);
    ``t_arrival_s`` is the tlog timestamp on replay, the receive time live (Unix seconds)."""

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.enabled = self.config.enabled()
        self._sensor = adapters.landing_target_sensor(
            self.config.landing_target_orientation, self.config.landing_target_yaw_align_deg
        )
        self.vehicles: dict[int, Vehicle] = {}
        #: gimbal readings decided from the data before a restart, by (sysid, device id)
        self._saved_angles: dict[tuple[int, int], str] = {}
        self.received: Counter[str] = Counter()
        self.used: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()
        self.events: Counter[str] = Counter()
        #: ``(t_boot_s, sysid, event)`` of the latest events (resets, clock changes, ...)
        self.event_log: deque[tuple[float, int, str]] = deque(maxlen=10_000)
        #: when set, every velocity and bearing used is kept there (replay --smooth), and
        #: every bearing used as a geodetic ray (:mod:`~mav_observer.tracking.rays`)
        self.sample_log: SampleLog | None = None
        self.rays: list[Ray] | None = None
        self._warned: Counter[str] = Counter()  # log rate limiting
        #: saved observers waiting for their vehicle's first position (see :meth:`restore`)
        self._pending: dict[int, list[dict[str, Any]]] = {}
        #: estimates committed when their vehicle was reset, published with the message's
        self._orphans: list[EstimateRecord] = []
        self._handlers: dict[str, Callable[[Vehicle, float, Any, list[EstimateRecord]], None]] = {
            "LOCAL_POSITION_NED": self._on_local_position,
            "ATTITUDE": self._on_attitude,
            "ATTITUDE_QUATERNION": self._on_attitude_quaternion,
            "GIMBAL_DEVICE_ATTITUDE_STATUS": self._on_gimbal,
            "CAMERA_TRACKING_IMAGE_STATUS": self._on_camera_tracking,
            "CAMERA_FOV_STATUS": self._on_camera_fov,
            "CAMERA_INFORMATION": self._on_camera_information,
            "MOUNT_ORIENTATION": self._on_mount_orientation,
            "MOUNT_STATUS": self._on_mount_status,
            "LANDING_TARGET": self._on_landing_target,
            "DISTANCE_SENSOR": self._on_distance_sensor,
            "HOME_POSITION": self._on_home,
            "GPS_GLOBAL_ORIGIN": self._on_gps_global_origin,
            "GLOBAL_POSITION_INT": self._on_global_position,
            "SYSTEM_TIME": self._on_system_time,
            "HEARTBEAT": self._on_heartbeat,
        }

    # -- entry point ----------------------------------------------------------------
    def handle(self, t_arrival_s: float, msg: Any) -> list[EstimateRecord]:
        """Process one decoded message; returns the estimates it produced (often none)."""
        mtype = type_key(msg)
        self.received[mtype] += 1
        handler = self._handlers.get(mtype)
        if handler is None:
            if mtype == "BAD_DATA":
                self.skipped[signing.rejection_reason(msg) or "bad_data"] += 1
            return []
        sysid = msg.get_srcSystem()
        if self.config.sysids is not None and sysid not in self.config.sysids:
            self.skipped["foreign_sysid"] += 1
            return []
        veh = self.vehicles.get(sysid)
        if veh is None:
            veh = self.vehicles[sysid] = Vehicle(sysid, self._new_targets())
        out: list[EstimateRecord] = []
        stamp = getattr(msg, "time_boot_ms", None)
        if stamp is not None:
            key = (mtype, msg.get_srcComponent())
            if veh.last_time_ms.get(key) == stamp:
                dup = Skip("duplicate", f"{mtype} time_boot_ms {stamp} again")
                self._count_skip(veh, mtype, dup)
                return out
            veh.last_time_ms[key] = stamp
        self._guarded(veh, mtype, handler, t_arrival_s, msg, out)
        if self._orphans:  # committed before a reset of their vehicle: earlier than ``out``
            out[:0] = self._orphans
            self._orphans = []
        if veh.waiting:
            self._release(veh, t_arrival_s, out)
        return out

    def flush(self) -> list[EstimateRecord]:
        """Process the bearings still waiting for an attitude (the end of a replay), with
        the attitude extrapolated, and (``publish = "committed"``) commit the bearings still
        waiting for a velocity after them; returns their estimates."""
        out: list[EstimateRecord] = []
        for veh in self.vehicles.values():
            while veh.waiting:
                self._release(veh, math.inf, out)
            if veh.targets.committed:
                self._publish_committed(veh, out, end=True)
        return out

    def _new_targets(self) -> Targets:
        return Targets(self.config.observer, committed=self.config.publish == "committed")

    def _guarded(
        self,
        veh: Vehicle,
        mtype: str,
        fn: Callable[..., None],
        *args: Any,
    ) -> None:
        """Run a handler (or a waiting bearing's second stage) on ``veh``: a message that
        cannot be used is counted by reason, never raised; one that waits counts nothing."""
        try:
            fn(veh, *args)
        except _Deferred:
            return
        except Skip as s:
            self._count_skip(veh, mtype, s)
        except MavObserverError as exc:
            self.skipped["invalid"] += 1
            veh.skipped["invalid"] += 1
            log.debug("vehicle %d: %s refused: %s", veh.sysid, mtype, exc)
        except (AttributeError, TypeError, ValueError, ArithmeticError) as exc:
            # a message missing a field or carrying nonsense the checks did not foresee
            self.skipped["malformed"] += 1
            veh.skipped["malformed"] += 1
            key = f"malformed {mtype} {type(exc).__name__}"
            self._warned[key] += 1
            if self._warned[key] in (1, 10, 100) or self._warned[key] % 1000 == 0:
                log.warning(
                    "vehicle %d: malformed %s skipped (%d so far): %r",
                    veh.sysid,
                    mtype,
                    self._warned[key],
                    exc,
                )
        else:
            self.used[mtype] += 1

    def _note(self, veh: Vehicle, event: str) -> None:
        """Count an event and log when it happened (the vehicle's latest autopilot time)."""
        self.events[event] += 1
        t = veh.latest_boot[0] if veh.latest_boot is not None else math.nan
        self.event_log.append((t, veh.sysid, event))

    def _count_skip(self, veh: Vehicle, mtype: str, s: Skip) -> None:
        self.skipped[s.reason] += 1
        veh.skipped[s.reason] += 1
        n = veh.skipped[s.reason]
        if n in (1, 10, 100) or n % 10_000 == 0:
            log.info("vehicle %d: %s skipped as %s (%d so far): %s",
                     veh.sysid, mtype, s.reason, n, s)  # fmt: skip

    # -- bearings that wait for the attitude of their time ----------------------------
    def _when_attitude(
        self,
        veh: Vehicle,
        tb: float,
        t_arrival: float,
        msg: Any,
        out: list[EstimateRecord],
        stage: Callable[..., None],
        needs_attitude: bool,
    ) -> None:
        """Run ``stage(veh, tb, t_arrival, msg, out)`` now, or queue it until the vehicle
        attitude at ``tb`` is known (the ATTITUDE of that time has arrived): a bearing from a
        gimbal or camera that is its own component often arrives first. Bearings keep their
        order: one that needs no attitude waits behind those that do."""
        if veh.waiting or (needs_attitude and self._attitude_ahead(veh, tb)):
            if len(veh.waiting) >= MAX_WAITING:
                self._release(veh, math.inf, out, at_most=1)
            veh.waiting.append(WaitingBearing(tb, t_arrival, msg, stage, needs_attitude))
            raise _Deferred
        stage(veh, tb, t_arrival, msg, out)

    def _attitude_ahead(self, veh: Vehicle, tb: float) -> bool:
        """True if a bearing at ``tb`` should wait: the attitude stream exists and has not
        reached ``tb`` yet."""
        h = veh.attitude
        latest = h.latest_t_s
        if self.config.attitude_wait_s <= 0.0 or latest is None or latest >= tb:
            return False
        ahead = tb - latest
        dense = 0.0 < h.interval_s <= 0.05 and h.has_rates
        return not (dense and ahead <= self.config.attitude_extrapolate_s)

    def release_due(self, t_arrival_s: float) -> list[EstimateRecord]:
        """Run the bearings that have waited for their attitude long enough by now
        (``t_arrival_s``, the receive clock), extrapolated: live, a stream that pauses must
        not hold its last bearings until the next message. Returns their estimates."""
        out: list[EstimateRecord] = []
        for veh in self.vehicles.values():
            if veh.waiting:
                self._release(veh, t_arrival_s, out)
        return out

    def _release(
        self, veh: Vehicle, t_arrival: float, out: list[EstimateRecord], at_most: int = 0
    ) -> None:
        """Run the waiting bearings whose attitude has arrived, or that have waited
        ``attitude_wait_s`` (arrival time) or whose time the autopilot's clock has passed by
        that much (then extrapolated); ``at_most`` > 0: release that many whatever."""
        # a sparse attitude stream (1 Hz on an old telemetry link) is waited for longer:
        # 1.5 of its intervals, up to 2 s
        wait = self.config.attitude_wait_s
        if wait > 0.0:
            wait = max(wait, min(2.0, 1.5 * veh.attitude.interval_s))
        latest = veh.attitude.latest_t_s
        ap = veh.latest_boot[0] if veh.latest_boot is not None else -math.inf
        done = 0
        while veh.waiting:
            w = veh.waiting[0]
            ready = not w.needs_attitude or latest is None or latest >= w.t_boot_s
            forced = at_most > 0 and done < at_most
            if not ready and not forced:
                timed_out = t_arrival - w.t_arrival_s > wait or ap - w.t_boot_s > wait
                if not timed_out:
                    return
            veh.waiting.popleft()
            done += 1
            if not ready:
                self._note(veh, "attitude_extrapolated")
            self._guarded(veh, type_key(w.msg), w.stage, w.t_boot_s, w.t_arrival_s, w.msg, out)
            if at_most and done >= at_most:
                return

    # -- time -------------------------------------------------------------------------
    def _timed(self, veh: Vehicle, key: Any, boot_s: float, arrival: float) -> float:
        """Boot time of a timed message from clock ``key`` moved onto the autopilot clock."""
        return autopilot_time(veh, key, boot_s, arrival, self._note, self._reboot)

    def _untimed(self, veh: Vehicle, arrival: float) -> float:
        """A message with no time field: its arrival moved onto the autopilot clock."""
        return arrival_on_autopilot_clock(veh, arrival)

    def _claim_autopilot(self, veh: Vehicle, compid: int) -> None:
        if veh.autopilot_compid is None:
            veh.autopilot_compid = compid

    def _reboot(self, veh: Vehicle, event: str = "reboot") -> None:
        """Reset a vehicle whose autopilot clock restarted: ``event`` is the clock's
        ``"reboot"`` (it went back) or ``"clock_jump"`` (it jumped ahead)."""
        how = "went back: reboot" if event == "reboot" else "jumped ahead"
        log.warning(
            "vehicle %d: autopilot clock %s, resetting its %d observer(s)",
            veh.sysid,
            how,
            len(veh.targets),
        )
        self._note(veh, f"autopilot_{event}")
        if veh.targets.committed:  # what the old observers had not published yet
            self._publish_committed(veh, self._orphans, end=True)
        if self.sample_log is not None:
            self.sample_log.new_epoch(veh.sysid)
        keep = veh.autopilot_compid
        fresh = Vehicle(veh.sysid, self._new_targets(), autopilot_compid=keep, skipped=veh.skipped,
                         local_frame=veh.local_frame)  # fmt: skip
        if self._pending.pop(veh.sysid, None):
            log.warning("vehicle %d: saved observers discarded (autopilot rebooted)", veh.sysid)
        veh.__dict__.update(fresh.__dict__)

    # -- vehicle state ----------------------------------------------------------------
    def _on_heartbeat(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        if msg.autopilot != MAV_AUTOPILOT_INVALID:
            self._claim_autopilot(veh, msg.get_srcComponent())

    def _on_system_time(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        comp = msg.get_srcComponent()
        if comp == veh.autopilot_compid:
            self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
            if msg.time_unix_usec > 0:  # 0: the autopilot has no GNSS time yet
                veh.unix_minus_boot_s = msg.time_unix_usec * 1e-6 - msg.time_boot_ms * 1e-3

    def _on_local_position(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        comp = msg.get_srcComponent()
        self._claim_autopilot(veh, comp)
        pos = (msg.x, msg.y, msg.z)
        vel = (msg.vx, msg.vy, msg.vz)
        if not all(math.isfinite(v) for v in (*pos, *vel)):
            raise Skip("non_finite", "LOCAL_POSITION_NED")
        if max(map(abs, vel)) > MAX_SPEED_MPS or max(map(abs, pos)) > MAX_LOCAL_POSITION_M:
            raise Skip("out_of_range", f"LOCAL_POSITION_NED position {pos} velocity {vel}")
        tb = self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
        if veh.position is not None and tb < veh.position[0]:
            raise Skip("out_of_order", f"LOCAL_POSITION_NED at {tb:.3f} s after a later one")
        mean_v = self._interval_mean_velocity(veh, tb, pos, vel)
        veh.position = (tb, pos, vel)
        veh.positions.append((tb, pos, vel))
        veh.lpn_ms = (msg.time_boot_ms, pos)
        if veh.gpi_ms is not None and veh.gpi_ms[0] == msg.time_boot_ms:
            pair_global_local(veh, self.config.local_frame, self._note)
        if self.sample_log is not None:
            self.sample_log.local_position(veh.sysid, tb, pos, vel)
        v = [-vel[0], -vel[1], -vel[2]]  # the paper's v = -u (checked finite above)
        veh.velocity = (tb, v)
        if veh.sysid in self._pending:
            self._resume_saved(veh, self._pending.pop(veh.sysid))
        for exc in veh.targets.velocity(tb, v, mean_v):
            self.skipped["refused_velocity"] += 1
            veh.skipped["refused_velocity"] += 1
            log.debug("vehicle %d: velocity refused: %s", veh.sysid, exc)
        if veh.targets.committed:
            self._publish_committed(veh, out)
        if "home" in self.enabled and veh.home is not None:
            h = veh.home
            self._bearing(
                veh,
                "home",
                "HOME_POSITION",
                tb,
                t,
                (h[0] - pos[0], h[1] - pos[1], h[2] - pos[2]),
                out,
            )

    def _interval_mean_velocity(
        self, veh: Vehicle, tb: float, pos: Vec3, vel: Vec3
    ) -> list[float] | None:
        """The mean of the paper's ``v`` since the previous LOCAL_POSITION_NED, from the
        change of its position (:meth:`~mav_observer.core.drift.PositionDrift.interval`), or
        ``None``: the velocity samples are interpolated; a position jump is counted as
        ``position_reset``."""
        prev = veh.position
        if prev is None:
            return None
        mean, reset = veh.drift.interval(*prev, tb, pos, vel)
        if reset:
            self._note(veh, "position_reset")
        return mean

    def _on_attitude(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        comp = msg.get_srcComponent()
        self._claim_autopilot(veh, comp)
        adapters.check_attitude(msg.roll, msg.pitch, msg.yaw)
        tb = self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
        rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
        veh.attitude.add(tb, msg.roll, msg.pitch, msg.yaw, rates)

    def _on_attitude_quaternion(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        comp = msg.get_srcComponent()
        self._claim_autopilot(veh, comp)
        q = adapters.check_quaternion((msg.q1, msg.q2, msg.q3, msg.q4))
        tb = self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
        rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
        veh.attitude.add(tb, *euler_from_dcm(quat_to_dcm(q)), rates)

    def _vehicle_attitude(self, veh: Vehicle, tb: float) -> tuple[float, float, float] | None:
        return veh.attitude.at(tb, self.config.max_attitude_age_s)

    def _on_home(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        home = (msg.x, msg.y, msg.z)
        if not all(math.isfinite(v) for v in home):
            raise Skip("non_finite", "HOME_POSITION")
        veh.home = home
        if msg.latitude or msg.longitude:  # 0, 0: no home yet
            place_origin(
                veh, "HOME_POSITION", msg.latitude * 1e-7, msg.longitude * 1e-7,
                msg.altitude * 1e-3, home, self.config.local_frame, self._note,
            )  # fmt: skip

    def _on_gps_global_origin(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        place_origin(
            veh, "GPS_GLOBAL_ORIGIN", msg.latitude * 1e-7, msg.longitude * 1e-7,
            msg.altitude * 1e-3, (0.0, 0.0, 0.0), self.config.local_frame, self._note,
        )  # fmt: skip

    def _on_global_position(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        if not (msg.lat or msg.lon):  # 0, 0: no fix
            return
        veh.gpi_ms = (msg.time_boot_ms, (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3))
        pair_global_local(veh, self.config.local_frame, self._note)

    # -- the observers ----------------------------------------------------------------
    def _bearing(
        self,
        veh: Vehicle,
        target: str,
        source: str,
        tb: float,
        t_arrival: float,
        direction: Vec3,
        out: list[EstimateRecord],
        range_m: float | None = None,
    ) -> None:
        n2 = direction[0] ** 2 + direction[1] ** 2 + direction[2] ** 2
        if not math.isfinite(tb) or not math.isfinite(n2):
            raise Skip("non_finite", f"bearing {direction} at {tb}")
        if n2 <= 0.0:
            raise Skip("zero_length", f"bearing {direction}")
        inv = 1.0 / math.sqrt(n2)
        y = [direction[0] * inv, direction[1] * inv, direction[2] * inv]
        range_std = self.config.range_noise_m
        if range_m is None and source in GIMBAL_SOURCES and veh.gimbal_range is not None:
            t_r, r, sd = veh.gimbal_range
            if abs(t_r - tb) <= self.config.max_range_age_s:  # each range fused once
                range_m, range_std, veh.gimbal_range = r, sd, None
        obs = veh.targets.get(target)
        reacq = 0 if obs is None else obs.reacquisitions
        try:
            est, new = veh.targets.bearing(target, source, tb, y, veh.velocity, range_m, range_std)
        except InvalidSampleError as exc:
            raise Skip("refused_bearing", str(exc)) from exc
        if obs is None:  # a new target: its observer now exists
            obs = veh.targets.get(target)
        if obs is not None and obs.reacquisitions > reacq:
            # the bearings stopped agreeing with the estimate (the target moved, the tracker
            # locked onto something else): the estimate starts again from the Riccati observer
            self._note(veh, "reacquired")
            log.warning(
                "vehicle %d: target %r re-acquired at %.3f s: the bearings stopped agreeing "
                "with its estimate",
                veh.sysid,
                target,
                tb,
            )
        if self.sample_log is not None:
            self.sample_log.bearing(veh.sysid, target, tb, y)
        if self.rays is not None and obs is not None and obs.started:
            ray_of(self.rays, veh, target, (tb, t_arrival), y, obs.bearing_noise_var(), range_m,
                   range_std)  # fmt: skip
        if new:
            self.events["targets"] += 1
            log.info("vehicle %d: bearing source found: %s -> target %r", veh.sysid, source, target)
        if veh.targets.committed:
            pending = veh.arrivals.get(target)
            if pending is None:
                pending = veh.arrivals[target] = deque(maxlen=MAX_PENDING_ARRIVALS)
            pending.append((tb, t_arrival))
            if obs is None or not obs.started:  # no velocity yet: nothing to report yet
                self.events["estimates_withheld_no_velocity"] += 1
            self._publish_committed(veh, out)
            return
        if est is None:  # no velocity yet: the bearing waits, nothing to report
            self.events["estimates_withheld_no_velocity"] += 1
            return
        vpos = position_at(veh.position, obs, est, tb, POSITION_MAX_AGE_S)
        est = veh.drift.published(est)
        out.append(EstimateRecord(t_arrival, tb, veh.sysid, target, source, est, vpos, veh.origin))

    def _publish_committed(
        self, veh: Vehicle, out: list[EstimateRecord], *, end: bool = False
    ) -> None:
        """Records of the estimates committed since the last call (``publish =
        "committed"``), each with its bearing's arrival time and the vehicle's position at
        its time: the LOCAL_POSITION_NED at or before it moved on the way the estimate was
        (by the velocity the observer integrated there, known on both sides)."""
        for target, source, est in veh.targets.take_committed(end=end):
            tb = est.t_s
            # its bearing's arrival (else, a bearing not on record, the latest message's)
            t_arr = veh.latest_boot[1] if veh.latest_boot is not None else math.nan
            pending = veh.arrivals.get(target)
            while pending and pending[0][0] < tb:
                pending.popleft()
            if pending and pending[0][0] == tb:
                t_arr = pending.popleft()[1]
            fix = next((f for f in reversed(veh.positions) if f[0] <= tb), None)
            fix = fix if fix is not None else veh.position
            vpos = position_at(fix, veh.targets.get(target), est, tb, POSITION_MAX_AGE_S)
            pub = veh.drift.published(est)
            out.append(EstimateRecord(t_arr, tb, veh.sysid, target, source, pub, vpos, veh.origin))

    def vehicle_attitude(self, sysid: int, t_boot_s: float) -> tuple[float, float, float] | None:
        """Vehicle ``sysid``'s roll, pitch, yaw (rad) at ``t_boot_s`` (its autopilot clock),
        interpolated as for the bearings, or ``None`` when unknown there."""
        veh = self.vehicles.get(sysid)
        return None if veh is None else self._vehicle_attitude(veh, t_boot_s)

    def origin(self, sysid: int) -> dict[str, float | str] | None:
        """The local frame's origin of vehicle ``sysid`` on WGS84 (latitude and longitude
        deg, altitude m AMSL, the message it came from), or ``None`` while unknown."""
        veh = self.vehicles.get(sysid)
        return None if veh is None or veh.origin is None else veh.origin.to_dict()

    def redundant_message_ids(self) -> frozenset[int]:
        """Ids that need no decoding any more: ATTITUDE_QUATERNION once ATTITUDE is arriving
        (both give the vehicle attitude); GLOBAL_POSITION_INT once every vehicle's origin
        comes from a more trusted source (it can no longer move it) and its local frame is
        told (:class:`~mav_observer.geo.geodesy.FrameVote`)."""
        out = set()
        if self.used.get("ATTITUDE"):
            out.add(MSG_ID["ATTITUDE_QUATERNION"])
        if self.vehicles and all(
            v.origin is not None
            and v.origin.source != "GLOBAL_POSITION_INT"
            and v.frame_vote is None
            for v in self.vehicles.values()
        ):
            out.add(MSG_ID["GLOBAL_POSITION_INT"])
        return frozenset(out)

    # -- read-out ---------------------------------------------------------------------
    def targets(self) -> dict[tuple[int, str], str]:
        """``(sysid, target) -> source`` of every observer created."""
        return {
            (s, name): src
            for s, veh in self.vehicles.items()
            for name, src in veh.targets.sources().items()
        }

    def is_vehicle(self, sysid: int) -> bool:
        """True once ``sysid`` has shown an autopilot (not a ground station or a stray
        component)."""
        veh = self.vehicles.get(sysid)
        return veh is not None and veh.autopilot_compid is not None

    def vehicle_skipped(self, sysid: int) -> dict[str, int]:
        """Messages of vehicle ``sysid`` skipped so far, by reason."""
        veh = self.vehicles.get(sysid)
        return {} if veh is None else dict(veh.skipped)

    def observer(self, sysid: int, target: str) -> BiasObserver | None:
        """The observer of ``target`` on vehicle ``sysid``, ``None`` if there is none."""
        veh = self.vehicles.get(sysid)
        return None if veh is None else veh.targets.get(target)
