"""Helpers for tests: real MAVLink frames and decoded messages, and tlog files."""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

from mav_observer.mavlink.dialect import codec, mavlink
from sim.tlogs import find_tlogs

T0_UNIX = 1_767_225_600.0


def frame(name: str, *fields: Any, sysid: int = 1, compid: int = 1, v1: bool = False) -> bytes:
    """Packed frame of message ``name`` (pymavlink's class ``MAVLink_<name>_message``)."""
    cls = getattr(mavlink, f"MAVLink_{name.lower()}_message")
    mav = codec(sysid, compid)
    if v1:
        return bytes(cls(*fields).pack(mav, force_mavlink1=True))
    return bytes(cls(*fields).pack(mav))


def message(name: str, *fields: Any, sysid: int = 1, compid: int = 1) -> Any:
    """A decoded message, as a reader would hand it over."""
    return codec().decode(bytearray(frame(name, *fields, sysid=sysid, compid=compid)))


def landing_target_fields(
    time_usec: int, target_num: int, frame_id: int, angle_x: float, angle_y: float
) -> tuple[Any, ...]:
    """LANDING_TARGET's positional fields with the rest zero (no position, no size)."""
    zeros = (0.0,) * 6  # distance, size_x, size_y, x, y, z
    return (time_usec, target_num, frame_id, angle_x, angle_y, *zeros, [1.0, 0.0, 0.0, 0.0], 0, 0)


def tlog(path: Path, records: list[tuple[float, bytes]]) -> Path:
    """Write ``(t_unix_s, frame)`` records as a tlog."""
    with open(path, "wb") as fh:
        for t, fr in records:
            fh.write(struct.pack(">Q", round(t * 1e6)) + fr)
    return path


TLOGS = find_tlogs()
