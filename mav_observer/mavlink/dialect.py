"""The one place that chooses the MAVLink dialect: MAVLink 2, ``ardupilotmega`` (which includes
``common``). MAVLink 1 frames still decode with it.

pymavlink picks its protocol version from the ``MAVLINK20`` environment variable when
``mavutil`` is first imported, so this module sets it before importing anything from
pymavlink. Import pymavlink through here, never directly.

``mavutil`` (the links) is imported when first used (:func:`connect`, or ``dialect.mavutil``):
it brings every MAVLink 1 and 2 dialect with it, a third of a replay's start-up, and reading
a log needs none of it.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"

from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

if TYPE_CHECKING:
    from pymavlink import mavutil

DIALECT = "ardupilotmega"

#: Message id by name, and name by id, for the whole dialect.
MSG_ID: dict[str, int] = {
    cls.msgname: msgid
    for msgid, cls in mavlink.mavlink_map.items()  # type: ignore[attr-defined]
}
MSG_NAME: dict[int, str] = {v: k for k, v in MSG_ID.items()}


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
    return mavlink.MAVLink(None, srcSystem=src_system, srcComponent=src_component)


def __getattr__(name: str) -> Any:
    if name == "mavutil":  # imported when first asked for (see the module's docstring)
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


__all__ = ["DIALECT", "MSG_ID", "MSG_NAME", "codec", "connect", "mavlink", "mavutil", "msg_name"]
