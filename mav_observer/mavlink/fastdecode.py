"""Fast decoding of the few MAVLink messages replay uses.

pymavlink's ``MAVLink.decode`` builds a full message object (header object, buffers, field
dictionaries), dear at a message's rate. Replay needs a handful of numeric messages at
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
from struct import Struct
from struct import error as StructError
from typing import Any

from mav_observer.mavlink import dialect
from mav_observer.mavlink.dialect import Wire

try:
    from fastcrc.crc16 import mcrf4xx as _crc16
except ImportError:  # pragma: no cover - pymavlink depends on fastcrc
    _crc16 = None


class DecodeError(Exception):
    """A frame that does not decode; ``reason`` is ``bad_crc`` or ``invalid_frame``."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def message_class(name: str, fields: list[str]) -> type:
    """The named tuple class of message ``name`` with ``fields`` (declared order), as this
    decoder returns it."""
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

    __slots__ = ("cls", "crc_extra", "fields", "size", "unpack", "unpack_from")

    def __init__(self, w: Wire) -> None:
        name, fieldnames, fmt, orders, lengths, crc_extra, _ = w
        self.crc_extra = bytes([crc_extra])
        unpacker = Struct(fmt)
        self.unpack = unpacker.unpack
        self.unpack_from = unpacker.unpack_from
        self.size = unpacker.size
        self.cls = message_class(name, list(fieldnames))
        #: the unpacked payload (wire order) to the fields (declared order, arrays as
        #: lists); ``None`` where they are the same
        self.fields: Any = None
        if sum(lengths) != len(lengths):
            # written out (``lambda t: (t[8], [*t[1:5]], ...)``): a generator over the
            # fields is slower
            spans = [(sum(lengths[:order]), lengths[order]) for order in orders]
            terms = [f"t[{tip}]" if n == 1 else f"[*t[{tip}:{tip + n}]]" for tip, n in spans]
            self.fields = eval(f"lambda t: ({', '.join(terms)},)")
        elif list(orders) != list(range(len(orders))):
            self.fields = itemgetter(*orders) if len(orders) > 1 else lambda t: (t[orders[0]],)


def supports(msgtype: Any) -> bool:
    """True for messages without string fields (the ones decoded here)."""
    return "char" not in msgtype.fieldtypes and _crc16 is not None


_new = tuple.__new__


class FastDecoder:
    """Decode frames of the given message ids (others, and string-bearing ones, through
    pymavlink). ``decode(frame)`` takes the raw frame bytes (bytes or memory slices);
    :meth:`decode_at` a whole frame inside a larger buffer (a tlog's)."""

    def __init__(self, msgids: frozenset[int] | set[int] | None = None) -> None:
        self._fallback: Any = None
        self._plans: dict[int, _Plan] = {}
        ids = dialect.mavlink.mavlink_map.keys() if msgids is None else msgids
        for msgid in ids:
            w = dialect.wire(msgid)
            if w is not None and not w[6] and _crc16 is not None:
                self._plans[msgid] = _Plan(w)

    def _pymavlink(self, frame: Any) -> Any:
        """``frame`` decoded by pymavlink (made when first needed: its dialect is imported
        then)."""
        mavlink = dialect.mavlink
        if self._fallback is None:
            self._fallback = mavlink.MAVLink(None)
        try:
            return self._fallback.decode(bytearray(frame))
        except mavlink.MAVError as exc:
            raise DecodeError(
                "bad_crc" if "CRC" in str(exc) else "invalid_frame", str(exc)
            ) from exc

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
            return self._pymavlink(frame)
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
        if plan.fields is not None:
            t = plan.fields(t)
        if hlen == 10:
            return _new(plan.cls, (*t, frame[5], frame[6]))
        return _new(plan.cls, (*t, frame[3], frame[4]))

    def decode_at(self, buf: Any, start: int, end: int, msgid: int) -> Any:
        """The frame ``buf[start:end]`` of message ``msgid`` decoded, as :meth:`decode` would;
        the frame must be whole (its length the one its header gives), as a tlog reader
        finds it. A payload of the message's full size is read in place."""
        plan = self._plans.get(msgid)
        if plan is None:
            return self.decode(buf[start:end])
        plen = buf[start + 1]
        if buf[start] == 0xFD:  # where the system and component ids are, where the CRC is
            src, body = start + 5, start + 10 + plen
        else:
            src, body = start + 3, start + 6 + plen
        if _crc16(buf[start + 1 : body] + plan.crc_extra) != buf[body] | (buf[body + 1] << 8):
            raise DecodeError("bad_crc", f"msgid {msgid}")
        if plen >= plan.size:
            t = plan.unpack_from(buf, body - plen)
        else:  # a MAVLink 2 payload whose trailing zeros were trimmed
            t = plan.unpack(buf[body - plen : body] + bytes(plan.size - plen))
        if plan.fields is not None:
            t = plan.fields(t)
        return _new(plan.cls, (*t, buf[src], buf[src + 1]))
