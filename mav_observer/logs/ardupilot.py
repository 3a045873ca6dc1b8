"""An ArduPilot DataFlash log's records as the MAVLink messages the tracker reads.

On the autopilot's boot clock (``TimeUS``, ``TimeMS`` on old logs):

* the vehicle's velocity and position: ``XKF1`` (EKF3), else ``NKF1`` (EKF2), else ``EKF1``:
  ``PN, PE, PD`` (m) and ``VN, VE, VD`` (m/s) in the EKF's local NED frame, one core (the
  lowest ``C`` logged) -> LOCAL_POSITION_NED;
* the vehicle's attitude: ``ATT`` ``Roll``, ``Pitch``, ``Yaw`` (degrees) -> ATTITUDE;
* the origin of the local frame: ``ORGN`` of ``Type`` 0 (the EKF origin) -> GPS_GLOBAL_ORIGIN;
  ``Type`` 1 (home) -> HOME_POSITION, its local position from the origin; ``POS`` ``Lat``,
  ``Lng`` (degrees), ``Alt`` (m above mean sea level) -> GLOBAL_POSITION_INT;
* the camera mount (ArduPilot 4.3 on): ``MNT`` ``Roll`` and ``Pitch`` against the horizon,
  ``YawB`` against the vehicle's heading, ``YawE`` against north (degrees; the measured
  angles, the demanded ones ``D*`` when a mount reports none), one mount instance (the
  lowest ``I``) -> MOUNT_ORIENTATION; ``Dist`` (the mount's own rangefinder, m; NaN: none) ->
  DISTANCE_SENSOR of orientation MAV_SENSOR_ROTATION_CUSTOM (the gimbal's range, fused with
  the bearing of the same record);
* precision landing (ArduCopter 3.6 on): ``PL`` ``mX, mY, mZ``, the landing target's measured
  position relative to the vehicle (NED; its direction is the camera's line of sight, its
  length the rangefinder's distance, not used), each new measurement (``LastMeasMS``, its
  time) while the target is acquired (``TAcq``) -> LANDING_TARGET in
  MAV_FRAME_LOCAL_OFFSET_NED, target 0.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mav_observer.logs.dataflash import DataFlashLog
from mav_observer.logs.messages import Stream, maker

#: The EKF records that carry the local position and velocity, newest estimator first.
POSITION_RECORDS = ("XKF1", "NKF1", "EKF1")
#: MAVLink's DISTANCE_SENSOR orientation of a sensor not fixed to the body (a gimbal's).
MAV_SENSOR_ROTATION_CUSTOM = 100
#: MAVLink's frame of a position relative to the vehicle, NED (a PL measurement's).
MAV_FRAME_LOCAL_OFFSET_NED = 7


def _one_instance(
    cols: dict[str, np.ndarray[Any, Any]], key: str, notes: list[str], what: str
) -> dict[str, np.ndarray[Any, Any]]:
    """The records of the lowest instance ``key`` (``C`` core, ``I`` mount) when several are
    logged."""
    if key not in cols:
        return cols
    inst = cols[key]
    values = np.unique(inst)
    if len(values) <= 1:
        return cols
    keep = inst == values[0]
    notes.append(f"{what} {values.tolist()} logged: {int(values[0])} used")
    return {k: v[keep] for k, v in cols.items()}


def _sorted(
    log: DataFlashLog, cols: dict[str, np.ndarray[Any, Any]]
) -> tuple[np.ndarray[Any, Any], dict[str, np.ndarray[Any, Any]]] | None:
    t = log.time_us(cols)
    if t is None:
        return None
    order = np.argsort(t, kind="stable")
    return t[order], {k: v[order] for k, v in cols.items()}


def _read(
    log: DataFlashLog, name: str, needed: set[str]
) -> tuple[np.ndarray[Any, Any], dict[str, np.ndarray[Any, Any]]] | None:
    """Record type ``name``'s times and columns in time order, ``None`` when the log has none
    or they lack a time or one of the ``needed`` columns."""
    cols = log.columns(name)
    if cols is None or not needed <= cols.keys():
        return None
    return _sorted(log, cols)


def streams(log: DataFlashLog, notes: list[str]) -> list[Stream]:
    """The log's messages as :class:`Stream` s; what it lacks, or how it was read, appended
    to ``notes``."""
    out: list[Stream] = []
    out += _position(log, notes)
    out += _attitude(log, notes)
    out += _origin(log, notes)
    out += _global_position(log)
    out += _mount(log, notes)
    out += _precision_landing(log, notes)
    return out


def _active_ekf(log: DataFlashLog) -> str | None:
    """The position record of the EKF the autopilot flew on: ``ATT.AEKF``, else the parameter
    ``AHRS_EKF_TYPE`` (2: EKF2, ``NKF1``; 3: EKF3, ``XKF1``); ``None`` if neither says."""
    by_type = {2: "NKF1", 3: "XKF1"}
    att = log.columns("ATT")
    if att is not None and "AEKF" in att and len(att["AEKF"]):
        values, counts = np.unique(att["AEKF"], return_counts=True)
        return by_type.get(int(values[np.argmax(counts)]))
    parm = log.columns("PARM")
    if parm is not None and "Name" in parm and "Value" in parm:
        hit = np.flatnonzero(parm["Name"] == b"AHRS_EKF_TYPE")
        if len(hit):
            return by_type.get(int(parm["Value"][hit[-1]]))
    return None


def _position(log: DataFlashLog, notes: list[str]) -> list[Stream]:
    present = [n for n in POSITION_RECORDS if log.count(n)]
    if not present:
        notes.append("no EKF position record (XKF1, NKF1 or EKF1): no velocity")
        return []
    name = present[0]
    if len(present) > 1:
        active = _active_ekf(log)
        name = active if active in present else name
        notes.append(f"{' and '.join(present)} logged: {name} used (the EKF flown on)")
    cols = log.columns(name)
    got = None if cols is None else _sorted(log, _one_instance(cols, "C", notes, f"{name} cores"))
    if got is None or not {"PN", "PE", "PD", "VN", "VE", "VD"} <= got[1].keys():
        notes.append(f"{name} without a time, position or velocity column: no velocity")
        return []
    t, c = got
    pn, pe, pd, vn, ve, vd = (
        c[k].astype(float).tolist() for k in ("PN", "PE", "PD", "VN", "VE", "VD")
    )
    ms = (t // 1000).tolist()
    make = maker("LOCAL_POSITION_NED")

    def build(i: int) -> Any:
        return make(time_boot_ms=ms[i], x=pn[i], y=pe[i], z=pd[i], vx=vn[i], vy=ve[i], vz=vd[i])

    return [Stream(t, 2, build)]


def _attitude(log: DataFlashLog, notes: list[str]) -> list[Stream]:
    got = _read(log, "ATT", {"Roll", "Pitch", "Yaw"})
    if got is None:
        notes.append("no ATT record: no vehicle attitude")
        return []
    t, c = got
    roll = np.radians(c["Roll"].astype(float)).tolist()
    pitch = np.radians(c["Pitch"].astype(float)).tolist()
    yaw = np.radians((c["Yaw"].astype(float) + 180.0) % 360.0 - 180.0).tolist()
    ms = (t // 1000).tolist()
    make = maker("ATTITUDE")
    return [
        Stream(t, 1, lambda i: make(time_boot_ms=ms[i], roll=roll[i], pitch=pitch[i], yaw=yaw[i]))
    ]


def _origin(log: DataFlashLog, notes: list[str]) -> list[Stream]:
    got = _read(log, "ORGN", {"Lat", "Lng", "Alt"})
    if got is None:
        return []
    t, c = got
    kind = c["Type"].tolist() if "Type" in c else [0] * len(t)
    lat, lng, alt = (c[k].astype(float).tolist() for k in ("Lat", "Lng", "Alt"))
    origin: list[tuple[float, float, float] | None] = [None]
    make_origin = maker("GPS_GLOBAL_ORIGIN")
    make_home = maker("HOME_POSITION")

    def build(i: int) -> Any:
        la, lo, al = lat[i], lng[i], alt[i]
        if not (la or lo):
            return None
        if kind[i] == 0:
            origin[0] = (la, lo, al)
            return make_origin(latitude=round(la * 1e7), longitude=round(lo * 1e7),
                               altitude=round(al * 1e3), time_usec=int(t[i]))  # fmt: skip
        if kind[i] == 1 and origin[0] is not None:
            import pymap3d

            n, e, d = (float(v) for v in pymap3d.geodetic2ned(la, lo, al, *origin[0]))
            return make_home(latitude=round(la * 1e7), longitude=round(lo * 1e7),
                             altitude=round(al * 1e3), x=n, y=e, z=d,
                             q=[1.0, 0.0, 0.0, 0.0], time_usec=int(t[i]))  # fmt: skip
        return None

    return [Stream(t, 0, build)]


def _global_position(log: DataFlashLog) -> list[Stream]:
    got = _read(log, "POS", {"Lat", "Lng", "Alt"})
    if got is None:
        return []
    t, c = got
    lat = np.round(c["Lat"].astype(float) * 1e7).astype(np.int64).tolist()
    lng = np.round(c["Lng"].astype(float) * 1e7).astype(np.int64).tolist()
    alt = np.round(c["Alt"].astype(float) * 1e3).astype(np.int64).tolist()
    ms = (t // 1000).tolist()
    make = maker("GLOBAL_POSITION_INT")
    return [Stream(t, 2, lambda i: make(time_boot_ms=ms[i], lat=lat[i], lon=lng[i], alt=alt[i]))]


def _mount(log: DataFlashLog, notes: list[str]) -> list[Stream]:
    cols = log.columns("MNT")
    if cols is None:
        notes.append("no MNT record: no camera mount angles (ArduPilot logs them from 4.3 on)")
        return []
    if not {"Pitch", "YawB"} <= cols.keys():
        notes.append(f"MNT without pitch and yaw columns ({', '.join(cols)}): not read")
        return []
    cols = _one_instance(cols, "I", notes, "mount instances")
    got = _sorted(log, cols)
    if got is None:
        return []
    t, c = got

    def col(name: str) -> np.ndarray[Any, Any]:
        v = c.get(name)
        d = c.get("D" + name, c.get("Des" + name))  # DRoll from 4.6, DesRoll before
        if v is None:
            v = d if d is not None else np.full(len(t), np.nan)
        v = v.astype(float)
        if d is not None:  # a mount that reports no angles: the demanded ones
            v = np.where(np.isfinite(v), v, d.astype(float))
        return v

    roll, pitch, yaw_b, yaw_e = (col(k).tolist() for k in ("Roll", "Pitch", "YawB", "YawE"))
    ms = (t // 1000).tolist()
    make = maker("MOUNT_ORIENTATION")
    nan = math.nan

    def build(i: int) -> Any:
        return make(time_boot_ms=ms[i], roll=roll[i], pitch=pitch[i], yaw=yaw_b[i],
                    yaw_absolute=yaw_e[i] if math.isfinite(yaw_e[i]) else nan)  # fmt: skip

    out = [Stream(t, 4, build)]
    if "Dist" in c:  # the mount's own rangefinder (NaN: none): its range, before the angles
        dist_cm = np.round(c["Dist"].astype(float) * 100.0)
        ok = (np.isfinite(dist_cm) & (dist_cm > 0) & (dist_cm < 65535)).tolist()
        cm = np.where(np.isfinite(dist_cm), dist_cm, 0).astype(np.int64).tolist()
        make_d = maker("DISTANCE_SENSOR")

        def build_d(i: int) -> Any:
            if not ok[i]:
                return None
            return make_d(time_boot_ms=ms[i], min_distance=1, max_distance=65535,
                          current_distance=cm[i], orientation=MAV_SENSOR_ROTATION_CUSTOM,
                          covariance=255)  # fmt: skip

        out.append(Stream(t, 3, build_d))
    return out


def _precision_landing(log: DataFlashLog, notes: list[str]) -> list[Stream]:
    cols = log.columns("PL")
    if cols is None:
        return []  # (most flights have no precision landing: nothing to say)
    if not {"TAcq", "mX", "mY", "mZ"} <= cols.keys():
        notes.append(f"PL without its measurement (mX, mY, mZ; ArduCopter 3.6 on): not read "
                     f"(its columns: {', '.join(cols)})")  # fmt: skip
        return []
    got = _sorted(log, cols)
    if got is None:
        return []
    t, c = got
    m = np.column_stack([c[k].astype(float) for k in ("mX", "mY", "mZ")])
    keep = (c["TAcq"] != 0) & np.isfinite(m).all(axis=1) & (np.abs(m).sum(axis=1) > 0)
    meas_us = t.astype(np.int64)
    if "LastMeasMS" in c:  # one bearing per measurement, at its time (PL repeats the last)
        ms = c["LastMeasMS"].astype(np.int64)
        new = np.ones(len(ms), bool)
        new[1:] = ms[1:] != ms[:-1]
        keep &= new & (ms > 0)
        meas_us = ms * 1000
    if not keep.any():
        notes.append("PL records without an acquired target (TAcq 0): no precision-landing "
                     "bearing")  # fmt: skip
        return []
    t, m, meas_us = t[keep], m[keep] * 0.01, meas_us[keep]  # cm -> m
    x, y, z = (m[:, k].tolist() for k in range(3))
    usec = meas_us.tolist()
    make = maker("LANDING_TARGET")

    def build(i: int) -> Any:
        return make(time_usec=usec[i], target_num=0, frame=MAV_FRAME_LOCAL_OFFSET_NED,
                    position_valid=1, x=x[i], y=y[i], z=z[i])  # fmt: skip

    return [Stream(t, 4, build)]
