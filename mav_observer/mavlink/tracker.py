"""Route MAVLink messages to one observer per vehicle (sysid) and target.

:class:`Tracker` takes decoded messages with their arrival (or tlog) time, keeps for each
vehicle its clocks (:mod:`~mav_observer.mavlink.timebase`), a short attitude history, its
latest position and velocity and its cameras' fields of view, turns bearing messages into
:class:`~mav_observer.core.samples.BearingSample` through the frame chains of
:mod:`~mav_observer.mavlink.adapters`, and returns an
:class:`~mav_observer.records.EstimateRecord` for each bearing the observers accept. A message
that cannot be used is counted by reason and skipped; nothing already received is lost.

Roles: this module turns messages into samples, per vehicle; the vehicle's attitude over time
is :mod:`~mav_observer.mavlink.attitude`'s; the observers of a vehicle's targets, and how they
are saved and resumed, are :mod:`~mav_observer.targets`'. Replay and the service run the same
loop body, :meth:`Tracker.handle` (``(t, message) -> records``), and read it through its
public methods.

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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from mav_observer import geodesy
from mav_observer.core.observer import BiasObserver, ObserverConfig
from mav_observer.core.samples import Estimate
from mav_observer.errors import ConfigError, InvalidSampleError, MavObserverError
from mav_observer.frames import Vec3, euler_from_dcm, euler_to_dcm, mat_vec, quat_to_dcm
from mav_observer.geodesy import Origin
from mav_observer.gimbalframe import GimbalFrameDetector
from mav_observer.mavlink import adapters, signing
from mav_observer.mavlink.adapters import Skip
from mav_observer.mavlink.attitude import AttitudeHistory
from mav_observer.mavlink.dialect import MSG_ID, type_key
from mav_observer.mavlink.timebase import ClockMap
from mav_observer.records import EstimateRecord
from mav_observer.targets import Targets, VehicleFix, check_saved

if TYPE_CHECKING:  # (the smoother's sample log is made by a replay that smooths)
    from mav_observer.smoother import SampleLog

log = logging.getLogger(__name__)

SOURCES = ("gimbal", "camera", "mount", "mount_status", "landing_target", "home")
AUTO_SOURCES = frozenset(SOURCES) - {"home"}
MAV_AUTOPILOT_INVALID = 8
POSITION_MAX_AGE_S = 1.0
#: What the tracker publishes per bearing (``TrackerConfig.publish``).
PUBLISH = ("auto", "live", "committed")
#: LOCAL_POSITION_NED positions kept to interpolate the vehicle's position at a committed
#: estimate's time.
POSITION_HISTORY = 32
#: Bearings' arrival times kept per target until their committed estimate is published.
MAX_PENDING_ARRIVALS = 4096


#: LOCAL_POSITION_NED beyond these is nonsense, refused as ``out_of_range``: a speed no
#: aircraft we serve reaches (m/s, per axis) and a local position farther than any flight from
#: its origin (m).
MAX_SPEED_MPS = 300.0
MAX_LOCAL_POSITION_M = 1.0e6
#: Bearings waiting for the vehicle attitude of their own time, per vehicle, at the most.
MAX_WAITING = 64
#: A component whose clock offset (arrival - time_boot_ms) is within this of the autopilot's
#: is on the autopilot's clock (s): its time_boot_ms is used as it is.
SAME_CLOCK_TOL_S = 0.05
#: LOCAL_POSITION_NED's position is used for the displacement between two of its samples
#: closer than this (s), at any rate (``docs/frames.md``, "Velocity from the positions").
SPARSE_VELOCITY_MAX_S = 5.0
#: The mean drift between LOCAL_POSITION_NED's position and its integrated velocity is
#: learnt over this much (s) of sparse intervals, then kept: one interval of a 1 Hz stream.
#: Any constant drift is taken up by ``a`` (the positions are GNSS-true); a drift still
#: being learnt changes the velocity handed to the estimator at every interval, a velocity
#: error ``a`` cannot follow: learnt over 30 s, a 35 s hover at 2-3 m (a public 1 Hz log)
#: was 6.7-9.0 % of the range off over its last third, 2.3-3.3 % learnt over the first
#: interval (``docs/frames.md``).
DRIFT_LEARN_S = 1.0
#: A correction of the published bias (:meth:`Tracker._published`) smaller than this on
#: every axis (m/s) is not applied: below the record's resolution (0.01 mm/s), and on the
#: per-bearing path of a service with a hundred targets.
BIAS_CORRECTION_MIN_MPS = 1e-6
#: How far (m) a new report of a source may put the origin from the one in use before the
#: origin is taken to have moved: GLOBAL_POSITION_INT and LOCAL_POSITION_NED, two estimates
#: rounded to 1 cm and 1e-7 deg (1.1 cm), disagree by centimetres; an EKF origin reset or a
#: new home moves it by metres.
ORIGIN_MOVED_M = {"GPS_GLOBAL_ORIGIN": 0.05, "HOME_POSITION": 0.05, "GLOBAL_POSITION_INT": 1.0}


@dataclass(frozen=True)
class TrackerConfig:
    """How messages become samples (``docs/frames.md``).

    * ``sources``: ``("auto",)`` or a subset of :data:`SOURCES`.
    * ``gimbal_angles``: ``"auto"`` (the flags are believed until the data show the angles
      to be body-relative: :mod:`mav_observer.gimbalframe`), ``"flags"`` (trust
      GIMBAL_DEVICE_FLAGS) or ``"body"`` (the quaternion is relative to the vehicle body:
      ArduPilot servo mounts, MNT1_TYPE 1).
    * ``mount_status_yaw``: frame of MOUNT_STATUS yaw, ``"vehicle"`` (ArduPilot) or ``"earth"``.
    * ``landing_target_orientation``, ``landing_target_yaw_align_deg``: the landing-target
      camera on the body, as ArduPilot's PLND_ORIENT (``"down"`` or ``"forward"``) and
      PLND_YAW_ALIGN.
    * ``camera_hfov_deg``, ``camera_vfov_deg``: field of view when the stream gives none.
    * ``max_attitude_age_s``: a vehicle attitude further than this from a bearing's time is
      not used (the bearing is skipped as ``no_attitude``).
    * ``max_camera_attitude_age_s``: same for pairing a tracked point with the gimbal or mount
      attitude.
    * ``attitude_wait_s``: a bearing that needs the vehicle attitude and arrives before the
      ATTITUDE of its own time waits for it at most this long (arrival time, s); then it is
      used with the attitude extrapolated by the reported body rates (counted as
      ``attitude_extrapolated``). 0: never wait.
    * ``attitude_extrapolate_s``: a bearing at most this far (s) past the latest attitude of
      a dense attitude stream (50 ms or less between samples) does not wait: the attitude is
      extrapolated by its rates at once (no latency added live; at 1 rad/s^2 of yaw
      acceleration 25 ms of extrapolation is 0.02 deg off). 0: always wait.
    * ``sysids``: only these vehicles (``None``: all).
    * ``restore_max_gap_s``: a saved observer older than this (vehicle time) is not restored
      (:meth:`Tracker.restore`).
    * ``observer``: settings of every observer (n must be 3).
    * ``publish``: ``"live"``: each bearing's estimate at its arrival, the vehicle's motion
      since the latest velocity sample predicted; ``"committed"``: each bearing's estimate
      once the velocity after it has arrived (at most one velocity interval later),
      interpolated, not predicted, that bearing applied, the vehicle's position moved on from
      the LOCAL_POSITION_NED before it by the velocity known on both sides; ``"auto"``: live
      in the service, committed in
      ``replay`` (``docs/cli.md``, "What replay publishes").
    * ``local_frame``: how the autopilot maps its local frame onto latitude and longitude
      (:data:`~mav_observer.geodesy.LOCAL_FRAMES`): ``"auto"`` (the WGS84 ellipsoid until the
      vehicle's own GLOBAL_POSITION_INT and LOCAL_POSITION_NED pairs tell ArduPilot's sphere,
      PX4's projection or the ellipsoid apart, :class:`~mav_observer.geodesy.FrameVote`),
      ``"wgs84"``, ``"ardupilot"`` or ``"px4"`` (``docs/geolocation.md``, "Frames and
      altitudes").
    """

    sources: tuple[str, ...] = ("auto",)
    gimbal_angles: str = "auto"
    mount_status_yaw: str = "vehicle"
    landing_target_orientation: str = "down"
    landing_target_yaw_align_deg: float = 0.0
    camera_hfov_deg: float | None = None
    camera_vfov_deg: float | None = None
    max_attitude_age_s: float = 0.5
    max_camera_attitude_age_s: float = 0.5
    attitude_wait_s: float = 0.3
    attitude_extrapolate_s: float = 0.025
    sysids: tuple[int, ...] | None = None
    restore_max_gap_s: float = 600.0
    observer: ObserverConfig = field(default_factory=ObserverConfig)
    publish: str = "auto"
    local_frame: str = "auto"

    def __post_init__(self) -> None:
        srcs = tuple(self.sources)
        bad = [s for s in srcs if s != "auto" and s not in SOURCES]
        if bad or not srcs:
            raise ConfigError(f"sources must be 'auto' or among {SOURCES}, got {srcs!r}")
        object.__setattr__(self, "sources", srcs)
        if self.gimbal_angles not in ("auto", "flags", "body"):
            raise ConfigError(
                f"gimbal_angles must be 'auto', 'flags' or 'body', got {self.gimbal_angles!r}"
            )
        if self.mount_status_yaw not in ("vehicle", "earth"):
            raise ConfigError(
                f"mount_status_yaw must be 'vehicle' or 'earth', got {self.mount_status_yaw!r}"
            )
        if self.landing_target_orientation not in ("down", "forward"):
            raise ConfigError(
                "landing_target_orientation must be 'down' or 'forward', "
                f"got {self.landing_target_orientation!r}"
            )
        for name in ("camera_hfov_deg", "camera_vfov_deg"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and 0.0 < v < 180.0):
                raise ConfigError(f"{name} must be in (0, 180) degrees, got {v!r}")
        for name in ("max_attitude_age_s", "max_camera_attitude_age_s", "restore_max_gap_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
                raise ConfigError(f"{name} must be a finite number > 0, got {v!r}")
        for name in ("attitude_wait_s", "attitude_extrapolate_s"):
            w = getattr(self, name)
            if not (isinstance(w, (int, float)) and math.isfinite(w) and 0.0 <= w <= 5.0):
                raise ConfigError(f"{name} must be a number in [0, 5] s, got {w!r}")
        if self.observer.n != 3:
            raise ConfigError(f"observer n must be 3 for NED, got {self.observer.n}")
        if self.publish not in PUBLISH:
            raise ConfigError(f"publish must be one of {PUBLISH}, got {self.publish!r}")
        if self.local_frame not in ("auto", *geodesy.LOCAL_FRAMES):
            raise ConfigError(
                f"local_frame must be 'auto' or one of {geodesy.LOCAL_FRAMES}, "
                f"got {self.local_frame!r}"
            )

    def enabled(self) -> frozenset[str]:
        if "auto" in self.sources:
            return AUTO_SOURCES | (frozenset(self.sources) - {"auto"})
        return frozenset(self.sources)

    def wanted_message_ids(self) -> frozenset[int]:
        """Message ids the tracker uses with these sources (for selective decoding)."""
        names = {"LOCAL_POSITION_NED", "ATTITUDE", "ATTITUDE_QUATERNION", "HEARTBEAT"}
        names |= {"GPS_GLOBAL_ORIGIN", "HOME_POSITION", "GLOBAL_POSITION_INT"}  # the origin
        en = self.enabled()
        if en & {"gimbal", "camera"}:
            names.add("GIMBAL_DEVICE_ATTITUDE_STATUS")
        if "camera" in en:
            names |= {"CAMERA_TRACKING_IMAGE_STATUS", "CAMERA_FOV_STATUS", "CAMERA_INFORMATION"}
        if en & {"mount", "camera"}:
            names.add("MOUNT_ORIENTATION")
        if "mount_status" in en:
            names.add("MOUNT_STATUS")
        if "landing_target" in en:
            names.add("LANDING_TARGET")
        if "home" in en:
            names.add("HOME_POSITION")
        return frozenset(MSG_ID[n] for n in names)


@dataclass
class _Waiting:
    """A bearing message waiting for the vehicle attitude of its time."""

    t_boot_s: float
    t_arrival_s: float
    msg: Any
    stage: Callable[..., None]
    needs_attitude: bool


@dataclass
class _Vehicle:
    sysid: int
    #: the observers of this vehicle's targets (:mod:`mav_observer.targets`)
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
    home: Vec3 | None = None
    #: messages of this vehicle skipped, by reason (the tracker's ``skipped`` sums all)
    skipped: Counter[str] = field(default_factory=Counter)
    #: the latest time_boot_ms per (message type, component): a repeat is a duplicate
    last_time_ms: dict[tuple[str, int], int] = field(default_factory=dict)
    #: bearing messages waiting for the attitude of their time, in arrival order
    waiting: deque[_Waiting] = field(default_factory=deque)
    #: components found to be on the autopilot's clock
    same_clock: set[Any] = field(default_factory=set)
    #: the latest autopilot time seen (s) and its arrival time (s)
    latest_boot: tuple[float, float] | None = None
    #: mean drift (m/s) between LOCAL_POSITION_NED's position and integrated velocity, and
    #: the time (s) of the sparse intervals it has seen
    drift: tuple[list[float], float] = field(default_factory=lambda: ([0.0, 0.0, 0.0], 0.0))
    #: every position interval kept so far: the sums of ``dp - trapezoid(u)`` (m) and of its
    #: ``dt`` (s), the long-run drift whose difference from ``drift`` corrects the bias
    #: published (:meth:`Tracker._published`)
    drift_all: tuple[list[float], float] = field(default_factory=lambda: ([0.0, 0.0, 0.0], 0.0))
    #: what :meth:`Tracker._published` adds to the observer's ``a`` (m/s), ``None`` while
    #: the drift is being learnt or the correction is below :data:`BIAS_CORRECTION_MIN_MPS`
    bias_correction: list[float] | None = None
    #: the previous sparse interval's deviation (m/s) of the position's change from the
    #: integrated velocity, drift removed (``None``: no such interval just before)
    position_dev: list[float] | None = None
    #: the local frame's origin on WGS84 (:mod:`mav_observer.geodesy`), once known
    origin: Origin | None = None
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


def _gimbal_target(device: int) -> str:
    """The target a gimbal device's bearings go to: ``gimbal`` for device 1 (or 0, no id),
    ``gimbalN`` for device N (a second gimbal keeps its own estimate)."""
    return "gimbal" if device <= 1 else f"gimbal{device}"


def _gimbal_device(target: str) -> int | None:
    """The gimbal device id of a target named after it (:func:`_gimbal_target`'s inverse),
    or ``None`` for another target."""
    if target == "gimbal":
        return 1
    if target.startswith("gimbal") and target[6:].isdigit():
        return int(target[6:])
    return None


class _Deferred(Exception):
    """Raised by a handler whose message waits for the attitude of its time."""


class Tracker:
    """Turns ``(t_arrival_s, message)`` pairs into estimate records; see the module docstring.

    ``t_arrival_s`` is the tlog timestamp on replay, the receive time live (Unix seconds).
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.enabled = self.config.enabled()
        self._sensor = adapters.landing_target_sensor(
            self.config.landing_target_orientation, self.config.landing_target_yaw_align_deg
        )
        self.vehicles: dict[int, _Vehicle] = {}
        #: gimbal readings decided from the data before a restart, by (sysid, device id)
        self._saved_angles: dict[tuple[int, int], str] = {}
        self.received: Counter[str] = Counter()
        self.used: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()
        self.events: Counter[str] = Counter()
        #: ``(t_boot_s, sysid, event)`` of the latest events (resets, clock changes, ...)
        self.event_log: deque[tuple[float, int, str]] = deque(maxlen=10_000)
        #: when set (replay --smooth), every velocity and bearing used is kept there
        self.sample_log: SampleLog | None = None
        self._warned: Counter[str] = Counter()  # log rate limiting
        #: saved observers waiting for their vehicle's first position (see :meth:`restore`)
        self._pending: dict[int, list[dict[str, Any]]] = {}
        #: estimates committed when their vehicle was reset, published with the message's
        self._orphans: list[EstimateRecord] = []
        self._handlers: dict[str, Callable[[_Vehicle, float, Any, list[EstimateRecord]], None]] = {
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
            veh = self.vehicles[sysid] = _Vehicle(sysid, self._new_targets())
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
        veh: _Vehicle,
        mtype: str,
        fn: Callable[..., None],
        *args: Any,
    ) -> None:
        """Run a handler (or a waiting bearing's second stage) on ``veh``: a message that
        cannot be used is counted by reason, never raised; one that waits counts nothing
        yet."""
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

    def _note(self, veh: _Vehicle, event: str) -> None:
        """Count an event and log when it happened (the vehicle's latest autopilot time)."""
        self.events[event] += 1
        t = veh.latest_boot[0] if veh.latest_boot is not None else math.nan
        self.event_log.append((t, veh.sysid, event))

    def _count_skip(self, veh: _Vehicle, mtype: str, s: Skip) -> None:
        self.skipped[s.reason] += 1
        veh.skipped[s.reason] += 1
        n = veh.skipped[s.reason]
        if n in (1, 10, 100) or n % 10_000 == 0:
            log.info("vehicle %d: %s skipped as %s (%d so far): %s",
                     veh.sysid, mtype, s.reason, n, s)  # fmt: skip

    # -- bearings that wait for the attitude of their time ----------------------------
    def _when_attitude(
        self,
        veh: _Vehicle,
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
            veh.waiting.append(_Waiting(tb, t_arrival, msg, stage, needs_attitude))
            raise _Deferred
        stage(veh, tb, t_arrival, msg, out)

    def _attitude_ahead(self, veh: _Vehicle, tb: float) -> bool:
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
        self, veh: _Vehicle, t_arrival: float, out: list[EstimateRecord], at_most: int = 0
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
    def _timed(self, veh: _Vehicle, key: Any, boot_s: float, arrival: float) -> float:
        """Boot time of a timed message from clock ``key`` moved onto the autopilot clock."""
        if not math.isfinite(boot_s):
            raise Skip("non_finite", "time")
        clock = veh.clocks.get(key)
        if clock is None:
            clock = veh.clocks[key] = ClockMap()
        event = clock.update(boot_s, arrival)
        if event in ("out_of_order", "clock_unconfirmed", "time_jump"):
            raise Skip(event, f"clock {key}: time_boot_ms {boot_s:.3f} s refused ({event})")
        is_autopilot = key == veh.autopilot_compid
        if event in ("reboot", "clock_jump"):
            if is_autopilot:
                self._reboot(veh, event)
                veh.clocks[key] = clock  # keep the restarted mapping
            else:
                self._note(veh, f"clock_restart_{key}")
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
            self._note(veh, "component_on_autopilot_clock")
            return boot_s
        return ap.to_boot(clock.to_arrival(boot_s))

    def _untimed(self, veh: _Vehicle, arrival: float) -> float:
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

    def _claim_autopilot(self, veh: _Vehicle, compid: int) -> None:
        if veh.autopilot_compid is None:
            veh.autopilot_compid = compid

    def _reboot(self, veh: _Vehicle, event: str = "reboot") -> None:
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
        fresh = _Vehicle(veh.sysid, self._new_targets(), autopilot_compid=keep, skipped=veh.skipped,
                         local_frame=veh.local_frame)  # fmt: skip
        if self._pending.pop(veh.sysid, None):
            log.warning("vehicle %d: saved observers discarded (autopilot rebooted)", veh.sysid)
        veh.__dict__.update(fresh.__dict__)

    # -- vehicle state ----------------------------------------------------------------
    def _on_heartbeat(self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        if msg.autopilot != MAV_AUTOPILOT_INVALID:
            self._claim_autopilot(veh, msg.get_srcComponent())

    def _local_frame(self, veh: _Vehicle) -> str:
        """The vehicle's local frame: the setting, else as its pairs told it, else WGS84."""
        if self.config.local_frame != "auto":
            return self.config.local_frame
        return veh.local_frame or "wgs84"

    def _vote_frame(self, veh: _Vehicle, lat_deg: float, lon_deg: float, alt_m: float,
                    ned: Vec3) -> None:  # fmt: skip
        """One more GLOBAL_POSITION_INT and LOCAL_POSITION_NED pair for the frame's vote: the
        origin placed again on the vote's choice when it changes (a GLOBAL_POSITION_INT origin
        with the mean of its pairs on that frame); once the vote has decided, the event
        ``local_frame_<frame>`` counted and the vote ended."""
        vote = veh.frame_vote
        if vote is None:
            return
        vote.add(lat_deg, lon_deg, alt_m, ned)
        origin = veh.origin
        if origin is None:
            return
        frame, decided = vote.choice(origin.frame)
        if decided:
            veh.local_frame, veh.frame_vote = frame, None
            self._note(veh, f"local_frame_{frame}")
            log.info("vehicle %d: local frame told by its position pairs: %s", veh.sysid, frame)
        if origin.frame == frame:
            return
        if origin.source == "GLOBAL_POSITION_INT":
            veh.origin_mean = vote.means[frame]
            veh.origin = veh.origin_mean.origin
        elif veh.origin_fix is not None:
            source, lat0, lon0, alt0, ned0 = veh.origin_fix
            veh.origin = geodesy.origin_from(lat0, lon0, alt0, ned0, source, frame)

    def _on_system_time(self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        comp = msg.get_srcComponent()
        if comp == veh.autopilot_compid:
            self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)

    def _on_local_position(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
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
            self._pair_global_local(veh)
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
        self, veh: _Vehicle, tb: float, pos: Vec3, vel: Vec3
    ) -> list[float] | None:
        """The mean of the paper's ``v`` since the previous LOCAL_POSITION_NED, from the
        change of its position, when the two are at most :data:`SPARSE_VELOCITY_MAX_S` apart
        (``docs/frames.md``, "Velocity from the positions"); else ``None`` (the velocity
        samples are interpolated linearly).

        LOCAL_POSITION_NED's x, y, z are the integral of the autopilot's velocity estimate,
        kept true by its GNSS or other position fixes: over a second of turning flight they
        give the displacement where two velocity samples a second apart do not, and at any
        rate they do not accumulate the velocity's wander (the SITL log's velocity is off
        its positions by 0.037 m/s RMS at 10 Hz, correlated over seconds: integrated, a
        target injected there was 0.2-0.5 m off along its range at a sigma of 2-3 cm). The mean
        drift between the two (a constant velocity error, ``a``'s business) is kept out: the
        displacement used is the position's change less ``drift * dt``, the drift being
        the time average of ``(dp - trapezoid(u)) / dt`` over the first
        :data:`DRIFT_LEARN_S` of such intervals (the first interval of a 1 Hz stream), then
        kept (a drift that followed the
        velocity sensor's slow wander would turn into a varying ``a``, which the model does
        not have: measured on the shared logs with injected bearings, following it cost 2x
        to 4x in position error). An
        interval whose position jumps (an EKF reset: more than ``0.5 m + 5 m/s^2 dt^2`` off
        the velocity's trapezoid, drift removed, and as much off the previous interval's
        deviation: a step, not a velocity that disagrees with the position for seconds)
        keeps the velocity and is counted as ``position_reset``."""
        prev = veh.position
        if prev is None:
            return None
        t0, p0, u0 = prev
        dt = tb - t0
        if not 0.0 < dt <= SPARSE_VELOCITY_MAX_S:
            veh.position_dev = None
            return None
        drift, seen_s = veh.drift
        resid = [(pos[j] - p0[j]) - 0.5 * (u0[j] + vel[j]) * dt for j in range(3)]
        dev = [resid[j] / dt - drift[j] for j in range(3)]  # m/s off the mean drift
        before = veh.position_dev or [0.0, 0.0, 0.0]
        veh.position_dev = dev
        off = math.sqrt(sum(d * d for d in dev)) * dt
        step = math.sqrt(sum((d - b) ** 2 for d, b in zip(dev, before, strict=True))) * dt
        gate = 0.5 + 5.0 * dt * dt
        w = dt / (seen_s + dt) if seen_s < DRIFT_LEARN_S else 0.0
        # the drift learns from every interval, a jump's share clipped to the gate (so a
        # reset moves it little and a large constant error is still learnt)
        clip = min(1.0, gate / off) if off > 0.0 else 1.0
        veh.drift = ([drift[j] + w * clip * dev[j] for j in range(3)], seen_s + dt)
        if off > gate and step > gate:
            self._note(veh, "position_reset")
            return None
        sums, span = veh.drift_all
        sums = [sums[j] + resid[j] for j in range(3)]
        veh.drift_all = (sums, span + dt)
        drift = veh.drift[0]
        corr = [drift[j] - sums[j] / (span + dt) for j in range(3)]
        big = span + dt > DRIFT_LEARN_S and max(map(abs, corr)) >= BIAS_CORRECTION_MIN_MPS
        veh.bias_correction = corr if big else None
        # v = -u: minus the mean measured velocity, (dp - drift dt) / dt
        return [-((pos[j] - p0[j]) / dt - drift[j]) for j in range(3)]

    def _on_attitude(self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        comp = msg.get_srcComponent()
        self._claim_autopilot(veh, comp)
        adapters.check_attitude(msg.roll, msg.pitch, msg.yaw)
        tb = self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
        rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
        veh.attitude.add(tb, msg.roll, msg.pitch, msg.yaw, rates)

    def _on_attitude_quaternion(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        comp = msg.get_srcComponent()
        self._claim_autopilot(veh, comp)
        q = adapters.check_quaternion((msg.q1, msg.q2, msg.q3, msg.q4))
        tb = self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
        rates = (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
        veh.attitude.add(tb, *euler_from_dcm(quat_to_dcm(q)), rates)

    def _vehicle_attitude(self, veh: _Vehicle, tb: float) -> tuple[float, float, float] | None:
        return veh.attitude.at(tb, self.config.max_attitude_age_s)

    def _on_home(self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        home = (msg.x, msg.y, msg.z)
        if not all(math.isfinite(v) for v in home):
            raise Skip("non_finite", "HOME_POSITION")
        veh.home = home
        if msg.latitude or msg.longitude:  # 0, 0: no home yet
            self._place_origin(
                veh, "HOME_POSITION", msg.latitude * 1e-7, msg.longitude * 1e-7,
                msg.altitude * 1e-3, home,
            )  # fmt: skip

    def _on_gps_global_origin(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        self._place_origin(
            veh, "GPS_GLOBAL_ORIGIN", msg.latitude * 1e-7, msg.longitude * 1e-7,
            msg.altitude * 1e-3, (0.0, 0.0, 0.0),
        )  # fmt: skip

    def _on_global_position(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        if not (msg.lat or msg.lon):  # 0, 0: no fix
            return
        veh.gpi_ms = (msg.time_boot_ms, (msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3))
        self._pair_global_local(veh)

    def _pair_global_local(self, veh: _Vehicle) -> None:
        """GLOBAL_POSITION_INT and LOCAL_POSITION_NED at the same time_boot_ms: the origin,
        unless a better source has given it."""
        g, lp = veh.gpi_ms, veh.lpn_ms
        if g is None or lp is None or g[0] != lp[0]:
            return
        if veh.origin is not None and veh.origin.source != "GLOBAL_POSITION_INT":
            if veh.frame_vote is not None:  # a better source placed it: the pair only votes
                try:
                    geodesy.check_geodetic(*g[1], "GLOBAL_POSITION_INT")
                except InvalidSampleError as exc:
                    raise Skip("out_of_range", str(exc)) from exc
                self._vote_frame(veh, *g[1], lp[1])
            return
        self._place_origin(veh, "GLOBAL_POSITION_INT", *g[1], lp[1])

    def _place_origin(
        self, veh: _Vehicle, source: str, lat_deg: float, lon_deg: float, alt_m: float, ned: Vec3
    ) -> None:
        """A point at ``lat_deg, lon_deg, alt_m`` (AMSL) is at ``ned`` in the local frame:
        the origin, if ``source`` is at least as trusted as the one in use
        (:data:`~mav_observer.geodesy.ORIGIN_SOURCES`) and the origin in use does not already
        put it there (within :data:`ORIGIN_MOVED_M`); a moved origin (an EKF origin reset, a
        new home) is counted as ``origin_changed`` and logged. GLOBAL_POSITION_INT's pairs that
        agree with the origin in use are averaged into it (:class:`~mav_observer.geodesy.
        OriginMean`: each is rounded to 1e-7 deg, about 1 cm)."""
        cur = veh.origin
        rank = geodesy.ORIGIN_SOURCES.index(source)
        if cur is not None:
            cur_rank = geodesy.ORIGIN_SOURCES.index(cur.source)
            if rank > cur_rank:
                return
            if rank == cur_rank:
                try:
                    geodesy.check_geodetic(lat_deg, lon_deg, alt_m, source)
                except InvalidSampleError as exc:
                    raise Skip("out_of_range", str(exc)) from exc
                lat, lon, alt = geodesy.to_geodetic(cur, ned)
                if (
                    geodesy.gap_m((lat, lon, alt), (lat_deg, lon_deg, alt_m))
                    <= ORIGIN_MOVED_M[source]
                ):
                    mean = veh.origin_mean
                    if mean is not None:  # another pair: the mean of them all
                        if veh.frame_vote is not None:  # (the mean in use is among its)
                            self._vote_frame(veh, lat_deg, lon_deg, alt_m, ned)
                        else:
                            mean.add(lat_deg, lon_deg, alt_m, ned)
                        veh.origin = veh.origin_mean.origin  # type: ignore[union-attr]
                    return
        try:
            origin = geodesy.origin_from(
                lat_deg, lon_deg, alt_m, ned, source, self._local_frame(veh)
            )
        except InvalidSampleError as exc:
            raise Skip("out_of_range", str(exc)) from exc
        veh.origin = origin
        veh.origin_fix = (source, lat_deg, lon_deg, alt_m, ned)
        vote = None
        if self.config.local_frame == "auto" and veh.local_frame is None:
            vote = geodesy.FrameVote.start(lat_deg, lon_deg, alt_m, ned, source)
        veh.frame_vote = vote
        if source != "GLOBAL_POSITION_INT":
            veh.origin_mean = None
        else:  # the pairs' mean (while the frame is voted on, the vote's for the frame in use)
            veh.origin_mean = vote.means[origin.frame] if vote else geodesy.OriginMean(origin)
        moved = (
            cur is not None
            and geodesy.gap_m(
                (cur.lat_deg, cur.lon_deg, cur.alt_m),
                (origin.lat_deg, origin.lon_deg, origin.alt_m),
            )
            > ORIGIN_MOVED_M[source]
        )
        if moved:
            self._note(veh, "origin_changed")
        log.info(
            "vehicle %d: local frame origin %s from %s: %.7f %.7f %.2f m",
            veh.sysid,
            "found" if cur is None else ("moved" if moved else "confirmed"),
            source,
            origin.lat_deg,
            origin.lon_deg,
            origin.alt_m,
        )

    # -- bearings ---------------------------------------------------------------------
    def _on_gimbal(self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        tb = self._timed(veh, msg.get_srcComponent(), msg.time_boot_ms * 1e-3, t)
        # device 0 (a gimbal that gives no id) is target "gimbal", as device 1
        angles = self._gimbal_angles(veh, max(getattr(msg, "gimbal_device_id", 0), 1))
        needs = angles != "flags" or adapters.gimbal_needs_vehicle_yaw(
            msg.flags, getattr(msg, "delta_yaw", math.nan)
        )
        self._when_attitude(veh, tb, t, msg, out, self._gimbal_at, needs)

    def _gimbal_angles(self, veh: _Vehicle, device: int) -> str:
        """How gimbal ``device``'s angles are read: the setting, or with ``"auto"`` the
        detector's decision (``"auto"`` while undecided: the flags, with the detector fed)."""
        if self.config.gimbal_angles != "auto":
            return self.config.gimbal_angles
        det = veh.gimbal_frames.get(device)
        if det is None:
            saved = self._saved_angles.get((veh.sysid, device))
            if saved is None:
                return "auto"
            det = veh.gimbal_frames[device] = GimbalFrameDetector(saved)  # a restart's
        return "auto" if det.decided is None else det.decided

    def gimbal_angles(self, sysid: int) -> dict[int, str]:
        """How vehicle ``sysid``'s gimbals' angles are read, by gimbal device id: ``"flags"``
        or ``"body"`` (set, or decided from the data), ``"auto"`` while undecided."""
        veh = self.vehicles.get(sysid)
        if veh is None:
            return {}
        return {dev: self._gimbal_angles(veh, dev) for dev in sorted(veh.gimbal_frames)}

    def _gimbal_at(
        self, veh: _Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        att = self._vehicle_attitude(veh, tb)
        q = tuple(msg.q)
        delta_yaw = getattr(msg, "delta_yaw", math.nan)
        yaw = None if att is None else att[2]
        dev = max(getattr(msg, "gimbal_device_id", 0), 1)  # 0 (no id): target "gimbal"
        angles = self._gimbal_angles(veh, dev)
        if angles != "body":
            direction = adapters.gimbal_boresight(
                q, msg.flags, msg.failure_flags, vehicle_yaw=yaw, delta_yaw=delta_yaw
            )
            if angles == "auto":
                angles = self._detect_gimbal_frame(veh, dev, tb, msg, att, direction)
        if angles == "body":
            r_cam = adapters.gimbal_camera_attitude(
                q,
                msg.flags,
                msg.failure_flags,
                vehicle_yaw=yaw,
                vehicle_dcm=None if att is None else euler_to_dcm(*att),
                angles="body",
            )
            direction = adapters.boresight(r_cam)
            veh.camera_attitude = (tb, r_cam)
        elif "camera" in self.enabled:  # the full attitude is built only if a point needs it
            veh.camera_attitude = (tb, (q, msg.flags, yaw, delta_yaw))
        target = _gimbal_target(dev)
        if "gimbal" in self.enabled:
            self._bearing(veh, target, "GIMBAL_DEVICE_ATTITUDE_STATUS", tb, t, direction, out)

    def _detect_gimbal_frame(
        self,
        veh: _Vehicle,
        dev: int,
        tb: float,
        msg: Any,
        att: tuple[float, float, float] | None,
        b_flags: Vec3,
    ) -> str:
        """Feed gimbal ``dev``'s frame detector with this message, whose boresight read by
        its flags is ``b_flags`` (``gimbal_angles = "auto"``), and return the reading to use
        for it: ``"flags"`` until it decides."""
        det = veh.gimbal_frames.get(dev)
        if det is None:
            det = veh.gimbal_frames[dev] = GimbalFrameDetector()
        if att is None:
            return "flags"
        r_nb = euler_to_dcm(*att)
        if adapters.gimbal_yaw_frame(msg.flags) == "earth":
            t_fb = r_nb
        else:  # R_nb Rz(yaw)^T
            dy = getattr(msg, "delta_yaw", math.nan)
            yaw = adapters.gimbal_vehicle_yaw(msg.flags, dy, att[2])
            c, s = math.cos(yaw), math.sin(yaw)
            t_fb = tuple((row[0] * c - row[1] * s, row[0] * s + row[1] * c, row[2]) for row in r_nb)
        decided = det.add(tb, b_flags, t_fb)
        if decided is None:
            return "flags"
        ev = det.evidence()
        self._note(veh, f"gimbal_angles_{decided}")
        if decided == "body":  # its estimate and bearings so far read the angles wrongly
            target = _gimbal_target(dev)
            veh.targets.restart(target)
            veh.arrivals.pop(target, None)
            if self.sample_log is not None:
                self.sample_log.forget_bearings(veh.sysid, target)
        log.log(
            logging.WARNING if decided == "body" else logging.INFO,
            "vehicle %d: gimbal %d's roll and pitch read as %s from %.1f s (the boresight "
            "follows the vehicle's tilt %.2f +- %.2f of the way read by its flags)",
            veh.sysid,
            dev,
            "body-relative (a servo mount)" if decided == "body" else "its flags say",
            tb,
            ev.beta,
            ev.beta_se,
        )
        return decided

    def _on_mount_orientation(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        tb = self._timed(veh, msg.get_srcComponent(), msg.time_boot_ms * 1e-3, t)
        needs = not math.isfinite(getattr(msg, "yaw_absolute", math.nan))
        self._when_attitude(veh, tb, t, msg, out, self._mount_orientation_at, needs)

    def _mount_orientation_at(
        self, veh: _Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        att = self._vehicle_attitude(veh, tb)
        yaw_abs = getattr(msg, "yaw_absolute", math.nan)
        direction = adapters.mount_orientation_direction(
            msg.pitch, msg.yaw, yaw_abs, None if att is None else att[2]
        )
        roll = math.radians(msg.roll) if math.isfinite(msg.roll) else 0.0
        yaw_e = math.atan2(direction[1], direction[0])
        veh.camera_attitude = (tb, euler_to_dcm(roll, math.radians(msg.pitch), yaw_e))
        if "mount" in self.enabled:
            self._bearing(veh, "mount", "MOUNT_ORIENTATION", tb, t, direction, out)

    def _on_mount_status(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        tb = self._untimed(veh, t)
        needs = self.config.mount_status_yaw == "vehicle"
        self._when_attitude(veh, tb, t, msg, out, self._mount_status_at, needs)

    def _mount_status_at(
        self, veh: _Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        att = self._vehicle_attitude(veh, tb)
        direction = adapters.mount_status_direction(
            msg.pointing_a,
            msg.pointing_c,
            None if att is None else att[2],
            yaw_frame=self.config.mount_status_yaw,
        )
        self._bearing(veh, "mount_status", "MOUNT_STATUS", tb, t, direction, out)

    def _on_camera_fov(self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        if not (
            math.isfinite(msg.hfov) and math.isfinite(msg.vfov) and msg.hfov > 0 and msg.vfov > 0
        ):
            raise Skip("no_fov", "CAMERA_FOV_STATUS without a field of view")
        veh.fov[msg.get_srcComponent()] = (math.radians(msg.hfov), math.radians(msg.vfov))

    def _on_camera_information(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        fov = adapters.fov_from_camera_information(
            msg.focal_length, msg.sensor_size_h, msg.sensor_size_v
        )
        if fov is None:
            raise Skip("no_fov", "CAMERA_INFORMATION without focal length and sensor size")
        veh.fov.setdefault(msg.get_srcComponent(), fov)

    def _fov(self, veh: _Vehicle, compid: int) -> tuple[float, float]:
        fov = veh.fov.get(compid)
        if fov is None and veh.fov:
            fov = next(iter(veh.fov.values()))
        if fov is None and self.config.camera_hfov_deg and self.config.camera_vfov_deg:
            fov = (
                math.radians(self.config.camera_hfov_deg),
                math.radians(self.config.camera_vfov_deg),
            )
        if fov is None:
            raise Skip("no_fov", "no field of view from the stream or the configuration")
        return fov

    def _on_camera_tracking(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        adapters.tracking_status_usable(msg.tracking_status)
        tb = self._untimed(veh, t)
        # waits behind the gimbal message it goes with, if that one waits
        self._when_attitude(veh, tb, t, msg, out, self._camera_tracking_at, False)

    def _camera_tracking_at(
        self, veh: _Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        hfov, vfov = self._fov(veh, msg.get_srcComponent())
        ray = adapters.tracking_ray(msg.point_x, msg.point_y, hfov, vfov)
        cam = veh.camera_attitude
        if cam is None or abs(cam[0] - tb) > self.config.max_camera_attitude_age_s:
            raise Skip("no_camera_attitude", "no gimbal or mount attitude near the tracked point")
        r_cam = cam[1]
        if len(r_cam) == 4:  # a gimbal's (q, flags, yaw, delta_yaw)
            q, flags, yaw, delta_yaw = r_cam
            r_cam = adapters.gimbal_camera_attitude(
                q, flags, 0, vehicle_yaw=yaw, delta_yaw=delta_yaw
            )
        self._bearing(
            veh, "camera", "CAMERA_TRACKING_IMAGE_STATUS", tb, t, mat_vec(r_cam, ray), out
        )

    def _on_landing_target(
        self, veh: _Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        comp = msg.get_srcComponent()
        if adapters.time_usec_kind(msg.time_usec) == "unix":
            tb = self._untimed(veh, msg.time_usec * 1e-6)
        else:
            tb = self._timed(veh, ("landing_target", comp), msg.time_usec * 1e-6, t)
        self._when_attitude(veh, tb, t, msg, out, self._landing_target_at, True)

    def _landing_target_at(
        self, veh: _Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        att = self._vehicle_attitude(veh, tb)
        pos = None
        if veh.position is not None and abs(veh.position[0] - tb) <= POSITION_MAX_AGE_S:
            pos = veh.position[1]
        los = adapters.landing_target_direction(
            frame=msg.frame,
            angle_x=msg.angle_x,
            angle_y=msg.angle_y,
            position_valid=getattr(msg, "position_valid", 0),
            x=getattr(msg, "x", 0.0),
            y=getattr(msg, "y", 0.0),
            z=getattr(msg, "z", 0.0),
            vehicle_dcm=None if att is None else euler_to_dcm(*att),
            vehicle_yaw=None if att is None else att[2],
            vehicle_pos_ned=pos,
            sensor=self._sensor,
        )
        self._bearing(veh, f"landing_target_{msg.target_num}", "LANDING_TARGET", tb, t, los, out)

    # -- the observers ----------------------------------------------------------------
    def _bearing(
        self,
        veh: _Vehicle,
        target: str,
        source: str,
        tb: float,
        t_arrival: float,
        direction: Vec3,
        out: list[EstimateRecord],
    ) -> None:
        n2 = direction[0] ** 2 + direction[1] ** 2 + direction[2] ** 2
        if not math.isfinite(tb) or not math.isfinite(n2):
            raise Skip("non_finite", f"bearing {direction} at {tb}")
        if n2 <= 0.0:
            raise Skip("zero_length", f"bearing {direction}")
        inv = 1.0 / math.sqrt(n2)
        y = [direction[0] * inv, direction[1] * inv, direction[2] * inv]
        obs = veh.targets.get(target)
        reacq = 0 if obs is None else obs.reacquisitions
        try:
            est, new = veh.targets.bearing(target, source, tb, y, veh.velocity)
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
        vpos = self._predicted_position(veh, obs, est, tb)
        est = self._published(veh, est)
        out.append(EstimateRecord(t_arrival, tb, veh.sysid, target, source, est, vpos, veh.origin))

    def _predicted_position(
        self,
        veh: _Vehicle,
        obs: BiasObserver | None,
        est: Estimate,
        tb: float,
        fix: tuple[float, Vec3, Vec3] | None = None,
    ) -> Vec3 | None:
        """The vehicle's position (NED, m) at ``tb`` from the LOCAL_POSITION_NED ``fix``
        (default: the latest), moved on the way the estimate was; ``None`` without one near
        ``tb``."""
        fix = fix if fix is not None else veh.position
        if fix is None:
            return None
        tp, p, u = fix
        dt = tb - tp
        if abs(dt) > POSITION_MAX_AGE_S:
            return None
        # the latest position moved on the way the estimate was: by minus the observer's
        # predicted displacement of x less ``a`` dt (``a`` is the velocity's error where the
        # target stands still; with (2, -1, 0) m/s of it, moved on with the velocity as
        # measured the position was 0.18 m off 0.09 s after a 10 Hz sample; on a 1 Hz stream
        # the observer continues a trend, and a position moved on otherwise put the target
        # 2.8 cm off, outside its sigma)
        a0, a1, a2 = est.a_mps.tolist()
        disp = None if obs is None else obs.predicted_displacement_m(tp, tb)
        if disp is None:
            disp = [-u[0] * dt, -u[1] * dt, -u[2] * dt]
        return (p[0] - disp[0] - a0 * dt, p[1] - disp[1] - a1 * dt, p[2] - disp[2] - a2 * dt)

    @staticmethod
    def _published(veh: _Vehicle, est: Estimate) -> Estimate:
        """``est`` as published: its bias ``a`` (target velocity minus the velocity's error)
        against the velocity's long-run drift from the positions rather than the drift
        learnt once and handed to the observer (:meth:`_interval_mean_velocity`). The
        observer's ``a`` takes up that first drift, the mean of the velocity's error over
        the first second only (at 10 Hz with 0.1 m/s of white noise, 0.03 m/s off; with a
        wandering error, its value then); every interval kept since (the drift's sums,
        ``drift_all``) gives the velocity's constant error itself. The estimate moves the
        vehicle's position with the observer's ``a`` (:meth:`_predicted_position`), as the
        observer integrated it."""
        corr = veh.bias_correction
        if corr is None:
            return est
        a = est.a_mps + corr  # a new array (numpy's), read-only as the estimate's are
        a.setflags(write=False)
        return est.with_a(a)

    def _publish_committed(
        self, veh: _Vehicle, out: list[EstimateRecord], *, end: bool = False
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
            vpos = self._predicted_position(veh, veh.targets.get(target), est, tb, fix)
            pub = self._published(veh, est)
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
        told (:class:`~mav_observer.geodesy.FrameVote`)."""
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

    # -- persistence ------------------------------------------------------------------
    def export_state(self) -> list[dict[str, Any]]:
        """Every started observer with what :meth:`restore` needs to carry it across a gap:
        its vehicle's latest position and velocity (LOCAL_POSITION_NED frame, autopilot clock)
        and the whole observer (:meth:`Targets.export`). JSON-serialisable."""
        out: list[dict[str, Any]] = []
        for sysid, veh in self.vehicles.items():
            if veh.position is not None:
                for e in veh.targets.export(sysid, VehicleFix(*veh.position)):
                    dev = _gimbal_device(e["target"])
                    det = None if dev is None else veh.gimbal_frames.get(dev)
                    if det is not None and det.decided is not None:
                        e["gimbal_angles"] = det.decided  # what the data showed, kept too
                    out.append(e)
        # observers restored but whose vehicle has not come back yet are kept as they were
        for entries in self._pending.values():
            out.extend(entries)
        return out

    def restore(self, entries: list[dict[str, Any]]) -> None:
        """Take observers saved by :meth:`export_state`. Each waits for its vehicle's first
        LOCAL_POSITION_NED, then resumes (:meth:`Targets.resume`) moved by minus the
        vehicle's displacement since it was saved: the target is assumed to have stayed where
        it was in the local frame (a moving target resumes off by its own displacement, which
        the observer then corrects). It is discarded, with a warning, if the autopilot's
        clock went back (a reboot: the local frame may have moved) or more than
        ``config.restore_max_gap_s`` of vehicle time passed. Raises :class:`StateError` naming
        the bad entry (:func:`check_saved`); nothing is taken then."""
        for sysid, es in check_saved(entries).items():
            self._pending.setdefault(sysid, []).extend(es)
            for e in es:
                dev = _gimbal_device(e["target"])
                if dev is not None and e.get("gimbal_angles") is not None:
                    self._saved_angles[(sysid, dev)] = e["gimbal_angles"]

    def _resume_saved(self, veh: _Vehicle, entries: list[dict[str, Any]]) -> None:
        """Carry saved observers to the vehicle's current position (see :meth:`restore`)."""
        fix = VehicleFix(*veh.position)  # type: ignore[misc]
        for r in veh.targets.resume(entries, fix, self.config.restore_max_gap_s):
            who = (veh.sysid, r.target)
            if r.restored:
                self._note(veh, "restored")
                obs = veh.targets.get(r.target)
                log.info(
                    "vehicle %d: restored observer %r (%s), %.1f s of vehicle time after it "
                    "was saved, vehicle moved %.1f m since",
                    veh.sysid,
                    r.target,
                    "?" if obs is None else str(obs.status),
                    r.gap_s,
                    r.moved_m,
                )
            elif r.outcome == "superseded":
                log.info("vehicle %d: saved observer %r: a live one has its place", *who)
            else:
                why = "clock went back" if r.outcome == "clock_back" else f"{r.gap_s:.0f} s old"
                log.warning("vehicle %d: saved observer %r discarded (%s)", *who, why)
                self._note(veh, "restore_discarded")

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
