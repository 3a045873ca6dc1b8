"""How the tracker turns messages into samples: its settings (``docs/frames.md``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mav_observer.core.config import ObserverConfig
from mav_observer.errors import ConfigError
from mav_observer.geo import geodesy
from mav_observer.mavlink.dialect import MSG_ID

SOURCES = ("gimbal", "camera", "mount", "mount_status", "landing_target", "home")
AUTO_SOURCES = frozenset(SOURCES) - {"home"}
#: What the tracker publishes per bearing (``TrackerConfig.publish``).
PUBLISH = ("auto", "live", "committed")


@dataclass(frozen=True)
class TrackerConfig:
    """How messages become samples (``docs/frames.md``).

    * ``sources``: ``("auto",)`` or a subset of :data:`SOURCES`.
    * ``gimbal_angles``: ``"auto"`` (the flags are believed until the data show the angles
      to be body-relative: :mod:`mav_observer.geo.gimbal_frame`), ``"flags"`` (trust
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
    * ``range_noise_m``: the standard deviation (m) of a range measured with a bearing (a laser
      rangefinder on the gimbal: DISTANCE_SENSOR from the gimbal, DataFlash ``MNT.Dist``,
      LANDING_TARGET ``distance``) when the message gives none.
    * ``max_range_age_s``: a gimbal's range is fused with the gimbal or mount bearing at most
      this far from its time (s), each range once.
    * ``sysids``: only these vehicles (``None``: all).
    * ``restore_max_gap_s``: a saved observer older than this (vehicle time) is not restored
      (:meth:`~mav_observer.tracking.tracker.Tracker.restore`).
    * ``observer``: settings of every observer (n must be 3).
    * ``publish``: ``"live"``: each bearing's estimate at its arrival, the vehicle's motion
      since the latest velocity sample predicted; ``"committed"``: each bearing's estimate
      once the velocity after it has arrived (at most one velocity interval later),
      interpolated, not predicted, that bearing applied, the vehicle's position moved on from
      the LOCAL_POSITION_NED before it by the velocity known on both sides; ``"auto"``: live
      in the service, committed in
      ``replay`` (``docs/cli.md``, "What replay publishes").
    * ``local_frame``: how the autopilot maps its local frame onto latitude and longitude
      (:data:`~mav_observer.geo.geodesy.LOCAL_FRAMES`): ``"auto"`` (the WGS84 ellipsoid until the
      vehicle's own GLOBAL_POSITION_INT and LOCAL_POSITION_NED pairs tell ArduPilot's sphere,
      PX4's projection or the ellipsoid apart, :class:`~mav_observer.geo.geodesy.FrameVote`),
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
    range_noise_m: float = 1.0
    max_range_age_s: float = 0.1
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
        for name in ("max_attitude_age_s", "max_camera_attitude_age_s", "restore_max_gap_s",
                     "range_noise_m", "max_range_age_s"):  # fmt: skip
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
        names.add("DISTANCE_SENSOR")  # a rangefinder on the gimbal
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
