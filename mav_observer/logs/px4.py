"""A PX4 ULog's topics as the MAVLink messages the tracker reads, loaded with pyulog.

On the autopilot's boot clock (each message's ``timestamp``, microseconds):

* ``vehicle_local_position`` (instance 0), where ``xy_valid`` and ``v_xy_valid``: ``x, y, z``
  and ``vx, vy, vz`` in the EKF's local NED frame -> LOCAL_POSITION_NED; its reference
  ``ref_lat, ref_lon`` (degrees), ``ref_alt`` (m) where ``xy_global`` -> GPS_GLOBAL_ORIGIN;
* ``vehicle_attitude`` ``q`` (w, x, y, z, body to NED) -> ATTITUDE_QUATERNION;
* ``gimbal_device_attitude_status`` (``device_flags``, ``q``, ``failure_flags``,
  ``delta_yaw``, ``gimbal_device_id``) -> GIMBAL_DEVICE_ATTITUDE_STATUS, the MAVLink
  message's own fields;
* ``mount_orientation`` ``attitude_euler_angle`` (roll, pitch against the horizon, yaw against
  the vehicle's heading, rad) -> MOUNT_ORIENTATION;
* ``landing_target_pose`` where ``abs_pos_valid``: the target's local position ``x_abs,
  y_abs, z_abs`` -> LANDING_TARGET in MAV_FRAME_LOCAL_NED (PX4's convention).

PX4's logger does not record ``gimbal_device_attitude_status`` by default: a line
``gimbal_device_attitude_status 0`` in ``etc/logging/logger_topics.txt`` on the SD card adds it
(``docs/frames.md``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from mav_observer.logs.messages import Stream, maker

TOPICS = (
    "vehicle_local_position", "vehicle_attitude", "gimbal_device_attitude_status",
    "mount_orientation", "landing_target_pose", "distance_sensor",
)  # fmt: skip
#: ``distance_sensor``'s orientation of a sensor not fixed to the body (a gimbal's):
#: PX4's ROTATION_CUSTOM, MAVLink's MAV_SENSOR_ROTATION_CUSTOM.
ROTATION_CUSTOM = 100
#: The line of the logger's topic file that records the gimbal's attitude.
GIMBAL_TOPIC_LINE = "gimbal_device_attitude_status 0"
MAV_FRAME_LOCAL_NED = 1


class ULogError(Exception):
    """A file pyulog cannot read at all (not a ULog, a foreign or cut header)."""


def load(path: Path) -> Any:
    """The ULog with only the topics replay reads (pyulog's ``message_name_filter_list``)."""
    from pyulog import ULog

    try:
        return ULog(str(path), list(TOPICS), disable_str_exceptions=True)
    except Exception as exc:  # pyulog raises plain exceptions on a bad header or a cut file
        raise ULogError(f"not a readable ULog ({type(exc).__name__}: {exc})") from exc


def _topic(ulog: Any, name: str) -> dict[str, np.ndarray[Any, Any]] | None:
    for d in ulog.data_list:
        if d.name == name and d.multi_id == 0 and len(d.data.get("timestamp", ())):
            return d.data
    return None


def _arr(d: dict[str, np.ndarray[Any, Any]], key: str, default: float = math.nan) -> Any:
    v = d.get(key)
    return np.full(len(d["timestamp"]), default) if v is None else v


def streams(ulog: Any, notes: list[str]) -> list[Stream]:
    """The log's messages as :class:`Stream` s; what it lacks appended to ``notes``."""
    out: list[Stream] = []
    lp = _topic(ulog, "vehicle_local_position")
    if lp is None:
        notes.append("no vehicle_local_position: no velocity")
    else:
        out += _local_position(lp, notes)
    att = _topic(ulog, "vehicle_attitude")
    if att is None:
        notes.append("no vehicle_attitude: no vehicle attitude")
    else:
        t = att["timestamp"].astype(np.int64)
        q = [att[f"q[{k}]"].astype(float).tolist() for k in range(4)]
        ms = (t // 1000).tolist()
        make_att = maker("ATTITUDE_QUATERNION")
        out.append(Stream(t, 1, lambda i: make_att(
            time_boot_ms=ms[i], q1=q[0][i], q2=q[1][i], q3=q[2][i], q4=q[3][i])))  # fmt: skip
    gimbal = _topic(ulog, "gimbal_device_attitude_status")
    mount = _topic(ulog, "mount_orientation")
    if gimbal is not None:
        out.append(_gimbal(gimbal))
    if mount is not None:
        out.append(_mount(mount))
    lt = _topic(ulog, "landing_target_pose")
    if lt is not None:
        out.append(_landing_target(lt))
    for d in ulog.data_list:  # every instance: one of them may be on the gimbal
        if d.name == "distance_sensor" and len(d.data.get("timestamp", ())):
            out.append(_distance(d.data))
    if gimbal is None and mount is None and lt is None:
        notes.append(
            "no gimbal_device_attitude_status, mount_orientation or landing_target_pose: "
            f"PX4 logs the gimbal's attitude with the line '{GIMBAL_TOPIC_LINE}' in "
            "etc/logging/logger_topics.txt on the SD card"
        )
    return out


def _local_position(lp: dict[str, np.ndarray[Any, Any]], notes: list[str]) -> list[Stream]:
    t = lp["timestamp"].astype(np.int64)
    valid = (_arr(lp, "xy_valid", 1) != 0) & (_arr(lp, "v_xy_valid", 1) != 0)
    invalid = int(np.count_nonzero(~valid))
    if invalid:  # the estimator's own word: such a position or velocity is not to be used
        notes.append(
            f"vehicle_local_position: {invalid} of {len(t)} samples without xy_valid and "
            "v_xy_valid, not used"
        )
    x, y, z, vx, vy, vz = (lp[k].astype(float).tolist() for k in
                           ("x", "y", "z", "vx", "vy", "vz"))  # fmt: skip
    ms = (t // 1000).tolist()
    ok = valid.tolist()
    make = maker("LOCAL_POSITION_NED")
    out = [
        Stream(
            t,
            2,
            lambda i: (
                make(time_boot_ms=ms[i], x=x[i], y=y[i], z=z[i], vx=vx[i], vy=vy[i], vz=vz[i])
                if ok[i]
                else None
            ),
        )
    ]
    glob = _arr(lp, "xy_global", 0) != 0
    lat, lon, alt = (_arr(lp, k) for k in ("ref_lat", "ref_lon", "ref_alt"))
    ref = np.stack([lat, lon, alt], axis=1)
    finite = glob & np.isfinite(ref).all(axis=1) & ((lat != 0) | (lon != 0))
    idx = np.flatnonzero(finite)
    if len(idx):
        changed = np.ones(len(idx), bool)
        changed[1:] = np.any(ref[idx[1:]] != ref[idx[:-1]], axis=1)
        sel = idx[changed]
        make_o = maker("GPS_GLOBAL_ORIGIN")
        rows = ref[sel].tolist()
        ts = t[sel]
        out.append(Stream(ts, 0, lambda i: make_o(
            latitude=round(rows[i][0] * 1e7), longitude=round(rows[i][1] * 1e7),
            altitude=round(rows[i][2] * 1e3), time_usec=int(ts[i]))))  # fmt: skip
    return out


def _gimbal(g: dict[str, np.ndarray[Any, Any]]) -> Stream:
    t = g["timestamp"].astype(np.int64)
    q = [g[f"q[{k}]"].astype(float).tolist() for k in range(4)]
    flags = _arr(g, "device_flags", 0).astype(int).tolist()
    fail = _arr(g, "failure_flags", 0).astype(int).tolist()
    dyaw = _arr(g, "delta_yaw").astype(float).tolist()
    dev = _arr(g, "gimbal_device_id", 0).astype(int).tolist()
    ms = (t // 1000).tolist()
    make = maker("GIMBAL_DEVICE_ATTITUDE_STATUS")
    return Stream(t, 4, lambda i: make(
        time_boot_ms=ms[i], flags=flags[i], q=[q[0][i], q[1][i], q[2][i], q[3][i]],
        failure_flags=fail[i], delta_yaw=dyaw[i], delta_yaw_velocity=math.nan,
        gimbal_device_id=dev[i]))  # fmt: skip


def _mount(m: dict[str, np.ndarray[Any, Any]]) -> Stream:
    t = m["timestamp"].astype(np.int64)
    roll, pitch, yaw = (np.degrees(m[f"attitude_euler_angle[{k}]"].astype(float)).tolist()
                        for k in range(3))  # fmt: skip
    ms = (t // 1000).tolist()
    make = maker("MOUNT_ORIENTATION")
    return Stream(t, 4, lambda i: make(time_boot_ms=ms[i], roll=roll[i], pitch=pitch[i],
                                       yaw=yaw[i], yaw_absolute=math.nan))  # fmt: skip


def _distance(ds: dict[str, np.ndarray[Any, Any]]) -> Stream:
    """``distance_sensor`` of orientation ROTATION_CUSTOM (a rangefinder on the gimbal) ->
    DISTANCE_SENSOR (centimetres; its variance as the covariance, cm^2); the others (a downward
    rangefinder) are not a target's range."""
    t = ds["timestamp"].astype(np.int64)
    on_gimbal = (_arr(ds, "orientation", 0) == ROTATION_CUSTOM).tolist()
    cm = np.round(100.0 * _arr(ds, "current_distance").astype(float))
    lo = np.round(100.0 * _arr(ds, "min_distance", 0.0).astype(float))
    hi = np.round(100.0 * _arr(ds, "max_distance", 655.0).astype(float))
    var = 1e4 * _arr(ds, "variance", 0.0).astype(float)
    cov = np.where((var > 0) & (var < 255), np.round(var), 255).astype(np.int64).tolist()
    ok = (np.isfinite(cm) & (cm > 0) & (cm < 65535)).tolist()
    cm_l = np.where(np.isfinite(cm), cm, 0).astype(np.int64).tolist()
    lo_l = np.clip(np.nan_to_num(lo), 0, 65535).astype(np.int64).tolist()
    hi_l = np.clip(np.nan_to_num(hi, nan=65535), 0, 65535).astype(np.int64).tolist()
    ms = (t // 1000).tolist()
    make = maker("DISTANCE_SENSOR")
    return Stream(t, 3, lambda i: make(
        time_boot_ms=ms[i], min_distance=lo_l[i], max_distance=hi_l[i],
        current_distance=cm_l[i], orientation=ROTATION_CUSTOM, covariance=cov[i],
    ) if on_gimbal[i] and ok[i] else None)  # fmt: skip


def _landing_target(lt: dict[str, np.ndarray[Any, Any]]) -> Stream:
    t = lt["timestamp"].astype(np.int64)
    ok = (_arr(lt, "abs_pos_valid", 0) != 0).tolist()
    x, y, z = (_arr(lt, k).astype(float).tolist() for k in ("x_abs", "y_abs", "z_abs"))
    make = maker("LANDING_TARGET")
    return Stream(t, 3, lambda i: make(
        time_usec=int(t[i]), frame=MAV_FRAME_LOCAL_NED, x=x[i], y=y[i], z=z[i],
        position_valid=1, q=[1.0, 0.0, 0.0, 0.0]) if ok[i] else None)  # fmt: skip
