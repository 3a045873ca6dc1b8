"""Fast decoding of the few MAVLink messages replay uses.

pymavlink's ``MAVLink.decode`` builds a full message object (header object, buffers, field
dictionaries): about 5 microseconds a message. Replay needs a handful of numeric messages at
high rates, so this module decodes those itself from pymavlink's own metadata (the wire-order
``unpacker``, the field ``orders`` and array ``lengths``, the ``crc_extra``), with the same
checks: the frame length against the header, the CRC (CRC-16/MCRF4XX with the message's extra
byte, through ``fastcrc``, which pymavlink itself uses), zero-padding of MAVLink 2 payloads
that were trimmed. The result is a small named tuple with the message's fields (arrays as
lists) and pymavlink's ``get_type()``, ``get_srcSystem()``, ``get_srcComponent()``.

Messages with string fields, unknown ids, or (if ``fastcrc`` is missing) everything, go through
pymavlink's decoder instead. Signatures are not checked here (as pymavlink without a signing
key); a reader that verifies signatures must use pymavlink's decoder.
"""

from __future__ import annotations

from collections import namedtuple
from operator import itemgetter
from struct import error as StructError
from typing import Any

from mav_observer.mavlink.dialect import mavlink

try:
    from fastcrc.crc16 import mcrf4xx as _crc16
except ImportError:  # pragma: no cover - pymavlink depends on fastcrc
    _crc16 = None


class DecodeError(Exception):
    """A frame that does not decode; ``reason`` is ``bad_crc`` or ``invalid_frame``."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def _message_class(name: str, fields: list[str]) -> type:
    base = namedtuple(
        f"Fast{name.title().replace('_', '')}", [*fields, "src_system_", "src_component_"]
    )  # type: ignore[misc]

    def get_type(self: Any) -> str:
        return name

    def get_srcSystem(self: Any) -> int:
        return self.src_system_

    def get_srcComponent(self: Any) -> int:
        return self.src_component_

    return type(
        base.__name__,
        (base,),
        {
            "__slots__": (),
            "get_type": get_type,
            "get_srcSystem": get_srcSystem,
            "get_srcComponent": get_srcComponent,
        },
    )


class _Plan:
    """How to turn one message id's payload into its fields."""

    __slots__ = ("arrays", "cls", "crc_extra", "reorder", "size", "unpack")

    def __init__(self, msgtype: Any) -> None:
        self.crc_extra = bytes([msgtype.crc_extra])
        self.unpack = msgtype.unpacker.unpack
        self.size = msgtype.unpacker.size
        orders, lengths = msgtype.orders, msgtype.lengths
        self.cls = _message_class(msgtype.msgname, list(msgtype.fieldnames))
        if sum(lengths) == len(lengths):
            self.arrays = None
            self.reorder = (
                itemgetter(*orders) if len(orders) > 1 else (lambda t, _o=orders[0]: (t[_o],))
            )
        else:
            spans = []
            for order in orders:
                n = lengths[order]
                tip = sum(lengths[:order])
                spans.append((tip, n))
            self.arrays = spans
            self.reorder = None


def supports(msgtype: Any) -> bool:
    """True for messages without string fields (the ones decoded here)."""
    return "char" not in msgtype.fieldtypes and _crc16 is not None


class FastDecoder:
    """Decode frames of the given message ids (others, and string-bearing ones, through
    pymavlink). ``decode(frame)`` takes the raw frame bytes (bytes or memory slices)."""

    def __init__(self, msgids: frozenset[int] | set[int] | None = None) -> None:
        self._fallback = mavlink.MAVLink(None)
        self._plans: dict[int, _Plan] = {}
        ids = mavlink.mavlink_map.keys() if msgids is None else msgids
        for msgid in ids:
            msgtype = mavlink.mavlink_map.get(msgid)
            if msgtype is not None and supports(msgtype):
                self._plans[msgid] = _Plan(msgtype)

    def decode(self, frame: bytes) -> Any:
        if frame[0] == 0xFD:
            hlen = 10
            msgid = frame[7] | (frame[8] << 8) | (frame[9] << 16)
            siglen = 13 if frame[2] & 1 else 0
        else:
            hlen = 6
            msgid = frame[5]
            siglen = 0
        plan = self._plans.get(msgid)
        if plan is None:
            try:
                return self._fallback.decode(bytearray(frame))
            except mavlink.MAVError as exc:
                raise DecodeError(
                    "bad_crc" if "CRC" in str(exc) else "invalid_frame", str(exc)
                ) from exc
        plen = frame[1]
        end = hlen + plen
        if len(frame) != end + 2 + siglen:
            raise DecodeError("invalid_frame", f"length {len(frame)} for payload {plen}")
        crc = frame[end] | (frame[end + 1] << 8)
        if _crc16(bytes(frame[1:end]) + plan.crc_extra) != crc:
            raise DecodeError("bad_crc", f"msgid {msgid}")
        payload = frame[hlen:end]
        if plen < plan.size:
            payload = bytes(payload) + bytes(plan.size - plen)
        elif plen > plan.size:
            payload = payload[: plan.size]
        try:
            t = plan.unpack(payload)
        except StructError as exc:
            raise DecodeError("invalid_frame", str(exc)) from exc
        if plan.arrays is None:
            values = plan.reorder(t)
        else:
            values = tuple(t[tip] if n == 1 else list(t[tip : tip + n]) for tip, n in plan.arrays)
        if hlen == 10:
            return plan.cls(*values, frame[5], frame[6])
        return plan.cls(*values, frame[3], frame[4])
