"""The tracker's readers, one per bearing source: a message to a direction in NED.

Each ``_on_<message>`` times the message on the autopilot's clock and hands it to
``_when_attitude``, which runs its ``_<message>_at`` once the vehicle attitude of its time
is known; that turns the message into a unit direction in NED through the frame chains of
:mod:`~mav_observer.tracking.directions` and hands it to the tracker's ``_bearing``. A new
bearing source is a pair of such methods and an entry in the tracker's handlers.
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING, Any

from mav_observer.geo.frames import Vec3, euler_to_dcm, mat_vec
from mav_observer.geo.gimbal_frame import GimbalFrameDetector
from mav_observer.outputs.records import EstimateRecord
from mav_observer.tracking import directions as adapters
from mav_observer.tracking.directions import Skip
from mav_observer.tracking.vehicle import Vehicle, gimbal_target

if TYPE_CHECKING:
    pass

log = logging.getLogger("mav_observer.tracking.tracker")
#: A vehicle position further than this (s) from a landing target's time is not used.
POSITION_MAX_AGE_S = 1.0
#: The bearing messages of a gimbal or mount: a rangefinder on the gimbal measures along them.
GIMBAL_SOURCES = frozenset(("GIMBAL_DEVICE_ATTITUDE_STATUS", "MOUNT_ORIENTATION", "MOUNT_STATUS"))
#: DISTANCE_SENSOR's orientation of a sensor not fixed to the body (a gimbal's).
MAV_SENSOR_ROTATION_CUSTOM = 100
#: MAVLink's gimbal components (MAV_COMP_ID_GIMBAL, MAV_COMP_ID_GIMBAL2 .. 6).
GIMBAL_COMPIDS = frozenset((154, 171, 172, 173, 174, 175))


class BearingReaders:
    """The bearing sources' readers; mixed into :class:`~mav_observer.tracking.tracker.Tracker`."""

    def _on_gimbal(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        tb = self._timed(veh, msg.get_srcComponent(), msg.time_boot_ms * 1e-3, t)
        # device 0 (a gimbal that gives no id) is target "gimbal", as device 1
        angles = self._gimbal_angles(veh, max(getattr(msg, "gimbal_device_id", 0), 1))
        needs = angles != "flags" or adapters.gimbal_needs_vehicle_yaw(
            msg.flags, getattr(msg, "delta_yaw", math.nan)
        )
        self._when_attitude(veh, tb, t, msg, out, self._gimbal_at, needs)

    def _gimbal_angles(self, veh: Vehicle, device: int) -> str:
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
        self, veh: Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
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
        target = gimbal_target(dev)
        if "gimbal" in self.enabled:
            self._bearing(veh, target, "GIMBAL_DEVICE_ATTITUDE_STATUS", tb, t, direction, out)

    def _detect_gimbal_frame(
        self,
        veh: Vehicle,
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
            target = gimbal_target(dev)
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
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        tb = self._timed(veh, msg.get_srcComponent(), msg.time_boot_ms * 1e-3, t)
        needs = not math.isfinite(getattr(msg, "yaw_absolute", math.nan))
        self._when_attitude(veh, tb, t, msg, out, self._mount_orientation_at, needs)

    def _mount_orientation_at(
        self, veh: Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
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

    def _on_mount_status(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        tb = self._untimed(veh, t)
        needs = self.config.mount_status_yaw == "vehicle"
        self._when_attitude(veh, tb, t, msg, out, self._mount_status_at, needs)

    def _mount_status_at(
        self, veh: Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        att = self._vehicle_attitude(veh, tb)
        direction = adapters.mount_status_direction(
            msg.pointing_a,
            msg.pointing_c,
            None if att is None else att[2],
            yaw_frame=self.config.mount_status_yaw,
        )
        self._bearing(veh, "mount_status", "MOUNT_STATUS", tb, t, direction, out)

    def _on_camera_fov(self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]) -> None:
        if not (
            math.isfinite(msg.hfov) and math.isfinite(msg.vfov) and msg.hfov > 0 and msg.vfov > 0
        ):
            raise Skip("no_fov", "CAMERA_FOV_STATUS without a field of view")
        veh.fov[msg.get_srcComponent()] = (math.radians(msg.hfov), math.radians(msg.vfov))

    def _on_camera_information(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        fov = adapters.fov_from_camera_information(
            msg.focal_length, msg.sensor_size_h, msg.sensor_size_v
        )
        if fov is None:
            raise Skip("no_fov", "CAMERA_INFORMATION without focal length and sensor size")
        veh.fov.setdefault(msg.get_srcComponent(), fov)

    def _fov(self, veh: Vehicle, compid: int) -> tuple[float, float]:
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
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        adapters.tracking_status_usable(msg.tracking_status)
        tb = self._untimed(veh, t)
        # waits behind the gimbal message it goes with, if that one waits
        self._when_attitude(veh, tb, t, msg, out, self._camera_tracking_at, False)

    def _camera_tracking_at(
        self, veh: Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
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

    def _on_distance_sensor(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        """A rangefinder on the gimbal (a gimbal component's, or of orientation
        MAV_SENSOR_ROTATION_CUSTOM): its range waits for the gimbal's next bearing. Others (a
        downward rangefinder of the vehicle) are not a target's range and are left alone."""
        comp = msg.get_srcComponent()
        if msg.orientation != MAV_SENSOR_ROTATION_CUSTOM and comp not in GIMBAL_COMPIDS:
            return
        d, lo, hi = msg.current_distance, msg.min_distance, msg.max_distance
        if not (d > 0 and lo <= d <= hi):
            raise Skip("range_out_of_bounds", f"DISTANCE_SENSOR {d} cm outside [{lo}, {hi}] cm")
        tb = self._timed(veh, comp, msg.time_boot_ms * 1e-3, t)
        cov = msg.covariance  # cm^2; 0 and 255: unknown
        sd = math.sqrt(cov) * 0.01 if 0 < cov < 255 else self.config.range_noise_m
        veh.gimbal_range = (tb, d * 0.01, sd)

    def _on_landing_target(
        self, veh: Vehicle, t: float, msg: Any, out: list[EstimateRecord]
    ) -> None:
        comp = msg.get_srcComponent()
        if adapters.time_usec_kind(msg.time_usec) == "unix":
            tb = self._untimed(veh, msg.time_usec * 1e-6)
        else:
            tb = self._timed(veh, ("landing_target", comp), msg.time_usec * 1e-6, t)
        self._when_attitude(veh, tb, t, msg, out, self._landing_target_at, True)

    def _landing_target_at(
        self, veh: Vehicle, tb: float, t: float, msg: Any, out: list[EstimateRecord]
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
        dist = getattr(msg, "distance", 0.0)
        rng = dist if math.isfinite(dist) and dist > 0.0 else None  # 0: not measured
        self._bearing(
            veh, f"landing_target_{msg.target_num}", "LANDING_TARGET", tb, t, los, out, rng
        )
