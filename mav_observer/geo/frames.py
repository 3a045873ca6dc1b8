"""Rotations between the frames of MAVLink messages (pure, plain floats).

Conventions (the MAVLink ones, see ``docs/frames.md``):

* Frames are right-handed. Earth frame: NED (x north, y east, z down). Body frame: FRD
  (x forward, y right, z down). A camera or gimbal frame: x along the boresight (optical
  axis), y to the image's right, z to the image's bottom.
* A quaternion is ``(w, x, y, z)`` (Hamilton). The attitude quaternion ``q_ref_body`` of a
  body in a reference frame rotates body-frame vectors into the reference frame:
  ``v_ref = R(q_ref_body) v_body``. ``(1, 0, 0, 0)`` is the null rotation.
* Euler angles are the aeronautical ZYX sequence (yaw, then pitch, then roll, intrinsic):
  ``R = Rz(yaw) Ry(pitch) Rx(roll)``. Positive pitch raises the nose (x axis) above the
  horizon, positive yaw turns it to the right (from north toward east).

Matrices are tuples of three row tuples; vectors are 3-tuples. Plain floats keep the hot path
of message conversion free of numpy's per-call overhead.
"""

from __future__ import annotations

import math

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
Quat = tuple[float, float, float, float]


def quat_norm(q: Quat) -> float:
    return math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def quat_to_dcm(q: Quat) -> Mat3:
    """Rotation matrix of a quaternion ``(w, x, y, z)`` (normalised here; must be non-zero)."""
    n = quat_norm(q)
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    return (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def euler_to_dcm(roll: float, pitch: float, yaw: float) -> Mat3:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` (radians): body FRD to earth NED for an attitude."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (
        (cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy),
        (cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy),
        (-sp, sr * cp, cr * cp),
    )


def quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    """Quaternion ``(w, x, y, z)`` of the ZYX Euler angles (radians)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_dcm(r: Mat3) -> tuple[float, float, float]:
    """``(roll, pitch, yaw)`` (radians) of a rotation matrix (ZYX)."""
    pitch = -math.asin(max(-1.0, min(1.0, r[2][0])))
    roll = math.atan2(r[2][1], r[2][2])
    yaw = math.atan2(r[1][0], r[0][0])
    return roll, pitch, yaw


def quat_mul(a: Quat, b: Quat) -> Quat:
    """Hamilton product ``a * b`` (rotation ``b`` first, then ``a``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def mat_mul(a: Mat3, b: Mat3) -> Mat3:
    return tuple(  # type: ignore[return-value]
        tuple(a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3))
        for i in range(3)
    )


def mat_vec(a: Mat3, v: Vec3) -> Vec3:
    return (
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    )


def rot_z(yaw: float) -> Mat3:
    """Rotation about the down axis by ``yaw`` (radians, positive toward east)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return ((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0))


def yaw_rotate(yaw: float, v: Vec3) -> Vec3:
    """``rot_z(yaw) v`` without building the matrix."""
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


def normalize(v: Vec3) -> Vec3:
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return (v[0] / n, v[1] / n, v[2] / n)


def direction_from_angles(pitch: float, yaw: float) -> Vec3:
    """Unit x axis of a frame at ``pitch`` and ``yaw`` (radians, roll does not move it):
    ``(cos p cos y, cos p sin y, -sin p)``."""
    cp = math.cos(pitch)
    return (cp * math.cos(yaw), cp * math.sin(yaw), -math.sin(pitch))


def wrap_pi(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi
