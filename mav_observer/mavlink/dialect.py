"""The one place that chooses the MAVLink dialect: MAVLink 2, ``ardupilotmega`` (which includes
``common``). MAVLink 1 frames still decode with it.

pymavlink picks its protocol version from the ``MAVLINK20`` environment variable when
``mavutil`` is first imported, so this module sets it before importing anything from
pymavlink. Import pymavlink through here, never directly.

Neither the dialect's module (``dialect.mavlink``) nor ``mavutil`` (the links) is imported
before it is first used: the dialect is a large module, slow to import, and
``mavutil`` brings every MAVLink 1 and 2 dialect with it; reading a log needs neither. The
message names by id, and the wire layout of the messages the tracker uses
(:data:`TABLE_MESSAGES`), come from :mod:`~mav_observer.mavlink._dialect_table`, written from
the dialect by ``python -m mav_observer.mavlink.dialect`` and used only while the installed
pymavlink is the one it was written from (else they come from the dialect itself).
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

import sys
from typing import TYPE_CHECKING, Any

import pymavlink

if TYPE_CHECKING:
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

DIALECT = "ardupilotmega"
_DIALECT_MODULE = f"pymavlink.dialects.v20.{DIALECT}"

#: The messages whose wire layout the table holds: those the tracker may ask a reader for.
TABLE_MESSAGES = (
    "HEARTBEAT", "SYSTEM_TIME", "LOCAL_POSITION_NED", "ATTITUDE", "ATTITUDE_QUATERNION",
    "GPS_GLOBAL_ORIGIN", "HOME_POSITION", "GLOBAL_POSITION_INT", "GIMBAL_DEVICE_ATTITUDE_STATUS",
    "CAMERA_TRACKING_IMAGE_STATUS", "CAMERA_FOV_STATUS", "CAMERA_INFORMATION",
    "MOUNT_ORIENTATION", "MOUNT_STATUS", "LANDING_TARGET", "DISTANCE_SENSOR",
)  # fmt: skip

#: A message's wire layout: ``(name, field names, struct format of the payload in wire
#: order, the wire position of each field in declared order, each wire field's array length,
#: CRC extra byte, True if a field is a string)``.
Wire = tuple[str, tuple[str, ...], str, tuple[int, ...], tuple[int, ...], int, bool]


def _fingerprint() -> tuple[str, int]:
    """pymavlink's version and the size of the dialect's source, or ``("", -1)``."""
    path = os.path.join(os.path.dirname(pymavlink.__file__), "dialects", "v20", f"{DIALECT}.py")
    try:
        return pymavlink.__version__, os.path.getsize(path)
    except (AttributeError, OSError):
        return "", -1


def _load_table() -> Any:
    """The shipped table if it was written from the installed dialect, else ``None``."""
    from mav_observer.mavlink import _dialect_table as table

    return table if _fingerprint() == table.FINGERPRINT else None


_TABLE = _load_table()


def _mavlink() -> Any:
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


def wire_of(msgtype: Any) -> Wire:
    """The :data:`Wire` layout of one of the dialect's message classes."""
    return (
        msgtype.msgname,
        tuple(msgtype.fieldnames),
        msgtype.unpacker.format,
        tuple(msgtype.orders),
        tuple(msgtype.lengths),
        msgtype.crc_extra,
        "char" in msgtype.fieldtypes,
    )


if _TABLE is not None:
    #: Message id by name, and name by id, for the whole dialect.
    MSG_NAME: dict[int, str] = dict(_TABLE.MSG_NAME)
    _WIRE: dict[int, Wire] = _TABLE.WIRE
else:  # another pymavlink than the table's: from the dialect itself
    MSG_NAME = {i: c.msgname for i, c in _mavlink().mavlink_map.items()}
    _WIRE = {}
MSG_ID: dict[str, int] = {name: msgid for msgid, name in MSG_NAME.items()}


def wire(msgid: int) -> Wire | None:
    """The wire layout of message ``msgid`` (from the table when it has it, else from the
    dialect), ``None`` for an id the dialect does not define."""
    w = _WIRE.get(msgid)
    if w is None:
        msgtype = _mavlink().mavlink_map.get(msgid)
        if msgtype is None:
            return None
        w = wire_of(msgtype)
    return w


def type_key(msg: object) -> str:
    """The message's type for counters: its name, or ``UNKNOWN`` for every id the dialect does
    not define (pymavlink names them ``UNKNOWN_<id>``: one key per id would let garbage grow
    the counters without bound)."""
    name: str = msg.get_type()  # type: ignore[attr-defined]
    return "UNKNOWN" if name.startswith("UNKNOWN_") else name


def msg_name(msgid: int) -> str:
    """Name of a message id, ``UNKNOWN_<id>`` if the dialect does not define it."""
    return MSG_NAME.get(msgid, f"UNKNOWN_{msgid}")


def codec(src_system: int = 255, src_component: int = 190) -> mavlink.MAVLink:
    """A MAVLink 2 encoder/decoder with no transport (``pack``/``decode`` only)."""
    return _mavlink().MAVLink(None, srcSystem=src_system, srcComponent=src_component)


def __getattr__(name: str) -> Any:
    # imported when first asked for (see the module's docstring)
    if name == "mavlink":
        return _mavlink()
    if name == "mavutil":
        from pymavlink import mavutil

        return mavutil
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def connect(url: str, **kwargs: object) -> mavutil.mavfile:
    """``mavutil.mavlink_connection`` with the project's dialect.

    A ``udpout:`` connection to a loopback address is bound to 127.0.0.1 before its first
    send: left alone, the operating system binds it to every interface (0.0.0.0).
    """
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(url, dialect=DIALECT, **kwargs)
    if url.startswith("udpout:") and url.split(":")[1].startswith("127."):
        conn.port.bind(("127.0.0.1", 0))
    return conn


def table_source() -> str:
    """The text of :mod:`~mav_observer.mavlink._dialect_table` for the installed dialect."""
    mavlink_map = _mavlink().mavlink_map
    ids = {c.msgname: i for i, c in mavlink_map.items()}
    lines = [
        f'"""pymavlink\'s {DIALECT} dialect in short: do not edit, written by',
        "``python -m mav_observer.mavlink.dialect``.",
        "",
        "The dialect's message names by id (in the dialect's order), and the wire layout",
        "(:data:`~mav_observer.mavlink.dialect.Wire`) of the messages in",
        ":data:`~mav_observer.mavlink.dialect.TABLE_MESSAGES`, used while :data:`FINGERPRINT`",
        'is the installed pymavlink\'s."""',
        "",
        "# ruff: noqa: E501",
        "# fmt: off",
        f"FINGERPRINT = {_fingerprint()!r}",
        "MSG_NAME = {",
        *(f"    {i}: {c.msgname!r}," for i, c in mavlink_map.items()),
        "}",
        "WIRE = {",
        *(f"    {ids[n]}: {wire_of(mavlink_map[ids[n]])!r}," for n in TABLE_MESSAGES),
        "}",
        "",
    ]
    return "\n".join(lines)


__all__ = [
    "DIALECT", "MSG_ID", "MSG_NAME", "TABLE_MESSAGES", "Wire", "codec", "connect", "mavlink",
    "mavutil", "msg_name", "type_key", "wire", "wire_of",
]  # fmt: skip

if __name__ == "__main__":  # write the table for the installed pymavlink
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_dialect_table.py")
    with open(out, "w", encoding="utf-8") as fh:
        fh.write(table_source())
    sys.stdout.write(f"wrote {out}\n")
