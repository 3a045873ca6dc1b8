"""Inject a synthetic bearing stream into a real tlog (``python -m sim inject``).

A real flight log gives real vehicle motion, real velocity errors and real timing; what public
logs lack is a bearing stream with a known truth. This module adds one: bearings from the
vehicle toward a fixed point of the autopilot's local NED frame (the frame of
LOCAL_POSITION_NED), built by inverting the reader's frame chain exactly as
:mod:`sim.emitter` does, and writes

* a new tlog: every original record, byte for byte and in order, with the injected frames
  interleaved (LOCAL_POSITION_NED rewritten only with ``vel_error_ned_mps``);
* the truth in the format of :mod:`sim.truth` (one line per injected bearing; a reference
  track for ``replay --truth``).

How the stream is made (all times on the autopilot's boot clock, ``time_boot_ms``):

* **Sample times**: every ``1 / rate_hz`` s (multiples of the period), only inside spans of
  LOCAL_POSITION_NED whose consecutive samples are at most ``max_gap_s`` (5 s) apart, and
  only where an ATTITUDE sample lies within ``max_attitude_age_s`` (0.2 s).
* **Truth**: the vehicle position is LOCAL_POSITION_NED's x, y, z interpolated linearly in
  time_boot_ms; ``rel_pos_ned_m = target - vehicle``. The target stands still in the world:
  where the local frame resets (a position step the velocity does not explain, as
  :func:`frame_steps` finds), the target's local coordinates move with the frame, and the
  vehicle's path across the reset is the world's (continuous). The vehicle attitude is ATTITUDE
  interpolated as the tracker does (linearly, yaw unwrapped, between samples at most 1 s
  apart; else the nearest).
* **Messages** (``bearing``): ``gimbal``: GIMBAL_DEVICE_ATTITUDE_STATUS with roll and pitch
  locked to the horizon and yaw in the vehicle frame (needs the vehicle yaw, ArduPilot style);
  ``gimbal_earth``: the same with yaw in the earth frame; ``landing_target``: LANDING_TARGET,
  MAV_FRAME_BODY_FRD angle_x/angle_y of a downward camera (needs the full attitude; samples
  the camera could not see, the target not below the vehicle, are skipped). Isotropic angular
  noise as :func:`sim.stream.perturb_bearings`. The frames are MAVLink 2 (a MAVLink 1 log
  then holds both versions, as real logs do), from ``(sysid, compid)``, stamped with the
  sample's time_boot_ms.
* **Velocity error** ``vel_error_ned_mps`` (wind-like): added to every LOCAL_POSITION_NED
  vx, vy, vz of the vehicle, its x, y, z left alone (GNSS-true positions). The frame is
  re-encoded with the same sysid, compid, sequence number and MAVLink version (a signed
  MAVLink 2 frame loses its signature). With the measured velocity ``u_meas = u_true + e``,
  ``x' = -u_true = -u_meas + e = v + e``: the truth's ``bias_ned_mps`` is ``a = +e``.
* **Where the frames go**: on the autopilot's clock the tracker refuses a message older than
  the one before it (``out_of_order``), so an injected frame stamped ``t`` goes after the
  last message of its clock (``compid``'s LOCAL_POSITION_NED, ATTITUDE, ATTITUDE_QUATERNION,
  SYSTEM_TIME, GIMBAL_DEVICE_ATTITUDE_STATUS, MOUNT_ORIENTATION) stamped ``<= t`` and before
  the next one, among the records in between at its tlog time. Its tlog time is the tlog
  time of the nearest (in boot time) LOCAL_POSITION_NED or ATTITUDE plus the boot-time
  difference, kept between its neighbours' times.
* **Damage**: the records are split by hand (8-byte big-endian Unix microseconds, then a
  frame starting 0xFE or 0xFD), not through pymavlink's tlog reader, which loses alignment
  on mixed versions (``ENGINEERING_NOTES.md``). Bytes that are not a plausible record are
  copied as they are; frames that do not decode are copied and not used. An autopilot clock
  going back by more than 2 s (a reboot, or a second writer's data) starts a new epoch;
  samples never span two epochs.

``target="auto"`` (:func:`auto_target`): a point on the ground under the middle of the flight:
north and east the medians of the LOCAL_POSITION_NED track, down 2 m below the lowest point
the vehicle reached (the largest z), so that the target is always below the vehicle (a
downward camera can see it when the vehicle is level) and the range never falls below 2 m.
"""

from __future__ import annotations

import bisect
import functools
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from struct import unpack_from
from typing import Any

import numpy as np

from mav_observer.core.batch_fit import RESET_GATE_M, RESET_GATE_MPS2
from mav_observer.geo.frames import euler_to_dcm, quat_from_euler
from mav_observer.mavlink.dialect import MSG_ID, codec, mavlink
from mav_observer.mavlink.fastdecode import DecodeError, FastDecoder
from mav_observer.mavlink.tlog import MAGIC_V1, MAGIC_V2, TS_JUMP_MAX_US, TS_MAX_US, TS_MIN_US
from mav_observer.tracking import directions as adapters
from sim import truth as truth_file
from sim.emitter import TARGET_OF
from sim.stream import perturb_bearings

BEARINGS = ("gimbal", "gimbal_earth", "landing_target")
LPN_ID = MSG_ID["LOCAL_POSITION_NED"]
ATTITUDE_ID = MSG_ID["ATTITUDE"]
#: Messages the tracker times on their component's clock (``time_boot_ms``).
CLOCK_IDS = frozenset(
    MSG_ID[n]
    for n in (
        "LOCAL_POSITION_NED",
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "SYSTEM_TIME",
        "GIMBAL_DEVICE_ATTITUDE_STATUS",
        "MOUNT_ORIENTATION",
    )
)
#: A clock going back by more than this (s) starts a new epoch (the tracker's reboot rule).
REBOOT_BACK_S = 2.0
#: Attitude samples further apart than this (s) are not interpolated (the tracker's rule:
#: twice its ``max_attitude_age_s``).
ATTITUDE_INTERP_MAX_S = 2.5
AUTO_TARGET_BELOW_M = 2.0


class InjectError(ValueError):
    """The log or the options do not allow an injection; the message says why."""


@dataclass(frozen=True)
class InjectConfig:
    """What to inject. ``target_ned_m`` ``None``: :func:`auto_target`. ``sysid`` ``None``: the
    vehicle that sends the most LOCAL_POSITION_NED. ``gimbal_device_id`` 1 (or 0) gives the
    reader's target ``gimbal``, N > 1 ``gimbalN``."""

    target_ned_m: tuple[float, float, float] | None = None
    bearing: str = "gimbal"
    rate_hz: float = 10.0
    noise_deg: float = 0.5
    vel_error_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    seed: int = 0
    sysid: int | None = None
    compid: int = 1
    gimbal_device_id: int = 1
    max_gap_s: float = 5.0
    max_attitude_age_s: float = 0.2

    def __post_init__(self) -> None:
        if self.bearing not in BEARINGS:
            raise InjectError(f"bearing must be one of {BEARINGS}, got {self.bearing!r}")
        if not (math.isfinite(self.rate_hz) and 0.0 < self.rate_hz <= 1000.0):
            raise InjectError(f"rate_hz must be in (0, 1000], got {self.rate_hz!r}")
        if not (math.isfinite(self.noise_deg) and self.noise_deg >= 0.0):
            raise InjectError(f"noise_deg must be >= 0, got {self.noise_deg!r}")
        for name in ("target_ned_m", "vel_error_ned_mps"):
            v = getattr(self, name)
            if v is not None and (len(v) != 3 or not all(math.isfinite(c) for c in v)):
                raise InjectError(f"{name} must be 3 finite numbers, got {v!r}")
        for name in ("sysid", "compid"):
            v = getattr(self, name)
            if v is not None and not 0 < v < 256:
                raise InjectError(f"{name} must be in 1..255, got {v!r}")
        if not 0 <= self.gimbal_device_id < 256:
            raise InjectError(f"gimbal_device_id must be in 0..255, got {self.gimbal_device_id}")
        if not self.max_gap_s > 0.0 or not self.max_attitude_age_s > 0.0:
            raise InjectError("max_gap_s and max_attitude_age_s must be > 0")

    @property
    def target_name(self) -> str:
        """The reader's name of the injected target."""
        if self.bearing == "landing_target":
            return TARGET_OF["landing_target"]
        return "gimbal" if self.gimbal_device_id <= 1 else f"gimbal{self.gimbal_device_id}"


# -- tlog records ----------------------------------------------------------------------


@dataclass(frozen=True)
class TlogRecord:
    """A record as it is in the file: ``data`` is the 8-byte timestamp and the frame, or, with
    ``t_us`` ``None``, bytes that are not a record (damage), to be copied as they are."""

    data: bytes
    t_us: int | None

    @property
    def frame(self) -> bytes:
        return self.data[8:] if self.t_us is not None else b""

    @property
    def msgid(self) -> int | None:
        f = self.frame
        if not f:
            return None
        return f[7] | (f[8] << 8) | (f[9] << 16) if f[0] == MAGIC_V2 else f[5]

    @property
    def source(self) -> tuple[int, int] | None:
        """``(sysid, compid)`` from the frame header."""
        f = self.frame
        if not f:
            return None
        return (f[5], f[6]) if f[0] == MAGIC_V2 else (f[3], f[4])


def _header(buf: bytes, i: int, n: int) -> tuple[int, int] | None:
    """``(timestamp_us, frame_length)`` of a record at ``i`` whose header is a MAVLink one."""
    if i + 9 > n:
        return None
    magic = buf[i + 8]
    if magic == MAGIC_V2 and i + 18 <= n:
        flen = 12 + buf[i + 9] + (13 if buf[i + 10] & 1 else 0)
    elif magic == MAGIC_V1 and i + 14 <= n:
        flen = 8 + buf[i + 9]
    else:
        return None
    return unpack_from(">Q", buf, i)[0], flen


def _plausible(ts: int, last: int | None) -> bool:
    return TS_MIN_US <= ts <= TS_MAX_US and (last is None or abs(ts - last) <= TS_JUMP_MAX_US)


def split_records(buf: bytes) -> list[TlogRecord]:
    """Split a tlog into records, as :mod:`mav_observer.mavlink.tlog` does: a record is
    plausible when its timestamp lies between 2000 and 2100 and within a week of the previous
    one and its frame starts with a magic byte and fits in the file. Anything else becomes a
    damage chunk up to the next plausible record (one followed by another, or ending the
    file), a cut final record a damage chunk to the end. Joining every ``data`` gives the
    file back."""
    n = len(buf)
    out: list[TlogRecord] = []
    last: int | None = None
    i = 0
    while i < n:
        hdr = _header(buf, i, n)
        if hdr is not None and _plausible(hdr[0], last) and i + 8 + hdr[1] <= n:
            end = i + 8 + hdr[1]
            out.append(TlogRecord(bytes(buf[i:end]), hdr[0]))
            last = hdr[0]
            i = end
            continue
        j = _resync(buf, i + 1, n, last)
        out.append(TlogRecord(bytes(buf[i:j]), None))
        i = j
    return out


def _resync(buf: bytes, start: int, n: int, last: int | None) -> int:
    """Start of the next plausible record at or after ``start`` (one whose successor is
    plausible too, or that ends the file), or ``n``."""
    pos = start
    while True:
        cands = [c for c in (buf.find(b"\xfd", pos + 8), buf.find(b"\xfe", pos + 8)) if c >= 0]
        if not cands:
            return n
        i = min(cands) - 8
        hdr = _header(buf, i, n)
        if hdr is not None and _plausible(hdr[0], last):
            end = i + 8 + hdr[1]
            if end == n:
                return i
            if end < n:
                nxt = _header(buf, end, n)
                if nxt is not None and _plausible(nxt[0], hdr[0]) and end + 8 + nxt[1] <= n:
                    return i
        pos = i + 1


# -- what the log says about the vehicle ---------------------------------------------------


@dataclass(frozen=True)
class _Series:
    """Samples of one stream of one epoch, boot-time ordered."""

    t_boot_s: np.ndarray
    values: np.ndarray  # (N, k)
    t_unix_s: np.ndarray
    record: np.ndarray  # index of the record in the log


@dataclass
class FlightData:
    """What an injection needs from a log, for one vehicle (``sysid``) whose autopilot is
    ``autopilot_compid``: per epoch of its clock, LOCAL_POSITION_NED (x, y, z, vx, vy, vz)
    and ATTITUDE (roll, pitch, yaw), and the clock records of the injection's component
    (record index, time_boot_ms in s) for placing the frames."""

    sysid: int
    autopilot_compid: int
    local_position: dict[int, _Series]
    attitude: dict[int, _Series]
    clock: dict[int, tuple[list[int], list[float]]]
    decode_errors: int = 0
    epochs: int = 1
    lpn_records: list[int] = field(default_factory=list)

    def lpn_rate_hz(self) -> float:
        """Median LOCAL_POSITION_NED rate (Hz) over the epochs."""
        d = np.concatenate([np.diff(s.t_boot_s) for s in self.local_position.values()])
        d = d[d > 0]
        return float(1.0 / np.median(d)) if len(d) else math.nan

    def track_ned_m(self) -> np.ndarray:
        """Every LOCAL_POSITION_NED x, y, z, (N, 3)."""
        return np.concatenate([s.values[:, :3] for s in self.local_position.values()])


def _series(rows: list[tuple[float, int, float, list[float]]]) -> _Series:
    """Boot-time ordered, duplicates and out-of-order samples dropped (the first kept)."""
    kept: list[tuple[float, int, float, list[float]]] = []
    for r in rows:
        if not kept or r[0] > kept[-1][0]:
            kept.append(r)
    return _Series(
        np.array([r[0] for r in kept]),
        np.array([r[3] for r in kept], dtype=float).reshape(len(kept), -1),
        np.array([r[2] for r in kept]),
        np.array([r[1] for r in kept], dtype=int),
    )


def vehicles_with_local_position(records: Sequence[TlogRecord]) -> Counter[tuple[int, int]]:
    """LOCAL_POSITION_NED frames per ``(sysid, compid)`` (by header, decoded or not)."""
    return Counter(r.source for r in records if r.msgid == LPN_ID)  # type: ignore[misc]


def read_flight(
    records: Sequence[TlogRecord], sysid: int | None = None, clock_compid: int = 1
) -> FlightData:
    """Decode the vehicle's LOCAL_POSITION_NED and ATTITUDE (and the clock records of
    ``clock_compid``). ``sysid`` ``None``: the vehicle that sends the most
    LOCAL_POSITION_NED. Raises :class:`InjectError` if it sends none."""
    senders = vehicles_with_local_position(records)
    if sysid is None:
        if not senders:
            raise InjectError("the log has no LOCAL_POSITION_NED: nothing to inject into")
        sysid = senders.most_common(1)[0][0][0]
    mine = Counter({k: v for k, v in senders.items() if k[0] == sysid})
    if not mine:
        raise InjectError(f"vehicle {sysid} sends no LOCAL_POSITION_NED (senders: {dict(senders)})")
    ap = mine.most_common(1)[0][0][1]
    decoder = FastDecoder(frozenset(CLOCK_IDS))
    epoch = 0
    ap_max: float | None = None
    lpn: dict[int, list[Any]] = {}
    att: dict[int, list[Any]] = {}
    clock: dict[int, tuple[list[int], list[float]]] = {}
    errors = 0
    lpn_records: list[int] = []
    for idx, rec in enumerate(records):
        msgid = rec.msgid
        if msgid not in CLOCK_IDS:
            continue
        src = rec.source
        if src is None or src[0] != sysid or src[1] not in (ap, clock_compid):
            continue
        try:
            msg = decoder.decode(rec.frame)
        except DecodeError:
            errors += 1
            continue
        boot = msg.time_boot_ms * 1e-3
        if src[1] == ap:
            if msgid == LPN_ID:
                lpn_records.append(idx)
            if ap_max is not None and boot < ap_max - REBOOT_BACK_S:
                epoch += 1
                ap_max = None
            ap_max = boot if ap_max is None else max(ap_max, boot)
            t_unix = rec.t_us * 1e-6  # type: ignore[operator]
            if msgid == LPN_ID:
                vals = [msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz]
                if all(math.isfinite(v) for v in vals):
                    lpn.setdefault(epoch, []).append((boot, idx, t_unix, vals))
            elif msgid == ATTITUDE_ID:
                vals = [msg.roll, msg.pitch, msg.yaw]
                if all(math.isfinite(v) for v in vals):
                    att.setdefault(epoch, []).append((boot, idx, t_unix, vals))
        if src[1] == clock_compid:
            c = clock.setdefault(epoch, ([], []))
            c[0].append(idx)
            c[1].append(boot)
    if not lpn:
        raise InjectError(f"vehicle {sysid}: no LOCAL_POSITION_NED decodes")
    return FlightData(
        sysid=sysid,
        autopilot_compid=ap,
        local_position={e: _series(v) for e, v in lpn.items()},
        attitude={e: _series(v) for e, v in att.items()},
        clock=clock,
        decode_errors=errors,
        epochs=epoch + 1,
        lpn_records=lpn_records,
    )


def auto_target(flight: FlightData) -> np.ndarray:
    """A point on the ground under the middle of the flight: median north and east of the
    LOCAL_POSITION_NED track, down :data:`AUTO_TARGET_BELOW_M` (2 m) below the lowest point
    reached (the largest z)."""
    p = flight.track_ned_m()
    return np.array(
        [
            float(np.median(p[:, 0])),
            float(np.median(p[:, 1])),
            float(np.max(p[:, 2])) + AUTO_TARGET_BELOW_M,
        ]
    )


# -- sampling ---------------------------------------------------------------------------------


def bearing_times_ms(
    t_lpn_s: np.ndarray,
    t_att_s: np.ndarray,
    rate_hz: float,
    max_gap_s: float = 5.0,
    max_attitude_age_s: float = 0.2,
) -> np.ndarray:
    """Sample times (integer time_boot_ms, multiples of ``1000 / rate_hz`` rounded) inside
    the spans of ``t_lpn_s`` with gaps of at most ``max_gap_s``, with an attitude sample
    within ``max_attitude_age_s``."""
    if len(t_lpn_s) < 2 or len(t_att_s) == 0:
        return np.zeros(0, dtype=np.int64)
    period_ms = 1000.0 / rate_hz
    breaks = np.nonzero(np.diff(t_lpn_s) > max_gap_s)[0]
    starts = np.concatenate(([0], breaks + 1))
    ends = np.concatenate((breaks, [len(t_lpn_s) - 1]))
    out = []
    for a, b in zip(starts, ends, strict=True):
        if b <= a:
            continue
        lo_ms, hi_ms = t_lpn_s[a] * 1000.0, t_lpn_s[b] * 1000.0
        k = np.arange(math.ceil(lo_ms / period_ms - 1e-9), math.floor(hi_ms / period_ms) + 1)
        t_ms = np.round(k * period_ms).astype(np.int64)
        out.append(t_ms[(t_ms >= lo_ms - 1e-6) & (t_ms <= hi_ms + 1e-6)])
    t_ms = np.unique(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)
    t = t_ms * 1e-3
    j = np.clip(np.searchsorted(t_att_s, t), 1, max(len(t_att_s) - 1, 1))
    near = np.minimum(
        np.abs(t - t_att_s[np.minimum(j, len(t_att_s) - 1)]), np.abs(t - t_att_s[j - 1])
    )
    return t_ms[near <= max_attitude_age_s + 1e-9]




def frame_steps(series: _Series) -> np.ndarray:
    """The local frame's cumulative reset (m) at each LOCAL_POSITION_NED sample, (N, 3): the
    part of each step between two samples that the velocity's trapezoid does not explain, where
    that is more than ``RESET_GATE_M + RESET_GATE_MPS2 dt^2`` and as much off the previous
    interval's (a step, not a velocity that disagrees with the positions for a while: the
    tracker's test, ``mav_observer.core.drift``)."""
    p, u, t = series.values[:, :3], series.values[:, 3:6], series.t_boot_s
    steps = np.zeros_like(p)
    if len(t) > 1:
        dt = np.diff(t)
        resid = np.diff(p, axis=0) - 0.5 * (u[:-1] + u[1:]) * dt[:, None]
        gate = RESET_GATE_M + RESET_GATE_MPS2 * dt**2
        rate = resid / dt[:, None]
        before = np.vstack((np.zeros((1, 3)), rate[:-1]))
        step = np.linalg.norm(rate - before, axis=1) * dt
        jump = (np.linalg.norm(resid, axis=1) > gate) & (step > gate)
        steps[1:] = np.cumsum(np.where(jump[:, None], resid, 0.0), axis=0)
    return steps


def interp_position(series: _Series, t_s: np.ndarray) -> np.ndarray:
    """LOCAL_POSITION_NED x, y, z (or, with columns 3:6, vx, vy, vz) linearly interpolated
    in boot time, (T, 6)."""
    return np.column_stack([np.interp(t_s, series.t_boot_s, series.values[:, i]) for i in range(6)])


def interp_attitude(series: _Series, t_s: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (rad) at ``t_s``, (T, 3): linear between the samples around (yaw
    unwrapped) when they are at most :data:`ATTITUDE_INTERP_MAX_S` apart, else the nearest,
    as the tracker's :class:`~mav_observer.tracking.attitude.AttitudeHistory` does."""
    ts, v = series.t_boot_s, series.values
    out = np.empty((len(t_s), 3))
    for k, t in enumerate(t_s):
        j = int(np.searchsorted(ts, t, side="right"))
        if j == 0:
            out[k] = v[0]
            continue
        if j == len(ts):
            out[k] = v[-1]
            continue
        a, b = j - 1, j
        dt = ts[b] - ts[a]
        if dt > ATTITUDE_INTERP_MAX_S:
            out[k] = v[a] if t - ts[a] <= ts[b] - t else v[b]
            continue
        f = (t - ts[a]) / dt
        dyaw = math.remainder(v[b, 2] - v[a, 2], 2 * math.pi)
        out[k] = (
            v[a, 0] + f * (v[b, 0] - v[a, 0]),
            v[a, 1] + f * (v[b, 1] - v[a, 1]),
            v[a, 2] + f * dyaw,
        )
    return out


# -- frames -----------------------------------------------------------------------------------


def gimbal_quaternion(
    los_ned: Sequence[float], vehicle_yaw: float, earth: bool
) -> tuple[tuple[float, float, float, float], int]:
    """GIMBAL_DEVICE_ATTITUDE_STATUS ``(q, flags)`` whose boresight is ``los_ned`` (unit):
    roll and pitch locked to the horizon, yaw in the vehicle frame (relative to
    ``vehicle_yaw``) or, ``earth``, in the earth frame (the emitter's chain)."""
    yaw_c = math.atan2(los_ned[1], los_ned[0])
    pitch_c = -math.asin(max(-1.0, min(1.0, los_ned[2])))
    if earth:
        flags = (
            adapters.GIMBAL_ROLL_LOCK
            | adapters.GIMBAL_PITCH_LOCK
            | adapters.GIMBAL_YAW_LOCK
            | adapters.GIMBAL_YAW_IN_EARTH_FRAME
        )
        return quat_from_euler(0.0, pitch_c, yaw_c), flags
    flags = (
        adapters.GIMBAL_ROLL_LOCK
        | adapters.GIMBAL_PITCH_LOCK
        | adapters.GIMBAL_YAW_IN_VEHICLE_FRAME
    )
    return quat_from_euler(0.0, pitch_c, yaw_c - vehicle_yaw), flags


def landing_target_angles(
    los_ned: Sequence[float], rpy: Sequence[float]
) -> tuple[float, float] | None:
    """LANDING_TARGET ``(angle_x, angle_y)`` (rad, MAV_FRAME_BODY_FRD, downward camera) of
    ``los_ned``, or ``None`` when the target is not below the vehicle (z in the body frame
    at most 0.05 of the unit line of sight: the camera cannot see it)."""
    r = np.array(euler_to_dcm(*rpy))
    s = r.T @ np.asarray(los_ned, dtype=float)
    if s[2] <= 0.05:
        return None
    return math.atan2(s[1], s[2]), math.atan2(-s[0], s[2])


def bearing_frame(
    bearing: str,
    time_boot_ms: int,
    los_ned: Sequence[float],
    rpy: Sequence[float],
    mav: Any,
    gimbal_device_id: int = 1,
) -> bytes | None:
    """The MAVLink 2 frame of one bearing (``None``: a landing target the camera cannot
    see). ``mav``: a :func:`mav_observer.mavlink.dialect.codec` (its sysid, compid, seq)."""
    nan = float("nan")
    if bearing in ("gimbal", "gimbal_earth"):
        q, flags = gimbal_quaternion(los_ned, rpy[2], bearing == "gimbal_earth")
        msg = mavlink.MAVLink_gimbal_device_attitude_status_message(
            0, 0, time_boot_ms, flags, list(q), nan, nan, nan, 0, nan, nan, gimbal_device_id
        )
    elif bearing == "landing_target":
        angles = landing_target_angles(los_ned, rpy)
        if angles is None:
            return None
        msg = mavlink.MAVLink_landing_target_message(
            time_boot_ms * 1000,
            0,
            adapters.MAV_FRAME_BODY_FRD,
            angles[0],
            angles[1],
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
    else:
        raise InjectError(f"bearing must be one of {BEARINGS}, got {bearing!r}")
    return bytes(msg.pack(mav))


@functools.cache
def _lpn_decoder() -> FastDecoder:
    return FastDecoder(frozenset({LPN_ID}))


def rewrite_local_position(frame: bytes, vel_error_ned_mps: Sequence[float]) -> bytes:
    """A LOCAL_POSITION_NED frame with ``vel_error_ned_mps`` added to vx, vy, vz, re-encoded
    with the same sysid, compid, sequence number and MAVLink version (unsigned). Raises
    :class:`~mav_observer.mavlink.fastdecode.DecodeError` if it does not decode."""
    msg = _lpn_decoder().decode(frame)
    v1 = frame[0] == MAGIC_V1
    seq = frame[2] if v1 else frame[4]
    mav = codec(msg.get_srcSystem(), msg.get_srcComponent())
    mav.seq = seq
    e = vel_error_ned_mps
    out = mavlink.MAVLink_local_position_ned_message(
        msg.time_boot_ms,
        msg.x,
        msg.y,
        msg.z,
        msg.vx + e[0],
        msg.vy + e[1],
        msg.vz + e[2],
    )
    return bytes(out.pack(mav, force_mavlink1=v1))


# -- the injection ----------------------------------------------------------------------------


@dataclass
class InjectResult:
    """The new log's records (in order), the truth records, and what was done."""

    records: list[bytes]
    truth: list[dict[str, Any]]
    target_ned_m: tuple[float, float, float]
    sysid: int
    target: str
    injected: int = 0
    skipped_not_visible: int = 0
    rewritten_local_position: int = 0
    damage_chunks: int = 0
    epochs: int = 1
    lpn_rate_hz: float = math.nan
    range_m: tuple[float, float] = (math.nan, math.nan)
    #: bearing frames of the log itself for the same vehicle and target name (they feed the
    #: same observer as the injected ones: choose another ``gimbal_device_id``)
    same_target_frames: int = 0

    def text(self) -> str:
        t = self.target_ned_m
        warn = (
            f"\nWARNING: the log has {self.same_target_frames} bearing messages of its own for "
            f"vehicle {self.sysid} target {self.target!r}: they mix with the injected ones "
            "(use --gimbal-device-id 2)"
            if self.same_target_frames
            else ""
        )
        return (
            f"vehicle {self.sysid}: injected {self.injected} {self.target!r} bearings toward "
            f"[{t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}] m NED (range {self.range_m[0]:.1f} to "
            f"{self.range_m[1]:.1f} m); LOCAL_POSITION_NED at {self.lpn_rate_hz:.2f} Hz, "
            f"{self.rewritten_local_position} rewritten; {self.skipped_not_visible} samples "
            f"not visible; {self.damage_chunks} damaged chunks copied; "
            f"{self.epochs} clock epoch(s)" + warn
        )


def _placement(
    records: Sequence[TlogRecord],
    clock: tuple[list[int], list[float]],
    t_boot_s: float,
    t_unix_s: float,
    previous: tuple[int, int, int] | None = None,
) -> tuple[int, int, int]:
    """``(gap, insert_before_index, t_us)`` of an injected frame stamped ``t_boot_s`` whose
    wanted tlog time is ``t_unix_s`` (see the module docstring). ``clock``: the clock
    records' indices in file order and the running maximum of their boot times. ``gap``: the
    index of the clock record the frame follows; ``previous``: the placement of the frame
    before it (frames of one gap keep their boot-time order)."""
    idx, runmax = clock
    p = bisect.bisect_right(runmax, t_boot_s + 1e-9)
    if p == 0:
        lo, hi = idx[0] - 1, idx[0]
    elif p == len(idx):
        lo, hi = idx[-1], idx[-1] + 1
    else:
        lo, hi = idx[p - 1], idx[p]
    t_us = round(t_unix_s * 1e6)
    pos = lo + 1
    if previous is not None and previous[0] == lo:
        pos = max(pos, previous[1])
        t_us = max(t_us, previous[2])
    while pos < hi and (records[pos].t_us is None or records[pos].t_us <= t_us):  # type: ignore[operator]
        if records[pos].t_us is None:  # damage: keep the frame before it
            break
        pos += 1
    prev_t = next(
        (
            records[k].t_us
            for k in range(pos - 1, max(lo, 0) - 1, -1)
            if records[k].t_us is not None
        ),
        None,
    )
    if previous is not None and previous[0] == lo:
        prev_t = previous[2] if prev_t is None else max(prev_t, previous[2])
    next_t = records[pos].t_us if pos < len(records) else None
    if prev_t is not None and t_us < prev_t:
        t_us = prev_t
    if next_t is not None and t_us > next_t and (prev_t is None or next_t >= prev_t):
        t_us = next_t
    return lo, pos, t_us


def same_target_frames(records: Sequence[TlogRecord], sysid: int, config: InjectConfig) -> int:
    """Bearing frames already in the log that the reader gives the injected target's name
    (vehicle ``sysid``)."""
    msgid = MSG_ID[
        "LANDING_TARGET" if config.bearing == "landing_target" else "GIMBAL_DEVICE_ATTITUDE_STATUS"
    ]
    decoder = FastDecoder(frozenset({msgid}))
    n = 0
    for rec in records:
        src = rec.source
        if rec.msgid != msgid or src is None or src[0] != sysid:
            continue
        try:
            msg = decoder.decode(rec.frame)
        except DecodeError:
            continue
        if config.bearing == "landing_target":
            n += msg.target_num == 0
        else:
            dev = msg.gimbal_device_id
            n += ("gimbal" if dev <= 1 else f"gimbal{dev}") == config.target_name
    return n


def inject(records: Sequence[TlogRecord], config: InjectConfig) -> InjectResult:
    """Inject the bearing stream of ``config`` into ``records`` (pure; see the module
    docstring)."""
    flight = read_flight(records, config.sysid, config.compid)
    sysid = flight.sysid
    target = (
        np.asarray(config.target_ned_m, dtype=float)
        if config.target_ned_m is not None
        else auto_target(flight)
    )
    err = np.asarray(config.vel_error_ned_mps, dtype=float)
    rng = np.random.default_rng(config.seed)
    mav = codec(sysid, config.compid)
    target_name = config.target_name
    inserts: list[tuple[int, int, int, bytes]] = []
    truth: list[dict[str, Any]] = []
    not_visible = 0
    ranges: list[float] = []
    for e in sorted(flight.local_position):
        lpn = flight.local_position[e]
        att = flight.attitude.get(e)
        if att is None:
            continue
        t_ms = bearing_times_ms(
            lpn.t_boot_s,
            att.t_boot_s,
            config.rate_hz,
            config.max_gap_s,
            config.max_attitude_age_s,
        )
        if len(t_ms) == 0:
            continue
        t = t_ms * 1e-3
        # the vehicle in the world (the first frame), and the frame's reset at each time
        steps = frame_steps(lpn)
        world = _Series(lpn.t_boot_s, lpn.values.copy(), lpn.t_unix_s, lpn.record)
        world.values[:, :3] -= steps
        pv = interp_position(world, t)
        k_at = np.clip(np.searchsorted(lpn.t_boot_s, t, side="right") - 1, 0, len(steps) - 1)
        step_t = steps[k_at]
        rpy = interp_attitude(att, t)
        rel = target[None, :] - pv[:, :3]
        rng_m = np.linalg.norm(rel, axis=1)
        ok = rng_m > 1e-3
        t_ms, t, pv, rpy, rel, rng_m = t_ms[ok], t[ok], pv[ok], rpy[ok], rel[ok], rng_m[ok]
        step_t = step_t[ok]
        y_true = rel / rng_m[:, None]
        y = perturb_bearings(y_true, math.radians(config.noise_deg), rng)
        # anchors for the tlog time: every LOCAL_POSITION_NED and ATTITUDE of the epoch
        a_boot = np.concatenate((lpn.t_boot_s, att.t_boot_s))
        a_unix = np.concatenate((lpn.t_unix_s, att.t_unix_s))
        order = np.argsort(a_boot, kind="stable")
        a_boot, a_unix = a_boot[order], a_unix[order]
        # the clock records of the injection's component, else the autopilot's
        clock = flight.clock.get(e)
        if clock is not None and clock[0]:
            c_idx, c_boot = np.asarray(clock[0]), np.asarray(clock[1])
        else:
            c_idx = np.concatenate((lpn.record, att.record))
            c_boot = np.concatenate((lpn.t_boot_s, att.t_boot_s))
            o = np.argsort(c_idx, kind="stable")
            c_idx, c_boot = c_idx[o], c_boot[o]
        placement = (c_idx.tolist(), np.maximum.accumulate(c_boot).tolist())
        previous: tuple[int, int, int] | None = None
        for k in range(len(t)):
            mav.seq = len(inserts) % 256
            frame = bearing_frame(
                config.bearing, int(t_ms[k]), y[k], rpy[k], mav, config.gimbal_device_id
            )
            if frame is None:
                not_visible += 1
                continue
            j = int(np.searchsorted(a_boot, t[k]))
            cand = [c for c in (j - 1, j) if 0 <= c < len(a_boot)]
            near = min(cand, key=lambda c: abs(a_boot[c] - t[k]))
            t_unix = float(a_unix[near] + (t[k] - a_boot[near]))
            previous = _placement(records, placement, float(t[k]), t_unix, previous)
            _, pos, t_us = previous
            inserts.append((pos, int(t_ms[k]), t_us, frame))
            ranges.append(float(rng_m[k]))
            truth.append(
                truth_file.record(
                    t_unix_s=t_us * 1e-6,
                    t_boot_s=t_ms[k] / 1000.0,
                    sysid=sysid,
                    target=target_name,
                    rel_pos_ned_m=rel[k],
                    bias_ned_mps=err,
                    target_pos_ned_m=target + step_t[k],
                    vehicle_pos_ned_m=pv[k, :3] + step_t[k],
                    vehicle_vel_meas_ned_mps=pv[k, 3:6] + err,
                    attitude_rpy_rad=rpy[k],
                    bearing_ned=y[k],
                    epoch=e,
                )
            )
    # rewritten LOCAL_POSITION_NED
    replaced: dict[int, bytes] = {}
    if np.any(err != 0.0):
        for i, rec in enumerate(records):
            src = rec.source
            if rec.msgid == LPN_ID and src is not None and src[0] == sysid:
                try:
                    frame = rewrite_local_position(rec.frame, err)
                except DecodeError:
                    continue
                replaced[i] = rec.data[:8] + frame
    inserts.sort(key=lambda x: (x[0], x[1]))
    out: list[bytes] = []
    j = 0
    for i, rec in enumerate(records):
        while j < len(inserts) and inserts[j][0] <= i:
            out.append(inserts[j][2].to_bytes(8, "big") + inserts[j][3])
            j += 1
        out.append(replaced.get(i, rec.data))
    out.extend(ins[2].to_bytes(8, "big") + ins[3] for ins in inserts[j:])
    truth.sort(key=lambda d: (d["epoch"], d["t_boot_s"]))
    return InjectResult(
        records=out,
        truth=truth,
        target_ned_m=(float(target[0]), float(target[1]), float(target[2])),
        sysid=sysid,
        target=target_name,
        injected=len(inserts),
        skipped_not_visible=not_visible,
        rewritten_local_position=len(replaced),
        damage_chunks=sum(1 for r in records if r.t_us is None),
        epochs=flight.epochs,
        lpn_rate_hz=flight.lpn_rate_hz(),
        range_m=(min(ranges), max(ranges)) if ranges else (math.nan, math.nan),
        same_target_frames=same_target_frames(records, sysid, config),
    )


def inject_file(
    log_path: str | Path, out_path: str | Path, truth_path: str | Path, config: InjectConfig
) -> InjectResult:
    """Read ``log_path``, inject, write the new tlog and the truth (JSON Lines)."""
    data = Path(log_path).read_bytes()
    result = inject(split_records(data), config)
    with open(out_path, "wb") as fh:
        for chunk in result.records:
            fh.write(chunk)
    truth_file.write(truth_path, result.truth)
    return result


__all__ = [
    "BEARINGS",
    "InjectConfig",
    "InjectError",
    "InjectResult",
    "TlogRecord",
    "auto_target",
    "bearing_frame",
    "bearing_times_ms",
    "gimbal_quaternion",
    "inject",
    "inject_file",
    "interp_attitude",
    "interp_position",
    "landing_target_angles",
    "read_flight",
    "rewrite_local_position",
    "same_target_frames",
    "split_records",
]
