"""The software MAVLink emitter: a scenario as a vehicle and its gimbal or camera would send it.

Streams (each at its own rate, on the vehicle's simulated clock):

* HEARTBEAT (1 Hz; a quadrotor running ArduPilot), SYSTEM_TIME (1 Hz), SYS_STATUS (1 Hz);
* ATTITUDE and ATTITUDE_QUATERNION (``attitude_hz``), LOCAL_POSITION_NED and
  GLOBAL_POSITION_INT (``position_hz``; velocity with the scenario's error and noise; the
  position placed as ArduPilot places it, :func:`ardupilot_offset`);
* the bearing stream (``bearing_hz``), with the scenario's noise, dropouts and latency:

  ==========================  =================================================================
  ``bearing``                 messages
  ==========================  =================================================================
  ``gimbal``                  GIMBAL_DEVICE_ATTITUDE_STATUS, yaw in the vehicle frame (ArduPilot)
  ``gimbal_earth``            GIMBAL_DEVICE_ATTITUDE_STATUS, yaw in the earth frame
  ``camera``                  CAMERA_TRACKING_IMAGE_STATUS (camera component 100) with
                              CAMERA_FOV_STATUS, the gimbal pointing only roughly at the target
  ``mount``                   MOUNT_ORIENTATION
  ``mount_status``            MOUNT_STATUS (ArduPilot, centidegrees, no time)
  ``landing_target``          LANDING_TARGET, MAV_FRAME_BODY_FRD, downward camera
  ``landing_target_local``    LANDING_TARGET, MAV_FRAME_LOCAL_FRD
  ==========================  =================================================================

* optionally ``background_hz`` messages per second of other telemetry (VFR_HUD, RAW_IMU,
  SERVO_OUTPUT_RAW, ...), as an autopilot sends.

Every bearing message is built by inverting the reader's frame chain
(:mod:`mav_observer.tracking.directions`, ``docs/frames.md``), from the true line of sight with
isotropic angular noise and, optionally, gross errors (``outlier_prob``: a share of the
bearings off the line of sight by 5 to 30 degrees by default, a tracker's false lock).
Output: a tlog file and/or any pymavlink output string (127.0.0.1 in tests and examples),
plus the truth as JSON Lines, one line per bearing message, keyed by its ``t_boot_s`` (the
vehicle clock) and ``t_unix_s`` (the tlog time of the message).
"""

from __future__ import annotations

import contextlib
import heapq
import math
import struct
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, TextIO

import numpy as np

from mav_observer.geo.frames import quat_from_euler
from mav_observer.mavlink.dialect import codec, connect, mavlink
from mav_observer.tracking import directions as adapters
from sim import truth as truth_file
from sim.scenarios import Scenario
from sim.stream import perturb_bearings
from sim.vehicle import Vehicle, VehicleState

BEARINGS = (
    "gimbal",
    "gimbal_earth",
    "camera",
    "mount",
    "mount_status",
    "landing_target",
    "landing_target_local",
)
#: The reader's target name for each bearing stream (truth records use it).
TARGET_OF = {
    "gimbal": "gimbal",
    "gimbal_earth": "gimbal",
    "camera": "camera",
    "mount": "mount",
    "mount_status": "mount_status",
    "landing_target": "landing_target_0",
    "landing_target_local": "landing_target_0",
}
AUTOPILOT = 1
#: The gimbal's rangefinder: MAV_COMP_ID_GIMBAL, MAV_SENSOR_ROTATION_CUSTOM.
RANGEFINDER_COMPID = 154
RANGEFINDER_ORIENTATION = 100
#: The bearings a rangefinder on the gimbal goes with.
RANGED_BEARINGS = ("gimbal", "gimbal_earth", "mount", "mount_status")
CAMERA = 100
ORIGIN_LAT_DEG, ORIGIN_LON_DEG, ORIGIN_ALT_M = -35.363261, 149.165230, 584.0
#: ArduPilot's ``LOCATION_SCALING_FACTOR`` (m per 1e-7 deg on its sphere of 6,378,100 m,
#: ``libraries/AP_Common/Location.h``).
LOCATION_SCALING_FACTOR = 0.011131884502145034


def ardupilot_offset(
    lat0_deg: Any, lon0_deg: Any, alt0_m: Any, n_m: Any, e_m: Any, d_m: Any
) -> tuple[Any, Any, Any]:
    """Latitude and longitude (deg) and altitude (m AMSL) of the local point ``n_m, e_m,
    d_m`` from the origin, as ArduPilot's ``Location::offset`` places it (its EKF reports
    GLOBAL_POSITION_INT so, and the emitter is an ArduPilot): north over
    ``LOCATION_SCALING_FACTOR``, east over it times the cosine of the latitude half-way, both
    in 1e-7 deg. Scalars or numpy arrays."""
    dlat_e7 = np.asarray(n_m) / LOCATION_SCALING_FACTOR
    scale = np.maximum(np.cos(np.radians(lat0_deg + 0.5e-7 * dlat_e7)), 0.01)
    dlon_e7 = np.asarray(e_m) / LOCATION_SCALING_FACTOR / scale
    return lat0_deg + 1e-7 * dlat_e7, lon0_deg + 1e-7 * dlon_e7, alt0_m - np.asarray(d_m)


@dataclass(frozen=True)
class EmitterConfig:
    """What to emit. Rates in Hz, angles in degrees, times in seconds.

    ``bearing_noise_deg``: the standard deviation of the isotropic Gaussian bearing noise
    (degrees per tangent axis). ``outlier_prob``: the share of bearings, each drawn
    independently, that are gross errors instead (in [0, 1); 0: none): the true line of sight
    turned by an angle uniform in [``outlier_min_deg``, ``outlier_max_deg``] degrees about a
    uniformly random axis perpendicular to it, as a tracker locked on the wrong thing would
    report. The truth keeps the true line of sight. With ``outlier_prob`` 0 no random number
    is drawn for outliers: a seed gives the same messages as before the knob existed.
    ``bearing_noise_dof``: the bearing noise's shape: ``inf`` (the default) Gaussian; a
    finite number (> 2) of degrees of freedom draws each of its two tangent components from a
    Student-t instead, scaled to the same standard deviation ``bearing_noise_deg``: heavy
    tails without separate outliers (3: a per-axis Fisher information twice the Gaussian's,
    its Cramér-Rao bound that of Gaussian noise of ``bearing_noise_deg / sqrt(2)``).
    ``rangefinder_noise_m``: a laser rangefinder on the gimbal: with each gimbal or mount
    bearing a DISTANCE_SENSOR (orientation MAV_SENSOR_ROTATION_CUSTOM, from the gimbal's
    component 154, centimetres) of the true range plus Gaussian noise of this standard
    deviation (m); ``None``: none.
    ``origin_geodetic``: the EKF origin (latitude deg, longitude deg, altitude m AMSL) the
    local position is placed from in GLOBAL_POSITION_INT (a fleet gives each vehicle its own).
    ``system_time_offset_s``: added to SYSTEM_TIME's Unix time only (a vehicle whose GPS clock
    is off); the tlog stamps and every other clock stay true.
    """

    bearing: str = "gimbal"
    sysid: int = 1
    duration_s: float = 300.0
    attitude_hz: float = 20.0
    position_hz: float = 10.0
    bearing_hz: float = 10.0
    background_hz: float = 0.0
    bearing_noise_deg: float = 0.0
    bearing_noise_dof: float = math.inf
    velocity_noise_mps: float = 0.0
    drop_prob: float = 0.0
    outlier_prob: float = 0.0
    outlier_min_deg: float = 5.0
    outlier_max_deg: float = 30.0
    latency_s: float = 0.0
    camera_hfov_deg: float = 60.0
    camera_vfov_deg: float = 45.0
    camera_pointing_error_deg: float = 4.0
    t0_unix_s: float = 1_767_225_600.0  # 2026-01-01T00:00:00Z
    boot_at_start_s: float = 120.0  # the autopilot booted this long before the scenario starts
    landing_target_unix_time: bool = False
    rangefinder_noise_m: float | None = None
    seed: int = 0
    origin_geodetic: tuple[float, float, float] = (ORIGIN_LAT_DEG, ORIGIN_LON_DEG, ORIGIN_ALT_M)
    system_time_offset_s: float = 0.0

    def __post_init__(self) -> None:
        if self.bearing not in BEARINGS:
            raise ValueError(f"bearing must be one of {BEARINGS}, got {self.bearing!r}")
        for name in ("attitude_hz", "position_hz", "bearing_hz"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 <= self.drop_prob < 1.0:
            raise ValueError(f"drop_prob must be in [0, 1), got {self.drop_prob}")
        if not 0.0 <= self.outlier_prob < 1.0:
            raise ValueError(f"outlier_prob must be in [0, 1), got {self.outlier_prob}")
        if not 0.0 <= self.outlier_min_deg <= 180.0:
            raise ValueError(f"outlier_min_deg must be in [0, 180], got {self.outlier_min_deg}")
        if not self.outlier_min_deg <= self.outlier_max_deg <= 180.0:
            raise ValueError(
                f"outlier_max_deg must be in [outlier_min_deg, 180], got {self.outlier_max_deg}"
            )
        if not self.bearing_noise_dof > 2.0:
            raise ValueError(
                f"bearing_noise_dof must be > 2 (inf: Gaussian), got {self.bearing_noise_dof}"
            )
        if self.latency_s < 0.0 or self.duration_s <= 0.0:
            raise ValueError("latency_s must be >= 0 and duration_s > 0")


def _tangent_basis(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis ``(e1, e2)`` of the plane perpendicular to the unit ``y``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(y, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(y, e1)


@dataclass(frozen=True)
class Emission:
    """One message on the wire: when it leaves (simulated seconds from the start) and its bytes."""

    t_emit_s: float
    frame: bytes
    truth: dict[str, Any] | None = None


class Emitter:
    """Generates the messages of a scenario in time order (pure: no I/O; see :func:`run`)."""

    def __init__(self, scenario: Scenario, config: EmitterConfig, vehicle: Vehicle | None = None):
        self.scenario = scenario
        self.config = config
        self.vehicle = vehicle if vehicle is not None else Vehicle(scenario)
        self.rng = np.random.default_rng(config.seed)
        self._codecs = {
            comp: codec(config.sysid, comp) for comp in (AUTOPILOT, CAMERA, RANGEFINDER_COMPID)
        }

    # -- clocks ---------------------------------------------------------------------------
    def boot_ms(self, t: float) -> int:
        return round((self.config.boot_at_start_s + t) * 1000.0)

    def unix_s(self, t: float) -> float:
        return self.config.t0_unix_s + t

    def _pack(self, msg: Any, comp: int = AUTOPILOT) -> bytes:
        return bytes(msg.pack(self._codecs[comp]))

    # -- streams --------------------------------------------------------------------------
    def _times(self, rate_hz: float, offset_s: float = 0.0) -> np.ndarray:
        n = math.floor(self.config.duration_s * rate_hz) + 1
        return offset_s + np.arange(n) / rate_hz

    def emissions(self) -> Iterator[Emission]:
        """All messages, in emission order."""
        cfg = self.config
        streams = [
            self._heartbeats(),
            self._attitude(),
            self._position(),
            self._bearings(),
        ]
        if cfg.background_hz > 0:
            streams.append(self._background())
        yield from heapq.merge(*streams, key=lambda e: e.t_emit_s)

    def _heartbeats(self) -> Iterator[Emission]:
        for t in self._times(1.0, 0.001):
            if t > self.config.duration_s:
                break
            yield Emission(
                t,
                self._pack(
                    mavlink.MAVLink_heartbeat_message(
                        type=mavlink.MAV_TYPE_QUADROTOR,
                        autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                        base_mode=mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                        | mavlink.MAV_MODE_FLAG_SAFETY_ARMED
                        | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
                        | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED,
                        custom_mode=4,  # GUIDED
                        system_status=mavlink.MAV_STATE_ACTIVE,
                        mavlink_version=3,
                    )
                ),
            )
            yield Emission(
                t + 0.0005,
                self._pack(
                    mavlink.MAVLink_system_time_message(
                        round((self.unix_s(t) + self.config.system_time_offset_s) * 1e6),
                        self.boot_ms(t),
                    )
                ),
            )
            yield Emission(
                t + 0.0007,
                self._pack(
                    mavlink.MAVLink_sys_status_message(
                        0x3FFFF, 0x3FFFF, 0x3FFFF, 250, 16000, 1200, 80, 0, 0, 0, 0, 0, 0
                    )
                ),
            )

    def _attitude(self) -> Iterator[Emission]:
        for t in self._times(self.config.attitude_hz, 0.002):
            if t > self.config.duration_s:
                break
            s = self.vehicle.state(t)
            yield Emission(
                t,
                self._pack(
                    mavlink.MAVLink_attitude_message(
                        self.boot_ms(t), s.roll, s.pitch, s.yaw, 0.0, 0.0, 0.0
                    )
                ),
            )
            q = quat_from_euler(s.roll, s.pitch, s.yaw)
            yield Emission(
                t + 0.0001,
                self._pack(
                    mavlink.MAVLink_attitude_quaternion_message(
                        self.boot_ms(t), *q, 0.0, 0.0, 0.0, [0.0, 0.0, 0.0, 0.0]
                    )
                ),
            )

    def _position(self) -> Iterator[Emission]:
        cfg = self.config
        for t in self._times(cfg.position_hz, 0.004):
            if t > cfg.duration_s:
                break
            s = self.vehicle.state(t)
            u = s.vel_meas_ned_mps
            if cfg.velocity_noise_mps > 0:
                u = u + self.rng.normal(0.0, cfg.velocity_noise_mps, 3)
            p = s.pos_ned_m
            yield Emission(
                t,
                self._pack(
                    mavlink.MAVLink_local_position_ned_message(
                        self.boot_ms(t), p[0], p[1], p[2], u[0], u[1], u[2]
                    )
                ),
            )
            lat, lon, alt = ardupilot_offset(*cfg.origin_geodetic, p[0], p[1], p[2])
            yield Emission(
                t + 0.0001,
                self._pack(
                    mavlink.MAVLink_global_position_int_message(
                        self.boot_ms(t),
                        round(float(lat) * 1e7),
                        round(float(lon) * 1e7),
                        round(float(alt) * 1000),
                        int(-p[2] * 1000),
                        int(u[0] * 100),
                        int(u[1] * 100),
                        int(u[2] * 100),
                        int(math.degrees(s.yaw) % 360 * 100),
                    )
                ),
            )

    def _noisy_los(self, s: VehicleState) -> np.ndarray:
        """The line of sight as the sensor reports it (a unit NED vector): the Gaussian noise,
        or with probability ``outlier_prob`` a gross error (see :class:`EmitterConfig`)."""
        y = s.rel_pos_ned_m / np.linalg.norm(s.rel_pos_ned_m)
        cfg = self.config
        # outlier draws only when the knob is on: with it off the random stream is unchanged
        if cfg.outlier_prob > 0 and self.rng.random() < cfg.outlier_prob:
            return self._outlier(y)
        if cfg.bearing_noise_deg > 0 and math.isfinite(cfg.bearing_noise_dof):
            return self._student_t(y)
        if cfg.bearing_noise_deg > 0:
            y = perturb_bearings(y[None, :], math.radians(cfg.bearing_noise_deg), self.rng)[0]
        return y

    def _student_t(self, y: np.ndarray) -> np.ndarray:
        """``y`` (unit) turned by a tangent vector whose two components along an orthonormal
        basis perpendicular to it are Student-t (``bearing_noise_dof``), each of standard
        deviation ``bearing_noise_deg``."""
        cfg = self.config
        nu = cfg.bearing_noise_dof
        scale = math.radians(cfg.bearing_noise_deg) * math.sqrt((nu - 2.0) / nu)
        a, b = scale * self.rng.standard_t(nu, 2)
        e1, e2 = _tangent_basis(y)
        tangent = a * e1 + b * e2
        theta = float(np.linalg.norm(tangent))
        if theta == 0.0:
            return y
        out = math.cos(theta) * y + math.sin(theta) * tangent / theta
        return out / np.linalg.norm(out)

    def _outlier(self, y: np.ndarray) -> np.ndarray:
        """``y`` (unit) turned by an angle uniform in [outlier_min_deg, outlier_max_deg] about
        a uniformly random axis perpendicular to it."""
        cfg = self.config
        angle = math.radians(self.rng.uniform(cfg.outlier_min_deg, cfg.outlier_max_deg))
        phi = self.rng.uniform(0.0, 2.0 * math.pi)
        e1, e2 = _tangent_basis(y)
        axis = math.cos(phi) * e1 + math.sin(phi) * e2
        # Rodrigues' rotation of y about an axis perpendicular to it
        out = math.cos(angle) * y + math.sin(angle) * np.cross(axis, y)
        return out / np.linalg.norm(out)

    def _bearings(self) -> Iterator[Emission]:
        cfg = self.config
        target = TARGET_OF[cfg.bearing]
        fov_done = -1.0
        for t in self._times(cfg.bearing_hz, 0.006):
            if t > cfg.duration_s:
                break
            if cfg.bearing == "camera" and t - fov_done >= 1.0:
                fov_done = t
                yield Emission(t, self._fov_status(t))
            if cfg.drop_prob and self.rng.random() < cfg.drop_prob:
                continue
            s = self.vehicle.state(t)
            los = self._noisy_los(s)
            frames = self._bearing_frames(t, s, los)
            if not frames:
                continue
            if cfg.rangefinder_noise_m is not None and cfg.bearing in RANGED_BEARINGS:
                frames.insert(0, self._range_frame(t, s))
            truth = truth_file.record(
                t_unix_s=self.unix_s(t + cfg.latency_s),
                t_boot_s=self.boot_ms(t) / 1000.0,
                sysid=cfg.sysid,
                target=target,
                rel_pos_ned_m=s.rel_pos_ned_m,
                bias_ned_mps=self.scenario.a_mps,
                target_pos_ned_m=s.target_pos_ned_m,
                vehicle_pos_ned_m=s.pos_ned_m,
                vehicle_vel_meas_ned_mps=s.vel_meas_ned_mps,
                attitude_rpy_rad=(s.roll, s.pitch, s.yaw),
            )
            for i, frame in enumerate(frames):
                yield Emission(
                    t + cfg.latency_s + 1e-5 * i, frame, truth if i == len(frames) - 1 else None
                )

    def _range_frame(self, t: float, s: VehicleState) -> bytes:
        r = float(np.linalg.norm(s.rel_pos_ned_m))
        r += float(self.rng.normal()) * float(self.config.rangefinder_noise_m or 0.0)
        cm = max(1, min(65534, round(100.0 * r)))
        msg = mavlink.MAVLink_distance_sensor_message(
            self.boot_ms(t), 1, 65535, cm, 10, 1, RANGEFINDER_ORIENTATION, 255
        )
        return self._pack(msg, RANGEFINDER_COMPID)

    def _fov_status(self, t: float) -> bytes:
        cfg = self.config
        nan = float("nan")
        i32max = 2**31 - 1
        msg = mavlink.MAVLink_camera_fov_status_message(
            self.boot_ms(t),
            i32max,
            i32max,
            i32max,
            i32max,
            i32max,
            i32max,
            [nan, nan, nan, nan],
            cfg.camera_hfov_deg,
            cfg.camera_vfov_deg,
        )
        return self._pack(msg, CAMERA)

    def _bearing_frames(self, t: float, s: VehicleState, los: np.ndarray) -> list[bytes]:
        cfg = self.config
        kind = cfg.bearing
        yaw_c = math.atan2(los[1], los[0])
        pitch_c = -math.asin(max(-1.0, min(1.0, los[2])))
        nan = float("nan")
        if kind in ("gimbal", "gimbal_earth", "camera"):
            if kind == "camera":  # the gimbal points roughly; the tracked point is exact
                e = math.radians(cfg.camera_pointing_error_deg)
                yaw_c += e * math.sin(0.31 * t)
                pitch_c += e * math.cos(0.23 * t)
            if kind == "gimbal_earth":
                q = quat_from_euler(0.0, pitch_c, yaw_c)
                flags = (
                    adapters.GIMBAL_ROLL_LOCK
                    | adapters.GIMBAL_PITCH_LOCK
                    | adapters.GIMBAL_YAW_LOCK
                    | adapters.GIMBAL_YAW_IN_EARTH_FRAME
                )
            else:
                q = quat_from_euler(0.0, pitch_c, yaw_c - s.yaw)
                flags = (
                    adapters.GIMBAL_ROLL_LOCK
                    | adapters.GIMBAL_PITCH_LOCK
                    | adapters.GIMBAL_YAW_IN_VEHICLE_FRAME
                )
            gimbal = self._pack(
                mavlink.MAVLink_gimbal_device_attitude_status_message(
                    0, 0, self.boot_ms(t), flags, list(q), nan, nan, nan, 0, nan, nan, 1
                )
            )
            if kind != "camera":
                return [gimbal]
            r_cam = np.array(adapters.gimbal_camera_attitude(q, flags, 0, vehicle_yaw=s.yaw))
            ray = r_cam.T @ los  # line of sight in the camera frame
            if ray[0] <= 0:
                return [gimbal]
            px = 0.5 + ray[1] / ray[0] / (2 * math.tan(math.radians(cfg.camera_hfov_deg) / 2))
            py = 0.5 + ray[2] / ray[0] / (2 * math.tan(math.radians(cfg.camera_vfov_deg) / 2))
            if not (0.0 <= px <= 1.0 and 0.0 <= py <= 1.0):
                return [gimbal]
            track = self._pack(
                mavlink.MAVLink_camera_tracking_image_status_message(
                    1, 1, 4, px, py, nan, nan, nan, nan, nan, 0
                ),
                CAMERA,
            )
            return [gimbal, track]
        if kind == "mount":
            yaw_rel = math.degrees(math.remainder(yaw_c - s.yaw, 2 * math.pi))
            return [
                self._pack(
                    mavlink.MAVLink_mount_orientation_message(
                        self.boot_ms(t), 0.0, math.degrees(pitch_c), yaw_rel, math.degrees(yaw_c)
                    )
                )
            ]
        if kind == "mount_status":
            yaw_rel = math.degrees(math.remainder(yaw_c - s.yaw, 2 * math.pi))
            return [
                self._pack(
                    mavlink.MAVLink_mount_status_message(
                        0,
                        0,
                        round(math.degrees(pitch_c) * 100),
                        0,
                        round(yaw_rel * 100),
                        2,
                    )
                )
            ]
        # landing target: line of sight in the sensor frame (downward camera)
        if kind == "landing_target":
            r = np.array(s.dcm)
            sensor = r.T @ los
            frame_id = adapters.MAV_FRAME_BODY_FRD
        else:
            c, sn = math.cos(s.yaw), math.sin(s.yaw)
            sensor = np.array([c * los[0] + sn * los[1], -sn * los[0] + c * los[1], los[2]])
            frame_id = adapters.MAV_FRAME_LOCAL_FRD
        if sensor[2] <= 0.05:  # not below the vehicle: the downward camera cannot see it
            return []
        angle_x = math.atan2(sensor[1], sensor[2])
        angle_y = math.atan2(-sensor[0], sensor[2])
        t_us = (
            round(self.unix_s(t) * 1e6) if cfg.landing_target_unix_time else self.boot_ms(t) * 1000
        )
        return [
            self._pack(
                mavlink.MAVLink_landing_target_message(
                    t_us,
                    0,
                    frame_id,
                    angle_x,
                    angle_y,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    0.0,
                    [1.0, 0.0, 0.0, 0.0],
                    2,
                    0,
                )
            )
        ]

    def _background(self) -> Iterator[Emission]:
        """Other telemetry an autopilot sends, ``background_hz`` messages per second in all."""
        makers = [
            lambda t: mavlink.MAVLink_vfr_hud_message(5.0, 5.0, 90, 50, 10.0, 0.1),
            lambda t: mavlink.MAVLink_raw_imu_message(
                int(t * 1e6), 1, 2, -1000, 3, 4, 5, 100, 200, 300
            ),
            lambda t: mavlink.MAVLink_servo_output_raw_message(
                int(t * 1e6) & 0xFFFFFFFF, 0, *([1500] * 8)
            ),
            lambda t: mavlink.MAVLink_rc_channels_message(self.boot_ms(t), 8, *([1500] * 18), 200),
            lambda t: mavlink.MAVLink_scaled_pressure_message(self.boot_ms(t), 1013.2, 0.1, 2500),
            lambda t: mavlink.MAVLink_meminfo_message(1000, 30000),
            lambda t: mavlink.MAVLink_power_status_message(5000, 5000, 0),
            lambda t: mavlink.MAVLink_nav_controller_output_message(
                0.0, 0.0, 90, 90, 10, 0.0, 0.0, 0.0
            ),
            lambda t: mavlink.MAVLink_ahrs2_message(0.0, 0.0, 1.0, 584.0, -353632610, 1491652300),
            lambda t: mavlink.MAVLink_vibration_message(int(t * 1e6), 0.1, 0.1, 0.1, 0, 0, 0),
        ]
        per = self.config.background_hz / len(makers)
        for t in self._times(per, 0.008):
            if t > self.config.duration_s:
                break
            for i, make in enumerate(makers):
                yield Emission(t + i * 1e-4, self._pack(make(t)))


# -- output --------------------------------------------------------------------------


class TlogWriter:
    """Writes tlog records: 8-byte big-endian Unix microseconds, then the frame."""

    def __init__(self, path: Path) -> None:
        self._fh: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed in close()

    def write(self, t_unix_s: float, frame: bytes) -> None:
        self._fh.write(struct.pack(">Q", round(t_unix_s * 1e6)) + frame)

    def close(self) -> None:
        self._fh.close()


@dataclass
class EmitReport:
    messages: int = 0
    bearing_messages: int = 0
    wall_s: float = 0.0


def _drain(conn: Any, max_reads: int = 100) -> None:
    """Read and discard what peers sent, so that a ``udpin``/``tcpin`` link accepts them."""
    with contextlib.suppress(OSError):
        for _ in range(max_reads):
            if not conn.recv():
                return


def run(
    emitter: Emitter,
    *,
    to: str | None = None,
    tlog: Path | None = None,
    truth: Path | None = None,
    speed: float | None = None,
    stop: Any = None,
    silent: Sequence[tuple[float, float]] = (),
    on_truth: Callable[[dict[str, Any]], None] | None = None,
) -> EmitReport:
    """Emit everything. ``speed``: 1 real time, 20 twenty times faster, ``None`` or 0 as fast as
    possible. ``to``: a pymavlink output string (``udpout:127.0.0.1:14550``). ``stop``: an
    object with ``is_set()`` (a ``threading.Event``) to end early. ``silent``: windows
    ``(start_s, end_s)`` of simulated time in which nothing is sent (a link outage: the
    vehicle flies on, its messages are lost). ``on_truth``: called with each truth record
    as its bearing message is sent."""
    report = EmitReport()
    conn = connect(to, source_system=emitter.config.sysid) if to else None
    tw = TlogWriter(tlog) if tlog else None
    th: TextIO | None = open(truth, "w", encoding="utf-8") if truth else None  # noqa: SIM115
    wall0 = time.monotonic()
    poll_at = 0.0
    try:
        for em in emitter.emissions():
            if stop is not None and stop.is_set():
                break
            if silent and any(a <= em.t_emit_s < b for a, b in silent):
                continue
            if speed:
                delay = wall0 + em.t_emit_s / speed - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            t_unix = emitter.unix_s(em.t_emit_s)
            if conn is not None:
                now = time.monotonic()
                if now >= poll_at:  # a server link (udpin, tcpin) learns its peers in recv()
                    _drain(conn)
                    poll_at = now + 0.05
                conn.write(em.frame)
            if tw is not None:
                tw.write(t_unix, em.frame)
            if th is not None and em.truth is not None:
                th.write(truth_file.dumps(em.truth) + "\n")
            if on_truth is not None and em.truth is not None:
                on_truth(em.truth)
            report.messages += 1
            if em.truth is not None:
                report.bearing_messages += 1
    finally:
        if conn is not None:
            conn.close()
        if tw is not None:
            tw.close()
        if th is not None:
            th.close()
    report.wall_s = time.monotonic() - wall0
    return report


__all__ = [
    "BEARINGS",
    "TARGET_OF",
    "EmitReport",
    "Emitter",
    "EmitterConfig",
    "TlogWriter",
    "run",
]
