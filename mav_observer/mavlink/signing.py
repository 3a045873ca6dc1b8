"""MAVLink 2 message signing: the key file, and telling rejected messages apart.

With a key configured the live reader (:class:`~mav_observer.mavlink.connection.ConnectionReader`)
asks pymavlink to check every incoming frame: a correctly signed one is used; an unsigned one
(any MAVLink 1 frame included) and a wrongly signed or replayed one (a timestamp not newer than
the last one of its stream) come out of pymavlink as ``BAD_DATA`` with the reason
``Invalid signature``, which :func:`rejection_reason` sorts into ``unsigned`` and
``bad_signature`` for the counters. Without a key nothing is checked and signed traffic is read
like any other. Our own HEARTBEATs are signed with the key.

The key file holds either the 32-byte secret key as 64 hexadecimal digits, or a passphrase
whose SHA-256 is the key (the convention of MAVProxy's ``signing setup`` and of QGroundControl).
A key is never accepted on the command line: it would show in the process list.
"""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path
from typing import Any

from mav_observer.errors import ConfigError

log = logging.getLogger(__name__)

KEY_BYTES = 32
#: The reason pymavlink gives a frame whose signature it refused (or that had none).
PYMAVLINK_REASON = "Invalid signature"
_MAVLINK2_MAGIC = 0xFD
_IFLAG_SIGNED = 0x01


def load_key(path: str | os.PathLike[str], *, setting: str = "mavlink.signing_key_file") -> bytes:
    """The 32-byte secret key from ``path``: 64 hex digits, or a passphrase hashed with
    SHA-256. Errors name ``setting`` and the file. A file others can read is logged."""
    p = Path(path)
    try:
        raw = p.read_bytes()
        mode = p.stat().st_mode
    except OSError as exc:
        raise ConfigError(f"{setting}: cannot read {str(p)!r}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise ConfigError(
            f"{setting}: {str(p)!r} is not text (64 hex digits or a passphrase)"
        ) from None
    if not text:
        raise ConfigError(f"{setting}: {str(p)!r} is empty")
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        log.warning(
            "%s: %s can be read by others (mode %o); chmod 600 it", setting, p, mode & 0o777
        )
    if len(text) == 2 * KEY_BYTES:
        try:
            return bytes.fromhex(text)
        except ValueError:
            pass  # 64 characters that are not all hex: a passphrase
    import hashlib  # (a key file's alone: not in a replay's start-up)

    return hashlib.sha256(text.encode("utf-8")).digest()


def rejection_reason(msg: Any) -> str | None:
    """``"unsigned"`` or ``"bad_signature"`` for a ``BAD_DATA`` that pymavlink produced
    because it refused a frame's signature; ``None`` for anything else."""
    if msg.get_type() != "BAD_DATA" or getattr(msg, "reason", None) != PYMAVLINK_REASON:
        return None
    data = bytes(getattr(msg, "data", b"") or b"")
    signed = len(data) > 2 and data[0] == _MAVLINK2_MAGIC and data[2] & _IFLAG_SIGNED
    return "bad_signature" if signed else "unsigned"


def setup(conn: Any, key: bytes, link_id: int = 0) -> None:
    """Enable signing on a pymavlink connection: check every incoming frame against ``key``,
    refuse unsigned ones, sign what we send on ``link_id``."""
    conn.setup_signing(
        key,
        sign_outgoing=True,
        allow_unsigned_callback=_refuse_unsigned,
        link_id=link_id,
    )


def _refuse_unsigned(_mav: Any, _msgid: int) -> bool:
    return False
