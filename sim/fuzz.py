"""Seeded garbage for robustness tests: damaged and nonsensical MAVLink frames (pure).

:func:`garbage` yields ``(kind, frame_bytes)``; every kind is a way real links and buggy peers
damage traffic:

* ``random_bytes``: 1 to 300 random bytes;
* ``bit_flip``: a valid frame with 1 to 8 bits flipped;
* ``truncated``: a valid frame cut short; ``over_long``: a valid frame with junk appended;
* ``wrong_length``: a valid frame whose length byte lies;
* ``bad_crc``: a valid frame with its checksum changed;
* ``unknown_msgid``: a well-formed MAVLink 2 frame of a message id no dialect defines;
* ``nonsense``: a correctly framed and checksummed message of the vehicle's own system id
  whose fields are NaN, infinite or absurd: NaN or infinite velocities, zero, NaN and
  non-unit quaternions, a gimbal reporting failure flags, angles of 1e30 rad, a time_boot_ms
  of 2^32 - 1, a LANDING_TARGET pointing nowhere.

The valid frames come from :func:`sample_frames`. No I/O; the caller sends or writes them.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator

import numpy as np

from mav_observer.mavlink.dialect import codec, mavlink

KINDS = (
    "random_bytes",
    "bit_flip",
    "truncated",
    "over_long",
    "wrong_length",
    "bad_crc",
    "unknown_msgid",
    "nonsense",
)
NAN, INF = math.nan, math.inf


def sample_frames(sysid: int = 1, compid: int = 1) -> list[bytes]:
    """A handful of valid MAVLink 2 frames of the kinds the service reads (to be damaged)."""
    m = codec(sysid, compid)
    msgs = [
        m.heartbeat_encode(2, 3, 0, 0, 4),
        m.local_position_ned_encode(1000, 1.0, 2.0, -10.0, 0.5, -0.5, 0.0),
        m.attitude_encode(1000, 0.01, 0.02, 1.0, 0.0, 0.0, 0.0),
        m.gimbal_device_attitude_status_encode(
            0, 0, 1000, 0, [0.9, 0.0, -0.43, 0.0], 0.0, 0.0, 0.0, 0
        ),
        m.global_position_int_encode(1000, 0, 0, 0, 0, 0, 0, 0, 0),
    ]
    return [bytes(x.pack(m)) for x in msgs]


def nonsense_frames(sysid: int = 1, compid: int = 1) -> list[bytes]:
    """Correctly framed messages with absurd contents (see the module docstring)."""
    m = codec(sysid, compid)
    gimbal = m.gimbal_device_attitude_status_encode
    failure = mavlink.GIMBAL_DEVICE_ERROR_FLAGS_AT_ROLL_LIMIT | 0x0100  # limit + a fault bit
    msgs = [
        m.local_position_ned_encode(1000, NAN, 0.0, 0.0, NAN, NAN, NAN),
        m.local_position_ned_encode(1000, 0.0, 0.0, 0.0, INF, -INF, 1e30),
        m.attitude_encode(1000, NAN, 1e30, -INF, 0.0, 0.0, 0.0),
        m.attitude_quaternion_encode(1000, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        gimbal(0, 0, 1000, 0, [0.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0),
        gimbal(0, 0, 1000, 0, [NAN, 0.0, 0.0, 1.0], 0.0, 0.0, 0.0, 0),
        gimbal(0, 0, 1000, 0, [3.0, 4.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0),
        gimbal(0, 0, 1000, 0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, failure),
        gimbal(0, 0, 2**32 - 1, 0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0),
        m.landing_target_encode(0, 0, 0, NAN, INF, 1e30, 0.0, 0.0),
        m.mount_orientation_encode(1000, NAN, INF, -INF, 1e30),
        m.local_position_ned_encode(2**32 - 1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    ]
    return [bytes(x.pack(m)) for x in msgs]


def unknown_msgid_frame(rng: np.random.Generator, sysid: int) -> bytes:
    """A MAVLink 2 frame with a message id no dialect defines (checksum without crc_extra)."""
    payload = rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
    msgid = int(rng.integers(40000, 2**24))
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, sysid, 1,
                         msgid & 0xFFFF, msgid >> 16)  # fmt: skip
    crc = mavlink.x25crc(header[1:] + payload).crc
    return header + payload + struct.pack("<H", crc)


def garbage(rng: np.random.Generator, count: int, *, sysid: int = 1) -> Iterator[tuple[str, bytes]]:
    """``count`` damaged or nonsensical frames, kinds drawn evenly from :data:`KINDS`."""
    valid = sample_frames(sysid)
    nonsense = nonsense_frames(sysid)
    for _ in range(count):
        kind = KINDS[int(rng.integers(len(KINDS)))]
        base = bytearray(valid[int(rng.integers(len(valid)))])
        if kind == "random_bytes":
            out = rng.integers(0, 256, int(rng.integers(1, 301)), dtype=np.uint8).tobytes()
        elif kind == "bit_flip":
            for _ in range(int(rng.integers(1, 9))):
                i = int(rng.integers(len(base) * 8))
                base[i // 8] ^= 1 << (i % 8)
            out = bytes(base)
        elif kind == "truncated":
            out = bytes(base[: int(rng.integers(1, len(base)))])
        elif kind == "over_long":
            junk = rng.integers(0, 256, int(rng.integers(1, 64)), dtype=np.uint8).tobytes()
            out = bytes(base) + junk
        elif kind == "wrong_length":
            base[1] = (base[1] + int(rng.integers(1, 255))) % 256
            out = bytes(base)
        elif kind == "bad_crc":
            base[-1] ^= int(rng.integers(1, 256))
            out = bytes(base)
        elif kind == "unknown_msgid":
            out = unknown_msgid_frame(rng, sysid)
        else:
            out = nonsense[int(rng.integers(len(nonsense)))]
        yield kind, out
