"""Write a tlog's flight as an ArduPilot DataFlash ``.bin`` or a PX4 ``.ulg`` (same data).

``python -m sim convert IN.tlog OUT.bin`` (or ``OUT.ulg``): the messages the tracker reads
become the records the autopilot's own logger writes for them, on the same boot clock, so an
emitted or injected tlog, its truth, and its DataFlash and ULog twins describe one flight:

* DataFlash: LOCAL_POSITION_NED -> ``XKF1`` (core 0), ATTITUDE -> ``ATT`` (centidegrees, as
  ArduPilot logs it), GIMBAL_DEVICE_ATTITUDE_STATUS and MOUNT_ORIENTATION -> ``MNT`` (the
  ArduPilot 4.3-4.7 layout: roll and pitch against the horizon, ``YawB`` against the heading,
  ``YawE`` against north, degrees; the heading from ATTITUDE interpolated as the tracker
  does), GPS_GLOBAL_ORIGIN -> ``ORGN``; each type's FMT record before its first record, as
  ArduPilot writes them; GLOBAL_POSITION_INT -> ``POS``; LANDING_TARGET (a body or heading
  frame) -> ``PL`` (ArduCopter 4.x layout, ``pZ`` first), its measurement ``mX, mY, mZ`` the
  line of sight in NED (cm; rotated by ATTITUDE interpolated) times the target's distance (10
  m when it has none), ``LastMeasMS`` its time, ``TAcq`` 1.
* ULog: LOCAL_POSITION_NED -> ``vehicle_local_position``, ATTITUDE -> ``vehicle_attitude``
  (quaternion), GIMBAL_DEVICE_ATTITUDE_STATUS -> ``gimbal_device_attitude_status``,
  GPS_GLOBAL_ORIGIN -> the reference of ``vehicle_local_position``; the PX4 field names, a
  subset of their fields.

A DISTANCE_SENSOR of the gimbal (orientation MAV_SENSOR_ROTATION_CUSTOM) becomes MNT's ``Dist``
(the mount's own rangefinder, ArduPilot 4.6 on) of the mount record of its time, and PX4's
``distance_sensor`` topic.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from mav_observer.geo.frames import euler_from_dcm, euler_to_dcm, quat_from_euler, quat_to_dcm
from mav_observer.mavlink.dialect import MSG_ID
from mav_observer.mavlink.tlog import TlogReader
from mav_observer.tracking.directions import Skip, landing_target_direction

# -- DataFlash ------------------------------------------------------------------------

#: name: (type, format, columns), ArduPilot's layouts.
DF_FORMATS = {
    "XKF1": (
        200,
        "QBccCfffffffccce",
        "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH",
    ),
    "ATT": (201, "QccccCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,AEKF"),
    "MNT": (202, "QBffffffff", "TimeUS,I,DRoll,Roll,DPitch,Pitch,DYawB,YawB,DYawE,YawE"),
    "MNTD": (202, "QBfffffffff", "TimeUS,I,DRoll,Roll,DPitch,Pitch,DYawB,YawB,DYawE,YawE,Dist"),
    "ORGN": (203, "QBLLe", "TimeUS,Type,Lat,Lng,Alt"),
    "PL": (
        206,
        "QBBffffffffIIB",
        "TimeUS,Heal,TAcq,pZ,pX,pY,vX,vY,mX,mY,mZ,LastMeasMS,EKFOutl,Est",
    ),
    "POS": (204, "QLLfff", "TimeUS,Lat,Lng,Alt,RelHomeAlt,RelOriginAlt"),
    "IMU": (
        205,
        "QBIfffffffIIfBBHH",
        "TimeUS,I,EG,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,T,EG2,EA,Tmp2,GH,AH,GHz,AHz",
    ),
}
_CHAR_STRUCT = {
    "Q": "Q", "B": "B", "c": "h", "C": "H", "f": "f", "e": "i", "L": "i", "I": "I", "H": "H",
}  # fmt: skip
_CHAR_MULT = {"c": 100.0, "C": 100.0, "e": 100.0, "L": 1e7}


class DataFlashWriter:
    """DataFlash records, each type's FMT record written before its first record."""

    def __init__(self, fh: BinaryIO) -> None:
        self._fh = fh
        self._written: set[str] = set()
        self._fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")

    def _fmt(self, typ: int, length: int, name: str, fmt: str, cols: str) -> None:
        self._fh.write(
            bytes([0xA3, 0x95, 0x80])
            + struct.pack("<BB4s16s64s", typ, length, name.encode(), fmt.encode(), cols.encode())
        )

    def write(self, key: str, values: tuple[float, ...]) -> None:
        typ, fmt, cols = DF_FORMATS[key]
        name = key[:3] if key == "MNTD" else key
        st = struct.Struct("<" + "".join(_CHAR_STRUCT[c] for c in fmt))
        if key not in self._written:
            self._written.add(key)
            self._fmt(typ, 3 + st.size, name, fmt, cols)
        packed = []
        for c, v in zip(fmt, values, strict=True):
            if c in _CHAR_MULT:
                packed.append(round(v * _CHAR_MULT[c]))
            else:
                packed.append(int(v) if c in "QBIH" else v)
        self._fh.write(bytes([0xA3, 0x95, typ]) + st.pack(*packed))


# -- ULog -----------------------------------------------------------------------------

#: topic: [(type, field)], PX4's names.
ULOG_TOPICS = {
    "vehicle_local_position": [
        ("uint64_t", "timestamp"), ("float", "x"), ("float", "y"), ("float", "z"),
        ("float", "vx"), ("float", "vy"), ("float", "vz"), ("double", "ref_lat"),
        ("double", "ref_lon"), ("float", "ref_alt"), ("bool", "xy_valid"), ("bool", "z_valid"),
        ("bool", "v_xy_valid"), ("bool", "v_z_valid"), ("bool", "xy_global"),
        ("uint8_t", "xy_reset_counter"),
    ],
    "vehicle_attitude": [("uint64_t", "timestamp"), ("float[4]", "q")],
    "distance_sensor": [
        ("uint64_t", "timestamp"), ("uint32_t", "device_id"), ("float", "min_distance"),
        ("float", "max_distance"), ("float", "current_distance"), ("float", "variance"),
        ("uint8_t", "orientation"),
    ],
    "sensor_combined": [
        ("uint64_t", "timestamp"), ("float[3]", "gyro_rad"), ("uint32_t", "gyro_integral_dt"),
        ("int32_t", "accelerometer_timestamp_relative"), ("float[3]", "accelerometer_m_s2"),
        ("uint32_t", "accelerometer_integral_dt"), ("uint8_t", "accelerometer_clipping"),
    ],
    "gimbal_device_attitude_status": [
        ("uint64_t", "timestamp"), ("uint8_t", "target_system"), ("uint8_t", "target_component"),
        ("uint16_t", "device_flags"), ("float[4]", "q"), ("float", "angular_velocity_x"),
        ("float", "angular_velocity_y"), ("float", "angular_velocity_z"),
        ("uint32_t", "failure_flags"), ("float", "delta_yaw"), ("float", "delta_yaw_velocity"),
        ("uint8_t", "gimbal_device_id"),
    ],
}  # fmt: skip
_ULOG_STRUCT = {
    "uint64_t": "Q", "float": "f", "double": "d", "bool": "B", "uint8_t": "B",
    "uint16_t": "H", "uint32_t": "I", "float[4]": "4f", "float[3]": "3f", "int32_t": "i",
}  # fmt: skip


class ULogWriter:
    """A ULog file: header, flag bits, formats and subscriptions, then data messages."""

    def __init__(self, fh: BinaryIO, t0_us: int = 0) -> None:
        self._fh = fh
        fh.write(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", t0_us))
        self._msg(b"B", bytes(16) + struct.pack("<QQQ", 0, 0, 0))
        self._info("char[3] sys_name", b"PX4")
        self._structs: dict[str, struct.Struct] = {}
        for topic, fields in ULOG_TOPICS.items():
            text = f"{topic}:" + "".join(f"{t} {n};" for t, n in fields)
            self._msg(b"F", text.encode())
            self._structs[topic] = struct.Struct("<" + "".join(_ULOG_STRUCT[t] for t, _ in fields))
        for msg_id, topic in enumerate(ULOG_TOPICS):
            self._msg(b"A", struct.pack("<BH", 0, msg_id) + topic.encode())
        self._ids = {topic: i for i, topic in enumerate(ULOG_TOPICS)}

    def _msg(self, kind: bytes, body: bytes) -> None:
        self._fh.write(struct.pack("<H", len(body)) + kind + body)

    def _info(self, key: str, value: bytes) -> None:
        self._msg(b"I", bytes([len(key)]) + key.encode() + value)

    def write(self, topic: str, values: tuple[Any, ...]) -> None:
        flat: list[Any] = []
        for v in values:
            flat.extend(v if isinstance(v, (tuple, list)) else (v,))
        self._msg(b"D", struct.pack("<H", self._ids[topic]) + self._structs[topic].pack(*flat))


# -- the conversion ---------------------------------------------------------------------

_WANTED = (
    "LOCAL_POSITION_NED", "ATTITUDE", "GIMBAL_DEVICE_ATTITUDE_STATUS", "MOUNT_ORIENTATION",
    "GPS_GLOBAL_ORIGIN", "GLOBAL_POSITION_INT", "DISTANCE_SENSOR", "LANDING_TARGET",
)  # fmt: skip
_YAW_IN_EARTH = 64
#: The target a converted log's reader names, where it differs: (format, the tlog's target).
TARGET_IN = {("bin", "gimbal"): "mount", ("bin", "mount"): "mount"}


def _heading(messages: list[tuple[float, Any]]) -> Callable[[float], float]:
    """The vehicle's heading (rad) at a boot time (s), ATTITUDE's yaw interpolated linearly
    (unwrapped), as the tracker does."""
    att = [(m.time_boot_ms * 1e-3, m.yaw) for _, m in messages if m.get_type() == "ATTITUDE"]
    if not att:
        return lambda t: math.nan
    tb = np.array([a[0] for a in att])
    yaw = np.unwrap(np.array([a[1] for a in att]))
    return lambda t: float(np.interp(t, tb, yaw))


def _attitude(messages: list[tuple[float, Any]]) -> Callable[[float], tuple[float, ...]]:
    """The vehicle's roll, pitch and yaw (rad) at a boot time (s), ATTITUDE interpolated
    linearly (the yaw unwrapped)."""
    att = [(m.time_boot_ms * 1e-3, m.roll, m.pitch, m.yaw) for _, m in messages
           if m.get_type() == "ATTITUDE"]  # fmt: skip
    if not att:
        return lambda t: (math.nan, math.nan, math.nan)
    a = np.array(att)
    a[:, 3] = np.unwrap(a[:, 3])
    return lambda t: tuple(float(np.interp(t, a[:, 0], a[:, k])) for k in (1, 2, 3))


def _boot_ms(m: Any) -> int:
    """A message's time on the autopilot's boot clock (ms; -1: none)."""
    ms = getattr(m, "time_boot_ms", None)
    if ms is None and m.get_type() == "LANDING_TARGET":
        return m.time_usec // 1000
    return -1 if ms is None else ms


def _on_autopilot_clock(messages: list[tuple[float, Any]]) -> list[tuple[float, Any]]:
    """The messages with every component's ``time_boot_ms`` on the autopilot's clock (the
    component of LOCAL_POSITION_NED), as the autopilot's logger stamps what it receives: a
    component with its own clock is mapped by a straight-line fit of its stamps against its
    arrivals on the autopilot's clock (offset and drift; the mean latency stays in)."""
    ap = [(t, m) for t, m in messages if m.get_type() == "LOCAL_POSITION_NED"]
    if not ap:
        return messages
    ap_comp = ap[0][1].get_srcComponent()
    offset = float(np.median([t - m.time_boot_ms * 1e-3 for t, m in ap]))
    fits: dict[int, tuple[float, float]] = {}
    for comp in {m.get_srcComponent() for _, m in messages} - {ap_comp}:
        pts = [(m.time_boot_ms * 1e-3, t - offset) for t, m in messages
               if m.get_srcComponent() == comp and hasattr(m, "time_boot_ms")]  # fmt: skip
        if len(pts) >= 2:
            x, y = np.array(pts).T
            b, a = np.polyfit(x - x[0], y, 1)
            fits[comp] = (float(a - b * x[0]), float(b))
    out = []
    for t, m in messages:
        fit = fits.get(m.get_srcComponent())
        if fit is not None and hasattr(m, "time_boot_ms"):
            ms = round(1000 * (fit[0] + fit[1] * m.time_boot_ms * 1e-3))
            out.append((t, m._replace(time_boot_ms=ms)))
        else:
            out.append((t, m))
    stamps = [m.time_boot_ms for _, m in ap]
    if all(b >= a - 1000 for a, b in pairwise(stamps)):  # one boot
        out.sort(key=lambda tm: _boot_ms(tm[1]))  # a logger's order
    return out


def _gimbal_ranges(messages: list[tuple[float, Any]]) -> Callable[[float], float] | None:
    """The gimbal's DISTANCE_SENSOR (orientation MAV_SENSOR_ROTATION_CUSTOM) nearest a boot
    time (s), within 50 ms (NaN: none); ``None`` when the flight has none."""
    got = [(m.time_boot_ms * 1e-3, m.current_distance * 0.01) for _, m in messages
           if m.get_type() == "DISTANCE_SENSOR" and m.orientation == 100]  # fmt: skip
    if not got:
        return None
    tr, rr = np.array(got).T

    def at(tb: float) -> float:
        k = int(np.clip(np.searchsorted(tr, tb), 1, len(tr) - 1)) if len(tr) > 1 else 0
        best = min((k - 1, k) if len(tr) > 1 else (0,), key=lambda i: abs(tr[i] - tb))
        return float(rr[best]) if abs(tr[best] - tb) <= 0.05 else math.nan

    return at


def convert(
    tlog: Path,
    out: Path,
    rangefinder: Callable[[float], float] | None = None,
    imu_hz: float = 0.0,
) -> int:
    """Write ``tlog``'s flight to ``out`` (``.bin`` or ``.ulg`` by its suffix); returns the
    number of records written. ``rangefinder``: the distance (m) at a boot time (s) for MNT's
    ``Dist`` (DataFlash only). ``imu_hz``: also inertial records at this rate (``IMU`` of two
    IMUs, ``sensor_combined``), the bulk of a real log (for timing a reader on a log of a
    real log's size)."""
    ids = {MSG_ID[n] for n in _WANTED}
    messages = _on_autopilot_clock(list(TlogReader(tlog, ids)))
    kind = out.suffix.lower()
    if kind not in (".bin", ".ulg"):
        raise ValueError(f"{out}: the output must end in .bin or .ulg")
    heading = _heading(messages)
    attitude = _attitude(messages)
    n = 0
    with open(out, "wb") as fh:
        if kind == ".bin":
            df = DataFlashWriter(fh)
            next_imu_us = None
            if rangefinder is None:
                rangefinder = _gimbal_ranges(messages)
            for _, m in messages:
                tb = getattr(m, "time_boot_ms", None)
                if imu_hz > 0 and tb is not None:
                    next_imu_us = tb * 1000 if next_imu_us is None else next_imu_us
                    while next_imu_us <= tb * 1000:
                        for inst in (0, 1):
                            df.write("IMU", (next_imu_us, inst, 0, 0.01, -0.02, 0.0, 0.1, 0.0,
                                             -9.8, 0.0, 0, 0, 40.0, 1, 1, 400, 400))  # fmt: skip
                            n += 1
                        next_imu_us += round(1e6 / imu_hz)
                n += _write_df(df, m, heading, rangefinder, attitude)
        else:
            t0 = int(messages[0][0] * 1e6) if messages else 0
            ul = ULogWriter(fh, t0)
            origin: tuple[float, float, float] | None = None
            next_imu_us = None
            for _, m in messages:
                tb = getattr(m, "time_boot_ms", None)
                if imu_hz > 0 and tb is not None:
                    next_imu_us = tb * 1000 if next_imu_us is None else next_imu_us
                    while next_imu_us <= tb * 1000:
                        ul.write("sensor_combined", (next_imu_us, (0.01, -0.02, 0.0), 5000, 0,
                                                     (0.1, 0.0, -9.8), 5000, 0))  # fmt: skip
                        n += 1
                        next_imu_us += round(1e6 / imu_hz)
                if m.get_type() == "GPS_GLOBAL_ORIGIN":
                    origin = (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3)
                    continue
                n += _write_ulog(ul, m, origin)
    return n


def _write_df(
    df: DataFlashWriter,
    m: Any,
    heading: Callable[[float], float],
    rangefinder: Callable[[float], float] | None,
    attitude: Callable[[float], tuple[float, ...]],
) -> int:
    mtype = m.get_type()
    if mtype == "LANDING_TARGET":
        return _write_pl(df, m, attitude)
    if mtype == "GPS_GLOBAL_ORIGIN":
        df.write("ORGN", (0, 0, m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3))
        return 1
    if mtype == "DISTANCE_SENSOR":
        return 0  # a gimbal's: MNT's Dist
    t_us = m.time_boot_ms * 1000
    if mtype == "GLOBAL_POSITION_INT":
        df.write("POS", (t_us, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, 0.0, 0.0))
    elif mtype == "LOCAL_POSITION_NED":
        df.write(
            "XKF1",
            (t_us, 0, 0, 0, 0, m.vx, m.vy, m.vz, m.vz, m.x, m.y, m.z, 0, 0, 0, 0),
        )
    elif mtype == "ATTITUDE":
        r, p, y = (math.degrees(a) for a in (m.roll, m.pitch, m.yaw))
        df.write("ATT", (t_us, r, r, p, p, y % 360, y % 360, 0, 3))
    else:
        tb = m.time_boot_ms * 1e-3
        if mtype == "GIMBAL_DEVICE_ATTITUDE_STATUS":
            roll, pitch, yaw = euler_from_dcm(quat_to_dcm(tuple(m.q)))
            if m.flags & _YAW_IN_EARTH:
                yaw_e, yaw_b = yaw, yaw - heading(tb)
            else:
                yaw_b, yaw_e = yaw, yaw + heading(tb)
            roll, pitch, yaw_b, yaw_e = (math.degrees(a) for a in (roll, pitch, yaw_b, yaw_e))
        else:  # MOUNT_ORIENTATION, degrees
            roll, pitch, yaw_b, yaw_e = m.roll, m.pitch, m.yaw, m.yaw_absolute
        yaw_b = (yaw_b + 180) % 360 - 180
        yaw_e = (yaw_e + 180) % 360 - 180
        row = (t_us, 0, roll, roll, pitch, pitch, yaw_b, yaw_b, yaw_e, yaw_e)
        if rangefinder is None:
            df.write("MNT", row)
        else:
            df.write("MNTD", (*row, rangefinder(tb)))
    return 1


def _write_pl(df: DataFlashWriter, m: Any, attitude: Callable[[float], tuple[float, ...]]) -> int:
    t_us = int(m.time_usec)
    roll, pitch, yaw = attitude(t_us * 1e-6)
    try:
        los = landing_target_direction(
            frame=m.frame, angle_x=m.angle_x, angle_y=m.angle_y,
            position_valid=getattr(m, "position_valid", 0), x=getattr(m, "x", 0.0),
            y=getattr(m, "y", 0.0), z=getattr(m, "z", 0.0),
            vehicle_dcm=euler_to_dcm(roll, pitch, yaw), vehicle_yaw=yaw,
        )  # fmt: skip
    except Skip:
        return 0  # (an absolute local position needs the vehicle's: not written)
    dist = m.distance if m.distance > 0 else 10.0
    scale = 100.0 * dist / math.sqrt(sum(c * c for c in los))  # m -> cm
    mx, my, mz = (c * scale for c in los)
    df.write("PL", (t_us, 1, 1, dist, 0.0, 0.0, 0.0, 0.0, mx, my, mz, t_us // 1000, 0, 1))
    return 1


def _write_ulog(ul: ULogWriter, m: Any, origin: tuple[float, float, float] | None) -> int:
    mtype = m.get_type()
    if mtype in ("MOUNT_ORIENTATION", "GLOBAL_POSITION_INT", "LANDING_TARGET"):
        # PX4 logs its mount as the gimbal's attitude, its origin as the reference, and its
        # landing target (landing_target_pose) as an absolute position: not written
        return 0
    if mtype == "DISTANCE_SENSOR":
        ul.write("distance_sensor", (m.time_boot_ms * 1000, 0, m.min_distance * 0.01,
                                     m.max_distance * 0.01, m.current_distance * 0.01, 0.0,
                                     m.orientation))  # fmt: skip
        return 1
    t_us = m.time_boot_ms * 1000
    if mtype == "LOCAL_POSITION_NED":
        lat, lon, alt = origin if origin is not None else (0.0, 0.0, 0.0)
        ul.write(
            "vehicle_local_position",
            (t_us, m.x, m.y, m.z, m.vx, m.vy, m.vz, lat, lon, alt, 1, 1, 1, 1,
             int(origin is not None), 0),
        )  # fmt: skip
    elif mtype == "ATTITUDE":
        ul.write("vehicle_attitude", (t_us, quat_from_euler(m.roll, m.pitch, m.yaw)))
    elif mtype == "GIMBAL_DEVICE_ATTITUDE_STATUS":
        ul.write(
            "gimbal_device_attitude_status",
            (t_us, m.target_system, m.target_component, m.flags, tuple(m.q),
             m.angular_velocity_x, m.angular_velocity_y, m.angular_velocity_z,
             m.failure_flags, m.delta_yaw, m.delta_yaw_velocity, m.gimbal_device_id),
        )  # fmt: skip
    else:
        return 0
    return 1


def convert_truth(truth_in: Path, truth_out: Path, log_out: Path) -> int:
    """The truth of ``truth_in`` for the converted log ``log_out``: the same lines, the
    target named as the log's reader names it (a DataFlash mount is ``mount``); returns the
    number of lines."""
    import json

    fmt = log_out.suffix.lower().lstrip(".")
    rename = {t: new for (f, t), new in TARGET_IN.items() if f == fmt}
    n = 0
    with open(truth_in, encoding="utf-8") as src, open(truth_out, "w", encoding="utf-8") as dst:
        for line in src:
            if not line.strip():
                continue
            d = json.loads(line)
            d["target"] = rename.get(d["target"], d["target"])
            dst.write(json.dumps(d) + "\n")
            n += 1
    return n
