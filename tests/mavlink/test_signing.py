"""MAVLink 2 signing (mav_observer/mavlink/signing.py) on loopback with pymavlink's signing."""

from __future__ import annotations

import hashlib
import socket
import time
from pathlib import Path

import pytest

from mav_observer.errors import ConfigError
from mav_observer.mavlink import signing
from mav_observer.mavlink.connection import ConnectionReader
from mav_observer.mavlink.dialect import connect
from mav_observer.tracking.tracker import Tracker
from sim.live import free_port

KEY = bytes(range(32))
WRONG = bytes(range(1, 33))
PER_SENDER = 20


def _key_file(tmp_path: Path, text: str, name: str = "key") -> Path:
    p = tmp_path / name
    p.write_text(text)
    p.chmod(0o600)
    return p


def test_key_file_holds_hex_or_a_passphrase(tmp_path: Path) -> None:
    assert signing.load_key(_key_file(tmp_path, KEY.hex() + "\n")) == KEY
    phrase = "correct horse battery staple"
    assert signing.load_key(_key_file(tmp_path, phrase)) == hashlib.sha256(phrase.encode()).digest()


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (None, "mavlink.signing_key_file: cannot read '.*missing'"),
        ("", "mavlink.signing_key_file: '.*' is empty"),
        (b"\xff\xfe\x00key", "is not text"),
    ],
)
def test_a_bad_key_file_names_the_setting(tmp_path: Path, content: object, match: str) -> None:
    p = tmp_path / "missing"
    if isinstance(content, bytes):
        p.write_bytes(content)
    elif isinstance(content, str):
        p.write_text(content)
    with pytest.raises(ConfigError, match=match):
        signing.load_key(p)


def test_a_key_of_the_wrong_length_is_refused() -> None:
    with pytest.raises(ConfigError, match="signing_key must be 32 bytes, got 3"):
        ConnectionReader("udpin:127.0.0.1:14999", signing_key=b"abc")


def _sender(port: int, sysid: int, key: bytes | None):
    conn = connect(f"udpout:127.0.0.1:{port}", source_system=sysid, source_component=1)
    if key is not None:
        conn.setup_signing(key, sign_outgoing=True, link_id=sysid)
    return conn


def _send_attitudes(conn, n: int) -> list[bytes]:
    frames = []
    for i in range(n):
        msg = conn.mav.attitude_encode(i * 10, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
        conn.mav.send(msg)
        frames.append(bytes(msg.get_msgbuf()))
    return frames


def _read_all(reader: ConnectionReader, expected: int, timeout_s: float = 5.0) -> list:
    got = []
    deadline = time.monotonic() + timeout_s
    while len(got) < expected and time.monotonic() < deadline:
        item = reader.recv(0.05)
        if item is not None:
            got.append(item)
    return got


def test_with_a_key_only_correctly_signed_messages_are_used() -> None:
    """Three senders: sysid 1 signs with the key, 2 with another key, 3 does not sign; then
    a correctly signed frame of sysid 1 is replayed. The tracker uses sysid 1's 20 messages
    and counts 20 unsigned and 21 badly signed (the replay included)."""
    port = free_port(socket.SOCK_DGRAM)
    reader = ConnectionReader(f"udpin:127.0.0.1:{port}", signing_key=KEY, heartbeat_period_s=None)
    reader.open()
    senders = [_sender(port, 1, KEY), _sender(port, 2, WRONG), _sender(port, 3, None)]
    try:
        frames = [_send_attitudes(s, PER_SENDER) for s in senders]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:
            raw.sendto(frames[0][5], ("127.0.0.1", port))  # a replay: its timestamp is old
        got = _read_all(reader, 3 * PER_SENDER + 1)
    finally:
        for s in senders:
            s.close()
        reader.close()
    tracker = Tracker()
    for t, msg in got:
        tracker.handle(t, msg)
    good = [m for _, m in got if m.get_type() == "ATTITUDE"]
    assert len(got) == 3 * PER_SENDER + 1
    assert {m.get_srcSystem() for m in good} == {1} and len(good) == PER_SENDER
    assert tracker.skipped["unsigned"] == PER_SENDER
    assert tracker.skipped["bad_signature"] == PER_SENDER + 1


def test_without_a_key_signed_traffic_is_read() -> None:
    port = free_port(socket.SOCK_DGRAM)
    reader = ConnectionReader(f"udpin:127.0.0.1:{port}", heartbeat_period_s=None)
    reader.open()
    senders = [_sender(port, 1, KEY), _sender(port, 3, None)]
    try:
        for s in senders:
            _send_attitudes(s, PER_SENDER)
        got = _read_all(reader, 2 * PER_SENDER)
    finally:
        for s in senders:
            s.close()
        reader.close()
    assert [m.get_type() for _, m in got] == ["ATTITUDE"] * (2 * PER_SENDER)


def test_our_heartbeats_are_signed_with_the_key() -> None:
    """A peer holding the key accepts the service's HEARTBEAT; one without signing support
    would see an unsigned-looking frame refused by a signing autopilot."""
    port = free_port(socket.SOCK_DGRAM)
    peer = connect(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    peer.setup_signing(KEY, sign_outgoing=False, allow_unsigned_callback=lambda *_: False)
    reader = ConnectionReader(
        f"udpout:127.0.0.1:{port}", signing_key=KEY, signing_link_id=7, heartbeat_period_s=0.05
    )
    try:
        deadline = time.monotonic() + 5.0
        hb = None
        while hb is None and time.monotonic() < deadline:
            reader.recv(0.05)
            hb = peer.recv_match(type="HEARTBEAT", blocking=True, timeout=0.05)
    finally:
        reader.close()
        peer.close()
    assert hb is not None
    buf = bytes(hb.get_msgbuf())
    assert buf[2] & 0x01 and buf[-13] == 7  # signed, on our link id
