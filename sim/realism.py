"""What real links, clocks and sensors do to the emitter's ideal stream (pure: no I/O but
:func:`write`).

The emitter (:mod:`sim.emitter`) sends every message at its sample time, from the
autopilot's component, with the scenario's velocity error. A :class:`Realism` stage takes
those emissions and returns them as a reader would receive them, each knob off by default:

* **per-stream latency and jitter** (``attitude_latency_s``, ``position_latency_s``,
  ``bearing_latency_s``, ``jitter_s``): a message arrives at its sample time plus its
  stream's latency plus a uniform delay in ``[0, jitter_s]``; each stream stays in order (a
  link is first in, first out per sender), the streams interleave by arrival. So a bearing
  may arrive before or after the ATTITUDE of its own time. ``time_boot_ms`` is untouched;
* **a bearing sender that is its own component** (``component_id``, e.g. 154, a gimbal),
  with **its own boot clock** (``component_boot_offset_s``, ``component_clock_drift_ppm``):
  its ``time_boot_ms`` (or LANDING_TARGET's boot-clock ``time_usec``) is
  ``t_boot * (1 + drift_ppm 1e-6) + offset``, ``t_boot`` the autopilot's time of the sample;
* **velocity error** beyond the emitter's white noise: a first-order Gauss-Markov part
  (``velocity_gm_std_mps`` stationary standard deviation per axis, ``velocity_gm_tau_s``
  correlation time; exact discretisation) and a constant (``velocity_bias_ned_mps``), added
  to LOCAL_POSITION_NED's and GLOBAL_POSITION_INT's velocity; positions stay true (GNSS-like).
  The constant joins the truth's ``bias_ned_mps`` (``x' = -u_true = v + a`` with
  ``v = -u_measured``: ``a`` grows by the added error); the Gauss-Markov part is noise;
* **bearing dropouts in bursts** (``dropout_every_s``, ``dropout_length_s``): no bearing
  message for ``dropout_length_s`` every ``dropout_every_s`` (a random phase);
* **gimbal tracking lag** (``gimbal_lag_s``): the gimbal's boresight follows the line of
  sight through a first-order lag of that time constant (a gimbal controller behind a moving
  target), its noise kept; the message reports where the gimbal points, the truth stays where
  the target is: a model error the estimator is not told of (GIMBAL_DEVICE_ATTITUDE_STATUS
  bearings; a tracked point in the image would see the target where it is);
* **the tlog's own clock** (``tlog_jitter_s``, ``tlog_jumps``): the timestamp written for
  a message is its arrival plus a uniform ``[0, tlog_jitter_s]`` and, from scenario time
  ``t``, each ``(t, delta_s)`` jump (a logger whose clock was stepped).

:class:`SwingVehicle` adds a yaw swing to the vehicle (yaw rates up to 60 deg/s and more),
every message staying exact (the bearing messages are built from the attitude of their time).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mav_observer.geo.frames import quat_from_euler
from mav_observer.mavlink.dialect import MSG_ID, codec
from mav_observer.tracking import directions as adapters
from sim import truth as truth_file
from sim.emitter import AUTOPILOT, Emission
from sim.vehicle import Vehicle

STREAMS = {
    MSG_ID["ATTITUDE"]: "attitude",
    MSG_ID["ATTITUDE_QUATERNION"]: "attitude",
    MSG_ID["LOCAL_POSITION_NED"]: "position",
    MSG_ID["GLOBAL_POSITION_INT"]: "position",
    MSG_ID["GIMBAL_DEVICE_ATTITUDE_STATUS"]: "bearing",
    MSG_ID["MOUNT_ORIENTATION"]: "bearing",
    MSG_ID["MOUNT_STATUS"]: "bearing",
    MSG_ID["LANDING_TARGET"]: "bearing",
    MSG_ID["CAMERA_TRACKING_IMAGE_STATUS"]: "bearing",
    MSG_ID["CAMERA_FOV_STATUS"]: "bearing",
}
#: Bearing messages whose time and component the component knobs change.
_TIMED_BEARINGS = {
    MSG_ID["GIMBAL_DEVICE_ATTITUDE_STATUS"],
    MSG_ID["MOUNT_ORIENTATION"],
    MSG_ID["MOUNT_STATUS"],
    MSG_ID["LANDING_TARGET"],
}
_LPN = MSG_ID["LOCAL_POSITION_NED"]
_GIMBAL = MSG_ID["GIMBAL_DEVICE_ATTITUDE_STATUS"]
_GPI = MSG_ID["GLOBAL_POSITION_INT"]


def msgid(frame: bytes) -> int:
    """The message id of a MAVLink 1 or 2 frame."""
    if frame[0] == 0xFD:
        return frame[7] | frame[8] << 8 | frame[9] << 16
    return frame[5]


@dataclass(frozen=True)
class Arrival:
    """A message as received: when (scenario seconds), the tlog timestamp written for it
    (Unix seconds), its bytes, and the truth record it carries (bearing messages)."""

    t_arrival_s: float
    t_tlog_unix_s: float
    frame: bytes
    truth: dict[str, Any] | None = None


@dataclass(frozen=True)
class Realism:
    """The knobs (see the module docstring); all off by default. Times in s."""

    attitude_latency_s: float = 0.0
    position_latency_s: float = 0.0
    bearing_latency_s: float = 0.0
    jitter_s: float = 0.0
    component_id: int | None = None
    component_boot_offset_s: float = 0.0
    component_clock_drift_ppm: float = 0.0
    velocity_gm_std_mps: float = 0.0
    velocity_gm_tau_s: float = 60.0
    velocity_bias_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dropout_every_s: float = 0.0
    dropout_length_s: float = 0.0
    gimbal_lag_s: float = 0.0
    tlog_jitter_s: float = 0.0
    tlog_jumps: tuple[tuple[float, float], ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        for name in (
            "attitude_latency_s",
            "position_latency_s",
            "bearing_latency_s",
            "jitter_s",
            "velocity_gm_std_mps",
            "dropout_every_s",
            "dropout_length_s",
            "gimbal_lag_s",
            "tlog_jitter_s",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if not self.velocity_gm_tau_s > 0.0:
            raise ValueError(f"velocity_gm_tau_s must be > 0, got {self.velocity_gm_tau_s!r}")
        if self.dropout_length_s and not 0.0 < self.dropout_length_s < self.dropout_every_s:
            raise ValueError(
                f"dropout_length_s must be in (0, dropout_every_s), got {self.dropout_length_s}"
            )
        if self.component_id is not None and not 0 < self.component_id < 256:
            raise ValueError(f"component_id must be in 1..255, got {self.component_id!r}")
        if len(self.velocity_bias_ned_mps) != 3:
            raise ValueError(
                f"velocity_bias_ned_mps must have 3 values, got {self.velocity_bias_ned_mps!r}"
            )

    def _lag(self, msg: Any, truth: dict[str, Any], lagged: list[Any], enc: Any) -> bytes:
        """The gimbal message re-made to point along the lagged line of sight (its noise,
        the difference between its boresight and the true line of sight, kept)."""
        x = np.asarray(truth["rel_pos_ned_m"], dtype=float)
        los = x / np.linalg.norm(x)
        t = float(truth["t_boot_s"])
        if lagged[0] is None:
            lagged[0] = los
        else:
            f = math.exp(-(t - lagged[1]) / self.gimbal_lag_s)
            y = f * lagged[0] + (1.0 - f) * los
            lagged[0] = y / np.linalg.norm(y)
        lagged[1] = t
        yaw_v = float(truth["attitude_rpy_rad"][2])
        earth = adapters.gimbal_yaw_frame(msg.flags) == "earth"
        sent = np.asarray(
            adapters.gimbal_boresight(tuple(msg.q), msg.flags, 0, vehicle_yaw=yaw_v), dtype=float
        )
        y = lagged[0] + (sent - los)
        y /= np.linalg.norm(y)
        yaw = math.atan2(y[1], y[0]) - (0.0 if earth else yaw_v)
        pitch = -math.asin(max(-1.0, min(1.0, y[2])))
        msg.q = list(quat_from_euler(0.0, pitch, yaw))
        return bytes(msg.pack(enc))

    def component_time_s(self, t_boot_s: float) -> float:
        """The component's clock reading (s) at the autopilot's ``t_boot_s``."""
        return (
            t_boot_s * (1.0 + 1e-6 * self.component_clock_drift_ppm) + self.component_boot_offset_s
        )

    def apply(
        self, emissions: Iterable[Emission], t0_unix_s: float, sysid: int = 1
    ) -> list[Arrival]:
        """The emitter's ``emissions`` (in emission order) as received, in arrival order."""
        rng = np.random.default_rng([self.seed, 7])
        latency = {
            "attitude": self.attitude_latency_s,
            "position": self.position_latency_s,
            "bearing": self.bearing_latency_s,
        }
        last: dict[str, float] = {}
        dec = codec()
        enc_ap = codec(sysid, AUTOPILOT)
        enc_comp = None if self.component_id is None else codec(sysid, self.component_id)
        bias = np.asarray(self.velocity_bias_ned_mps, dtype=float)
        vel_err = self.velocity_gm_std_mps > 0.0 or bool(np.any(bias))
        gm = (
            rng.normal(0.0, self.velocity_gm_std_mps, 3)
            if self.velocity_gm_std_mps
            else np.zeros(3)
        )
        gm_t: float | None = None
        phase = rng.uniform(0.0, self.dropout_every_s) if self.dropout_every_s else 0.0
        lagged: list[Any] = [None, None]  # the lagged line of sight (NED) and its time
        out: list[tuple[float, int, bytes, dict[str, Any] | None]] = []
        for k, em in enumerate(emissions):
            frame, truth = em.frame, em.truth
            mid = msgid(frame)
            stream = STREAMS.get(mid, "other")
            t = em.t_emit_s
            if (
                stream == "bearing"
                and self.dropout_length_s
                and (t - phase) % self.dropout_every_s < self.dropout_length_s
            ):
                continue
            if vel_err and mid in (_LPN, _GPI):
                if mid == _LPN:
                    if self.velocity_gm_std_mps and gm_t is not None:
                        f = math.exp(-(t - gm_t) / self.velocity_gm_tau_s)
                        gm = f * gm + math.sqrt(1.0 - f * f) * rng.normal(
                            0.0, self.velocity_gm_std_mps, 3
                        )
                    gm_t = t
                err = gm + bias
                msg = dec.decode(bytearray(frame))
                if mid == _LPN:
                    msg.vx, msg.vy, msg.vz = (msg.vx + err[0], msg.vy + err[1], msg.vz + err[2])
                else:
                    msg.vx, msg.vy, msg.vz = (
                        round(msg.vx + 100 * err[0]),
                        round(msg.vy + 100 * err[1]),
                        round(msg.vz + 100 * err[2]),
                    )
                frame = bytes(msg.pack(enc_ap))
            if self.gimbal_lag_s and mid == _GIMBAL and truth is not None:
                frame = self._lag(dec.decode(bytearray(frame)), truth, lagged, enc_ap)
            if enc_comp is not None and mid in _TIMED_BEARINGS:
                msg = dec.decode(bytearray(frame))
                if hasattr(msg, "time_boot_ms"):
                    msg.time_boot_ms = round(
                        1000.0 * self.component_time_s(msg.time_boot_ms * 1e-3)
                    )
                elif mid == MSG_ID["LANDING_TARGET"] and msg.time_usec < 10**12:  # boot clock
                    msg.time_usec = round(1e6 * self.component_time_s(msg.time_usec * 1e-6))
                frame = bytes(msg.pack(enc_comp))
            if truth is not None and np.any(bias):
                truth = dict(truth)
                truth["bias_ned_mps"] = (np.asarray(truth["bias_ned_mps"]) + bias).tolist()
            arrival = t + latency.get(stream, 0.0)
            if self.jitter_s:
                arrival += rng.uniform(0.0, self.jitter_s)
            arrival = max(arrival, last.get(stream, -math.inf))  # first in, first out
            last[stream] = arrival
            out.append((arrival, k, frame, truth))
        out.sort(key=lambda a: (a[0], a[1]))
        arrivals = []
        for arrival, _, frame, truth in out:
            t_tlog = t0_unix_s + arrival + sum(d for t_at, d in self.tlog_jumps if arrival >= t_at)
            if self.tlog_jitter_s:
                t_tlog += rng.uniform(0.0, self.tlog_jitter_s)
            told = None if truth is None else {**truth, "t_unix_s": t0_unix_s + arrival}
            arrivals.append(Arrival(arrival, t_tlog, frame, told))
        return arrivals


def write(
    arrivals: Iterable[Arrival], *, tlog: Path | None = None, truth: Path | None = None
) -> int:
    """Write the arrivals as a tlog (their ``t_tlog_unix_s``) and their truth as JSON Lines;
    returns the number of messages."""
    n = 0
    with (
        open(tlog or "/dev/null", "wb") as fh,
        open(truth or "/dev/null", "w", encoding="utf-8") as th,
    ):
        for a in arrivals:
            fh.write(struct.pack(">Q", max(0, round(a.t_tlog_unix_s * 1e6))) + a.frame)
            if a.truth is not None:
                th.write(truth_file.dumps(a.truth) + "\n")
            n += 1
    return n


@dataclass(frozen=True)
class SwingVehicle(Vehicle):
    """A :class:`~sim.vehicle.Vehicle` whose yaw swings ``yaw_swing_deg`` either way around
    the target's direction, one swing per ``yaw_swing_period_s``: the extra yaw rate peaks at
    ``2 pi yaw_swing_deg / yaw_swing_period_s`` deg/s (57 deg over 6 s: 60 deg/s). Roll and
    pitch still tilt the thrust to the acceleration."""

    yaw_swing_deg: float = 0.0
    yaw_swing_period_s: float = 6.0

    def yaw_offset(self, t: float) -> float:
        return math.radians(self.yaw_swing_deg) * math.sin(
            2 * math.pi * t / self.yaw_swing_period_s
        )


__all__ = ["STREAMS", "Arrival", "Realism", "SwingVehicle", "msgid", "write"]
