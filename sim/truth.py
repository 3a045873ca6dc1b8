"""The simulator's truth file: one JSON object per line, one line per bearing message.

Owned here and written only through :func:`record` and :func:`write`, by the emitter
(:mod:`sim.emitter`), the realism stage (:mod:`sim.realism`) and the injector
(:mod:`sim.inject`). Its first five keys (``t_boot_s``, ``sysid``, ``target``,
``rel_pos_ned_m``, ``bias_ned_mps``) carry the names and meaning of the product's estimate
record, so a truth file is also a *reference track* that ``mav-observer replay --truth`` reads
(:mod:`mav_observer.app.reference`, ``docs/schema.md``); the product parses nothing else of it.

==============================  ===================================================================
``t_unix_s``                    tlog time of the bearing message, s
``t_boot_s``                    its measurement time on the vehicle's autopilot clock, s
``sysid``                       MAVLink system id of the vehicle
``target``                      the reader's target name (``gimbal``, ``landing_target_0``...)
``rel_pos_ned_m``               true target minus vehicle position, NED, m
``bias_ned_mps``                true ``a``: target velocity minus the velocity error, NED, m/s
``target_pos_ned_m``            the target's position, LOCAL_POSITION_NED frame, m
``vehicle_pos_ned_m``           the vehicle's true position, m
``vehicle_vel_meas_ned_mps``    the velocity the vehicle reports (with its error), m/s
``attitude_rpy_rad``            roll, pitch, yaw of the vehicle, rad
``bearing_ned``                 (injector) the unit bearing sent (noise included), NED, optional
``epoch``                       (injector) the boot epoch of the log, optional
==============================  ===================================================================
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

#: The keys every truth line has, in order (the optional ones follow).
KEYS = (
    "t_unix_s",
    "t_boot_s",
    "sysid",
    "target",
    "rel_pos_ned_m",
    "bias_ned_mps",
    "target_pos_ned_m",
    "vehicle_pos_ned_m",
    "vehicle_vel_meas_ned_mps",
    "attitude_rpy_rad",
)
OPTIONAL_KEYS = ("bearing_ned", "epoch")


def _vec(v: Sequence[float] | Any) -> list[float]:
    return [float(x) for x in v]


def record(
    *,
    t_unix_s: float,
    t_boot_s: float,
    sysid: int,
    target: str,
    rel_pos_ned_m: Sequence[float],
    bias_ned_mps: Sequence[float],
    target_pos_ned_m: Sequence[float],
    vehicle_pos_ned_m: Sequence[float],
    vehicle_vel_meas_ned_mps: Sequence[float],
    attitude_rpy_rad: Sequence[float],
    bearing_ned: Sequence[float] | None = None,
    epoch: int | None = None,
) -> dict[str, Any]:
    """One truth line (a plain dict, JSON-ready); vectors as lists of floats."""
    d: dict[str, Any] = {
        "t_unix_s": float(t_unix_s),
        "t_boot_s": float(t_boot_s),
        "sysid": int(sysid),
        "target": str(target),
        "rel_pos_ned_m": _vec(rel_pos_ned_m),
        "bias_ned_mps": _vec(bias_ned_mps),
        "target_pos_ned_m": _vec(target_pos_ned_m),
        "vehicle_pos_ned_m": _vec(vehicle_pos_ned_m),
        "vehicle_vel_meas_ned_mps": _vec(vehicle_vel_meas_ned_mps),
        "attitude_rpy_rad": _vec(attitude_rpy_rad),
    }
    if bearing_ned is not None:
        d["bearing_ned"] = _vec(bearing_ned)
    if epoch is not None:
        d["epoch"] = int(epoch)
    return d


def dumps(d: dict[str, Any]) -> str:
    """One line of the file (no newline)."""
    return json.dumps(d)


def write(path: str | Path, lines: Iterable[dict[str, Any]]) -> int:
    """Write truth lines to ``path``; returns how many."""
    n = 0
    with open(path, "w", encoding="utf-8") as fh:
        for d in lines:
            fh.write(dumps(d) + "\n")
            n += 1
    return n


def read(path: str | Path, target: str | None = None) -> list[dict[str, Any]]:
    """The truth lines of ``path`` (of one ``target`` if given), in file order."""
    out = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.strip():
                d = json.loads(line)
                if target is None or d["target"] == target:
                    out.append(d)
    return out


__all__ = ["KEYS", "OPTIONAL_KEYS", "dumps", "read", "record", "write"]
