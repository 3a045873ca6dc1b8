"""From MAVLink message fields to bearings in NED: the frame chains (pure, plain floats).

Each function takes the fields it needs (and, where needed, the vehicle's attitude) and returns
the camera attitude ``R_ned_cam`` (camera frame: x boresight, y image right, z image down) or a
line of sight in NED. A message that cannot give a bearing raises :class:`Skip` with a short
reason, which the tracker counts. ``docs/frames.md`` writes every chain out.
"""

from __future__ import annotations

import math

from mav_observer.errors import MavObserverError
from mav_observer.geo.frames import (
    Mat3,
    Quat,
    Vec3,
    direction_from_angles,
    euler_to_dcm,
    mat_mul,
    mat_vec,
    normalize,
    quat_norm,
    quat_to_dcm,
    rot_z,
    yaw_rotate,
)

# GIMBAL_DEVICE_FLAGS
GIMBAL_RETRACT = 1
GIMBAL_NEUTRAL = 2
GIMBAL_ROLL_LOCK = 4
GIMBAL_PITCH_LOCK = 8
GIMBAL_YAW_LOCK = 16
GIMBAL_YAW_IN_VEHICLE_FRAME = 32
GIMBAL_YAW_IN_EARTH_FRAME = 64
#: GIMBAL_DEVICE_ERROR_FLAGS that make the reported attitude unusable (limits and "no
#: manager" do not: the attitude is still what the gimbal points at).
GIMBAL_BAD_FAILURES = (
    8 | 16 | 32 | 64 | 128 | 256
)  # encoder, power, motor, software, comms, calibrating

# MAV_FRAME values used by LANDING_TARGET
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_LOCAL_OFFSET_NED = 7
MAV_FRAME_BODY_FRD = 12
MAV_FRAME_LOCAL_FRD = 20

# CAMERA_TRACKING_STATUS_FLAGS
TRACKING_ACTIVE = 1
TRACKING_ERROR = 2

UNIX_US_MIN = 10**15  # time_usec above this is Unix time (after 2001-09), below it boot time

_EX: Vec3 = (1.0, 0.0, 0.0)


class Skip(MavObserverError):
    """A message that gives no bearing; ``reason`` is the counter's key."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


def _finite(reason: str, *values: float) -> None:
    for v in values:
        if not math.isfinite(v):
            raise Skip(reason, f"non-finite value {v!r}")


def check_attitude(roll: float, pitch: float, yaw: float) -> None:
    """Vehicle attitude (radians) must be finite and within the ATTITUDE ranges."""
    _finite("non_finite", roll, pitch, yaw)
    if (
        abs(roll) > math.pi + 1e-6
        or abs(pitch) > math.pi / 2 + 1e-6
        or abs(yaw) > 2 * math.pi + 1e-6
    ):
        raise Skip("attitude_out_of_range", f"roll={roll}, pitch={pitch}, yaw={yaw}")


def check_quaternion(q: Quat) -> Quat:
    """Finite, non-zero quaternion (normalised if within 10 % of unit length)."""
    _finite("non_finite", *q)
    n = quat_norm(q)
    if n < 1e-6:
        raise Skip("zero_quaternion", f"q={q}")
    if abs(n - 1.0) > 0.1:
        raise Skip("quaternion_not_unit", f"|q|={n:.3g}")
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


# -- gimbal -------------------------------------------------------------------------


def gimbal_yaw_frame(flags: int) -> str:
    """``"vehicle"`` or ``"earth"``: the frame of the quaternion's yaw, per the message
    definition (IN_VEHICLE/IN_EARTH flags; if neither, YAW_LOCK decides)."""
    if flags & GIMBAL_YAW_IN_EARTH_FRAME:
        return "earth"
    if flags & GIMBAL_YAW_IN_VEHICLE_FRAME:
        return "vehicle"
    return "earth" if flags & GIMBAL_YAW_LOCK else "vehicle"


def gimbal_needs_vehicle_yaw(flags: int, delta_yaw: float = math.nan) -> bool:
    """True if a GIMBAL_DEVICE_ATTITUDE_STATUS with these ``flags`` (and ``delta_yaw``)
    needs the vehicle's yaw to give a direction in NED (its yaw is in the vehicle frame and
    the message does not carry the vehicle's yaw itself)."""
    if gimbal_yaw_frame(flags) == "earth":
        return False
    new_style = flags & (GIMBAL_YAW_IN_VEHICLE_FRAME | GIMBAL_YAW_IN_EARTH_FRAME)
    return not (new_style and math.isfinite(delta_yaw))


def gimbal_camera_attitude(
    q: Quat,
    flags: int,
    failure_flags: int,
    *,
    vehicle_yaw: float | None,
    vehicle_dcm: Mat3 | None = None,
    delta_yaw: float = math.nan,
    angles: str = "flags",
) -> Mat3:
    """GIMBAL_DEVICE_ATTITUDE_STATUS to the camera attitude ``R_ned_cam``.

    ``angles="flags"`` (default): roll and pitch as the flags and the message definition say
    (horizon-relative for a stabilising gimbal); yaw in the vehicle frame is composed with the
    vehicle's yaw (``delta_yaw`` if the message carries it with the IN_VEHICLE/IN_EARTH
    flags, else ``vehicle_yaw``):
    ``R_ned_cam = Rz(yaw_vehicle) R(q)``; in the earth frame ``R_ned_cam = R(q)``.

    ``angles="body"``: the quaternion is relative to the vehicle body (ArduPilot servo mounts
    report body-relative servo angles whatever the flags say): ``R_ned_cam = R_ned_body R(q)``.
    """
    if failure_flags & GIMBAL_BAD_FAILURES:
        raise Skip("gimbal_failure", f"failure_flags=0x{failure_flags:x}")
    if flags & (GIMBAL_RETRACT | GIMBAL_NEUTRAL):
        raise Skip("gimbal_not_tracking", f"flags=0x{flags:x} (retract or neutral)")
    r_q = quat_to_dcm(check_quaternion(q))
    if angles == "body":
        if vehicle_dcm is None:
            raise Skip("no_attitude", "a body-relative gimbal needs the vehicle attitude")
        return mat_mul(vehicle_dcm, r_q)
    if gimbal_yaw_frame(flags) == "earth":
        return r_q
    return mat_mul(rot_z(gimbal_vehicle_yaw(flags, delta_yaw, vehicle_yaw)), r_q)


def gimbal_vehicle_yaw(flags: int, delta_yaw: float, vehicle_yaw: float | None) -> float:
    """The vehicle yaw (rad) a gimbal quaternion with its yaw in the vehicle frame is
    composed with: the message's ``delta_yaw`` when it came with the IN_VEHICLE/IN_EARTH
    flags (without them, older senders' missing extension field decodes as 0.0 and must be
    ignored, as the definition says), else ``vehicle_yaw``; :class:`Skip` when neither."""
    new_style = flags & (GIMBAL_YAW_IN_VEHICLE_FRAME | GIMBAL_YAW_IN_EARTH_FRAME)
    yaw = delta_yaw if new_style and math.isfinite(delta_yaw) else vehicle_yaw
    if yaw is None:
        raise Skip("no_attitude", "yaw in the vehicle frame needs the vehicle yaw")
    return yaw


def gimbal_boresight(
    q: Quat,
    flags: int,
    failure_flags: int,
    *,
    vehicle_yaw: float | None,
    delta_yaw: float = math.nan,
) -> Vec3:
    """The boresight (camera x axis) in NED of a GIMBAL_DEVICE_ATTITUDE_STATUS with
    ``angles="flags"``: the first column of :func:`gimbal_camera_attitude`, computed without
    building the matrices (this runs for every gimbal message)."""
    if failure_flags & GIMBAL_BAD_FAILURES:
        raise Skip("gimbal_failure", f"failure_flags=0x{failure_flags:x}")
    if flags & (GIMBAL_RETRACT | GIMBAL_NEUTRAL):
        raise Skip("gimbal_not_tracking", f"flags=0x{flags:x} (retract or neutral)")
    w, x, y, z = check_quaternion(q)
    bx, by, bz = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)
    if gimbal_yaw_frame(flags) == "earth":
        return (bx, by, bz)
    return yaw_rotate(gimbal_vehicle_yaw(flags, delta_yaw, vehicle_yaw), (bx, by, bz))


# -- camera tracking ---------------------------------------------------------------


def fov_from_camera_information(
    focal_length_mm: float, sensor_h_mm: float, sensor_v_mm: float
) -> tuple[float, float] | None:
    """``(hfov, vfov)`` in radians from CAMERA_INFORMATION, or ``None`` if unknown."""
    vals = (focal_length_mm, sensor_h_mm, sensor_v_mm)
    if not all(math.isfinite(v) and v > 0.0 for v in vals):
        return None
    return (
        2.0 * math.atan(sensor_h_mm / (2.0 * focal_length_mm)),
        2.0 * math.atan(sensor_v_mm / (2.0 * focal_length_mm)),
    )


def tracking_ray(point_x: float, point_y: float, hfov: float, vfov: float) -> Vec3:
    """Pinhole ray to a tracked image point, camera frame (x boresight, y right, z down).

    ``point_x``, ``point_y`` normalised 0..1 from the image's top-left (CAMERA_TRACKING_IMAGE_
    STATUS); ``hfov``, ``vfov`` the full fields of view (radians). Not normalised.
    """
    _finite("non_finite", point_x, point_y)
    if not (-0.05 <= point_x <= 1.05 and -0.05 <= point_y <= 1.05):
        raise Skip("out_of_range", f"tracked point ({point_x}, {point_y}) outside the image")
    if not (0.0 < hfov < math.pi and 0.0 < vfov < math.pi):
        raise Skip("no_fov", f"hfov={hfov}, vfov={vfov}")
    return (
        1.0,
        (2.0 * point_x - 1.0) * math.tan(0.5 * hfov),
        (2.0 * point_y - 1.0) * math.tan(0.5 * vfov),
    )


def tracking_status_usable(tracking_status: int) -> None:
    if tracking_status & TRACKING_ERROR or not tracking_status & TRACKING_ACTIVE:
        raise Skip("tracking_inactive", f"tracking_status={tracking_status}")


# -- mount --------------------------------------------------------------------------


def mount_orientation_direction(
    pitch_deg: float, yaw_deg: float, yaw_absolute_deg: float, vehicle_yaw: float | None
) -> Vec3:
    """MOUNT_ORIENTATION to the boresight in NED: pitch in the global frame (positive up),
    yaw relative to the vehicle, or ``yaw_absolute`` (from north) when it is valid. Roll does
    not move the boresight."""
    _finite("non_finite", pitch_deg)
    if abs(pitch_deg) > 90.0 + 1e-6:
        raise Skip("attitude_out_of_range", f"pitch={pitch_deg} deg")
    if math.isfinite(yaw_absolute_deg):
        yaw = math.radians(yaw_absolute_deg)
    else:
        _finite("non_finite", yaw_deg)
        if vehicle_yaw is None:
            raise Skip("no_attitude", "a vehicle-relative mount yaw needs the vehicle yaw")
        yaw = vehicle_yaw + math.radians(yaw_deg)
    return direction_from_angles(math.radians(pitch_deg), yaw)


def mount_status_direction(
    pointing_a_cdeg: int, pointing_c_cdeg: int, vehicle_yaw: float | None, *, yaw_frame: str
) -> Vec3:
    """ArduPilot MOUNT_STATUS (centidegrees: ``pointing_a`` pitch, ``pointing_b`` roll,
    ``pointing_c`` yaw) to the boresight in NED. Pitch is earth-frame (positive up); yaw is
    relative to the vehicle (``yaw_frame="vehicle"``, ArduPilot's mount backends) or to north
    (``"earth"``)."""
    pitch = math.radians(pointing_a_cdeg / 100.0)
    if abs(pitch) > math.pi / 2 + 1e-6:
        raise Skip("attitude_out_of_range", f"pointing_a={pointing_a_cdeg} cdeg")
    yaw = math.radians(pointing_c_cdeg / 100.0)
    if yaw_frame == "vehicle":
        if vehicle_yaw is None:
            raise Skip("no_attitude", "a vehicle-relative mount yaw needs the vehicle yaw")
        yaw += vehicle_yaw
    return direction_from_angles(pitch, yaw)


# -- landing target ---------------------------------------------------------------


def landing_target_direction(
    *,
    frame: int,
    angle_x: float,
    angle_y: float,
    position_valid: int,
    x: float,
    y: float,
    z: float,
    vehicle_dcm: Mat3 | None,
    vehicle_yaw: float | None,
    vehicle_pos_ned: Vec3 | None = None,
    sensor: Mat3 | None = None,
) -> Vec3:
    """LANDING_TARGET to the line of sight in NED (not normalised).

    Sensor frame line of sight, ArduPilot's convention for a downward camera (top of the image
    toward the nose): ``(-tan angle_y, tan angle_x, 1)``, or ``(x, y, z)`` when
    ``position_valid``. ``sensor`` rotates it into the body (or heading) axes (default
    identity: camera looking down, ArduPilot's PLND_ORIENT 25 with PLND_YAW_ALIGN 0).

    * ``MAV_FRAME_BODY_FRD`` (12): rotated by the full vehicle attitude.
    * ``MAV_FRAME_LOCAL_FRD`` (20): heading-aligned and level: rotated by the vehicle yaw only
      (``Rz(+yaw)``; ArduPilot's receiver rotates by ``-yaw``, a reported bug, #31651).
    * ``MAV_FRAME_LOCAL_NED`` (1) with ``position_valid``: the target's absolute local position
      (PX4's convention): line of sight = target minus vehicle position.
    * ``MAV_FRAME_LOCAL_OFFSET_NED`` (7) with ``position_valid``: the target's position
      relative to the vehicle, NED: the line of sight itself (ArduPilot's precision-landing
      measurement, ``PL`` ``mX, mY, mZ``, replayed from a DataFlash log).
    """
    if position_valid == 1:
        _finite("non_finite", x, y, z)
        if frame == MAV_FRAME_LOCAL_NED:
            if vehicle_pos_ned is None:
                raise Skip("no_position", "LOCAL_NED target position needs the vehicle position")
            los = (x - vehicle_pos_ned[0], y - vehicle_pos_ned[1], z - vehicle_pos_ned[2])
            if los[0] == 0.0 and los[1] == 0.0 and los[2] == 0.0:
                raise Skip("zero_length", "target at the vehicle")
            return los
        if frame == MAV_FRAME_LOCAL_OFFSET_NED:
            if x == 0.0 and y == 0.0 and z == 0.0:
                raise Skip("zero_length", "target at the vehicle")
            return (x, y, z)
        los = (x, y, z)
    elif position_valid == 0:
        _finite("non_finite", angle_x, angle_y)
        if abs(angle_x) >= math.pi / 2 or abs(angle_y) >= math.pi / 2:
            raise Skip("out_of_range", f"angle_x={angle_x}, angle_y={angle_y}")
        los = (-math.tan(angle_y), math.tan(angle_x), 1.0)
    else:
        raise Skip("invalid_frame", f"position_valid={position_valid}")
    if los[0] == 0.0 and los[1] == 0.0 and los[2] == 0.0:
        raise Skip("zero_length", "line of sight (0, 0, 0)")
    if sensor is not None:
        los = mat_vec(sensor, los)
    if frame == MAV_FRAME_BODY_FRD:
        if vehicle_dcm is None:
            raise Skip("no_attitude", "a body-frame line of sight needs the vehicle attitude")
        return mat_vec(vehicle_dcm, los)
    if frame == MAV_FRAME_LOCAL_FRD:
        if vehicle_yaw is None:
            raise Skip("no_attitude", "a heading-frame line of sight needs the vehicle yaw")
        return yaw_rotate(vehicle_yaw, los)
    raise Skip("unsupported_frame", f"frame={frame}")


def landing_target_sensor(orientation: str, yaw_align_deg: float = 0.0) -> Mat3 | None:
    """Sensor-to-body rotation of a landing-target camera, as ArduPilot's PLND_ORIENT and
    PLND_YAW_ALIGN: ``"down"`` (the default, 25) or ``"forward"`` (0), then the yaw
    alignment about the sensor's optical axis frame. ``None`` for down with no alignment."""
    r = None
    if yaw_align_deg:
        r = rot_z(math.radians(yaw_align_deg))
    if orientation == "forward":
        # ArduPilot: rotate(PITCH_90) brings the down-looking vector to the front
        p90 = euler_to_dcm(0.0, math.pi / 2, 0.0)
        r = p90 if r is None else mat_mul(p90, r)
    elif orientation != "down":
        raise ValueError(
            f"landing target orientation must be 'down' or 'forward', got {orientation!r}"
        )
    return r


def time_usec_kind(time_usec: int) -> str:
    """``"unix"`` or ``"boot"``, by magnitude (the LANDING_TARGET definition)."""
    return "unix" if time_usec >= UNIX_US_MIN else "boot"


def boresight(r_ned_cam: Mat3) -> Vec3:
    """The camera's x axis in NED."""
    return (r_ned_cam[0][0], r_ned_cam[1][0], r_ned_cam[2][0])


__all__ = [
    "Skip",
    "boresight",
    "check_attitude",
    "check_quaternion",
    "fov_from_camera_information",
    "gimbal_boresight",
    "gimbal_camera_attitude",
    "gimbal_yaw_frame",
    "landing_target_direction",
    "landing_target_sensor",
    "mount_orientation_direction",
    "mount_status_direction",
    "normalize",
    "time_usec_kind",
    "tracking_ray",
    "tracking_status_usable",
]
