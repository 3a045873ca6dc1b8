"""Reading MAVLink from any pymavlink connection string (live links, serial ports).

Accepted: everything ``mavutil.mavlink_connection`` takes (``udpin:127.0.0.1:14550``,
``udpout:HOST:PORT``, ``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, a serial device), plus
``DEVICE,BAUD`` for a serial device at a given baud rate (``/dev/ttyACM0,115200``). A path to an
existing file is a tlog and goes through :class:`~mav_observer.mavlink.tlog.TlogReader`
instead (see :func:`is_file_source`).

On a UDP input (``udpin:``, ``udp:``) without a signing key, each datagram is split into its
frames and decoded by :class:`~mav_observer.mavlink.fastdecode.FastDecoder` (the CRC checked,
the fields unpacked straight from pymavlink's metadata, without the cost of pymavlink's parser
and bookkeeping); anything else, and every signed link (signatures are checked by pymavlink),
goes through pymavlink.

The reader only listens, with one exception: on a ``udpout:`` link it sends a HEARTBEAT once a
second, because a UDP server (an autopilot's ``udpin`` port, mavlink-router, BlueOS) only
sends to peers it has heard from. The heartbeat comes from system 254, component 191
(MAV_COMP_ID_ONBOARD_COMPUTER), type MAV_TYPE_ONBOARD_CONTROLLER, never from 255: ArduPilot
treats any heartbeat from its ground station id (MAV_GCS_SYSID / SYSID_MYGCS, 255 by default)
as its ground station being alive, which would arm the GCS failsafe when we stop.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import select
import socket
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from typing import Any

from mav_observer.errors import ConfigError
from mav_observer.mavlink import signing
from mav_observer.mavlink.dialect import connect, mavlink, type_key
from mav_observer.mavlink.fastdecode import DecodeError, FastDecoder
from mav_observer.mavlink.sources import URL_PREFIXES, is_file_source  # noqa: F401 (its home)

log = logging.getLogger(__name__)

SOURCE_SYSTEM = 254
SOURCE_COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
AUTO = "auto"


def default_heartbeat_period_s(source: str) -> float | None:
    """1 s on ``udpout:`` links (the peer must hear from us first), otherwise ``None`` (silent)."""
    return 1.0 if source.startswith("udpout:") else None


def split_serial(source: str) -> tuple[str, dict[str, Any]]:
    """``"/dev/ttyUSB0,57600"`` -> ``("/dev/ttyUSB0", {"baud": 57600})``; other strings as is."""
    if "," in source and not source.startswith(URL_PREFIXES):
        dev, baud = source.rsplit(",", 1)
        if baud.isdigit():
            return dev, {"baud": int(baud)}
    return source, {}


#: Receive buffer asked for on UDP links (the kernel caps it at net.core.rmem_max): a burst or
#: a pause of the reader of a few tens of ms must not overflow the default ~200 KB.
UDP_RCVBUF_BYTES = 4 * 1024 * 1024


def udp_socket_stats(port: int, host: str = "127.0.0.1") -> tuple[int, int] | None:
    """``(bytes waiting, datagrams dropped)`` of the IPv4 UDP socket bound to ``host:port``,
    from Linux's ``/proc/net/udp``; ``None`` if there is no such socket or no such file. The
    drop count is the kernel's: datagrams lost because the reader did not keep up."""
    a, b, c, d = (int(x) for x in host.split("."))
    local = f"{d:02X}{c:02X}{b:02X}{a:02X}:{port:04X}"
    try:
        with open("/proc/net/udp", encoding="ascii") as fh:
            next(fh)
            for line in fh:
                f = line.split()
                if len(f) > 12 and f[1] == local:
                    return int(f[4].split(":")[1], 16), int(f[12])
    except (OSError, StopIteration, ValueError):
        return None
    return None


def _reset_parser(mav: Any) -> None:
    """Forget a pymavlink parser's partial frame (its documented initial state)."""
    mav.buf = bytearray()
    mav.buf_index = 0
    mav.expected_length = mavlink.HEADER_LEN_V1 + 2
    mav.have_prefix_error = False


def datagram_recv_msg(conn: Any) -> Any:
    """``recv_msg`` of a pymavlink UDP link that respects datagram boundaries.

    pymavlink parses a UDP link as one byte stream: the tail of a damaged datagram (a frame
    cut short, a length byte that lies) stays in its buffer and swallows the start of the next
    datagram, which may be a good frame from another sender (``docs/reliability.md``, "Fuzzed
    frames"). Here the rest of a datagram that is not a whole frame is returned as one
    ``BAD_DATA`` ("truncated frame at the end of a datagram") and the parser starts the next
    datagram afresh; the messages of one datagram still come one per call."""
    mav = conn.mav
    conn.pre_message()
    msg = _next_or_tail(mav, b"") if mav.buf_len() > 0 else None
    if msg is None:
        data = conn.recv()
        if not data:
            return None
        if conn.first_byte:
            conn.auto_mavlink_version(data)
        msg = _next_or_tail(mav, data)
    if msg is not None:
        conn.post_message(msg)
    return msg


#: pymavlink's reasons for what :func:`datagram_frames` reports as BAD_DATA
BAD_CRC_REASON = "invalid MAVLink CRC"
TRUNCATED_REASON = "truncated frame at the end of a datagram"
JUNK_REASON = "bytes before a MAVLink frame"
_MAGIC = (0xFD, 0xFE)


def datagram_frames(data: bytes, decode: Callable[[bytes], Any]) -> list[Any]:
    """The messages of one UDP datagram, in order: each frame decoded by ``decode`` (a
    :class:`~mav_observer.mavlink.fastdecode.FastDecoder`'s), a frame that does not decode
    (bad CRC, bad length), bytes before a frame and a frame the datagram cuts short each as one
    ``BAD_DATA`` (as :func:`datagram_recv_msg` reports them)."""
    out: list[Any] = []
    i, n = 0, len(data)
    while i < n:
        magic = data[i]
        if magic not in _MAGIC:
            j = min((k for k in (data.find(b"\xfd", i), data.find(b"\xfe", i)) if k >= 0),
                    default=n)  # fmt: skip
            out.append(mavlink.MAVLink_bad_data(bytearray(data[i:j]), JUNK_REASON))
            i = j
            continue
        if i + 3 > n:
            flen = n + 1  # not even a length: cut short
        elif magic == 0xFD:
            flen = 12 + data[i + 1] + (13 if data[i + 2] & 1 else 0)
        else:
            flen = 8 + data[i + 1]
        end = i + flen
        if end > n:
            out.append(mavlink.MAVLink_bad_data(bytearray(data[i:]), TRUNCATED_REASON))
            break
        frame = data[i:end]
        try:
            out.append(decode(frame))
        except DecodeError as exc:
            why = BAD_CRC_REASON if exc.reason == "bad_crc" else str(exc)
            out.append(mavlink.MAVLink_bad_data(bytearray(frame), why))
        i = end
    return out


def _next_or_tail(mav: Any, data: bytes) -> Any:
    """The next message of the current datagram (``data`` added), or, when what is left is
    not a whole frame, that rest as one BAD_DATA with the parser reset."""
    msg = mav.parse_char(data)
    if msg is None and mav.buf_len() > 0:
        rest = bytes(mav.buf[mav.buf_index :])
        _reset_parser(mav)
        msg = mavlink.MAVLink_bad_data(rest, "truncated frame at the end of a datagram")
    return msg


class ConnectionReader:
    """Iterate ``(t_arrival_s, message)`` from a live connection.

    Stops after ``duration_s`` (wall seconds, if given) or after ``idle_timeout_s`` without any
    message (if given); otherwise runs until :meth:`close`. A link that fails (a TCP peer gone,
    a serial port unplugged) is counted in :attr:`link_errors` and reopened after a back-off
    (0.5 s doubling to 8 s). ``clock`` is the arrival clock (Unix seconds), injected for tests.
    BAD_DATA from pymavlink (bad CRC, junk) is yielded like any message so it can be counted.
    ``signing_key`` (32 bytes): MAVLink 2 signing (:mod:`~mav_observer.mavlink.signing`):
    frames without a valid signature come out as BAD_DATA, our HEARTBEATs are signed with
    ``signing_link_id``.
    ``heartbeat_period_s``: send a HEARTBEAT this often (seconds), ``None`` never; ``"auto"``
    follows :func:`default_heartbeat_period_s`.
    """

    def __init__(
        self,
        source: str,
        *,
        duration_s: float | None = None,
        idle_timeout_s: float | None = None,
        clock: Callable[[], float] = time.time,
        poll_s: float = 0.1,
        heartbeat_period_s: float | str | None = AUTO,
        signing_key: bytes | None = None,
        signing_link_id: int = 0,
    ) -> None:
        self.source = source
        if signing_key is not None and len(signing_key) != signing.KEY_BYTES:
            raise ConfigError(
                f"signing_key must be {signing.KEY_BYTES} bytes, got {len(signing_key)}"
            )
        self.signing_key = signing_key
        self.signing_link_id = signing_link_id
        self.duration_s = duration_s
        self.idle_timeout_s = idle_timeout_s
        self.clock = clock
        self.poll_s = poll_s
        if heartbeat_period_s == AUTO:
            heartbeat_period_s = default_heartbeat_period_s(source)
        if heartbeat_period_s is not None and (
            isinstance(heartbeat_period_s, str) or not heartbeat_period_s > 0
        ):
            raise ConfigError(
                f"heartbeat_period_s must be a positive number of seconds, None or 'auto', "
                f"got {heartbeat_period_s!r}"
            )
        self.heartbeat_period_s: float | None = heartbeat_period_s
        self.heartbeats_sent = 0
        self._next_heartbeat = 0.0
        self.counts: Counter[str] = Counter()
        self.link_errors = 0
        self._conn: Any = None
        #: the datagram path (see the module docstring): its decoder, and the messages of
        #: the latest datagram not returned yet
        self._fast: FastDecoder | None = None
        self._pending: deque[Any] = deque()
        self._closed = False
        self._retry_at = 0.0
        self._backoff = 0.5

    def open(self) -> None:
        dev, kwargs = split_serial(self.source)
        try:
            self._conn = connect(
                dev,
                source_system=SOURCE_SYSTEM,
                source_component=SOURCE_COMPONENT,
                autoreconnect=True,
                **kwargs,
            )
        except (ValueError, OverflowError) as exc:  # a malformed address: no retry helps
            raise ConfigError(f"MAVLink source {self.source!r}: {exc}") from None
        if self.signing_key is not None:
            signing.setup(self._conn, self.signing_key, self.signing_link_id)
        self._next_heartbeat = 0.0
        sock = self._udp_socket()
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF_BYTES)
            # one datagram never continues in the next: parse each on its own
            self._conn.recv_msg = functools.partial(datagram_recv_msg, self._conn)
        # the datagram path: an unsigned UDP input (pymavlink checks signatures)
        server = getattr(self._conn, "udp_server", False)
        fast = sock is not None and server and self.signing_key is None
        self._fast = (self._fast or FastDecoder()) if fast else None
        self._pending.clear()

    def _udp_socket(self) -> socket.socket | None:
        """The socket of an open UDP link (pymavlink keeps it as ``port``), else ``None``."""
        sock = getattr(self._conn, "port", None)
        if self.source.startswith("udp") and isinstance(sock, socket.socket):
            return sock
        return None

    def kernel_drops(self) -> int | None:
        """Datagrams the kernel dropped on this UDP link's socket because we did not read
        them in time (Linux, IPv4); ``None`` when unknown (not UDP, not open, not Linux)."""
        sock = self._udp_socket()
        if sock is None:
            return None
        try:
            host, port = sock.getsockname()[:2]
        except (OSError, ValueError):
            return None
        stats = udp_socket_stats(port, host)
        return None if stats is None else stats[1]

    def _heartbeat(self, now: float) -> None:
        """Send a HEARTBEAT when one is due (``now``: monotonic seconds)."""
        if self.heartbeat_period_s is None or now < self._next_heartbeat:
            return
        self._next_heartbeat = now + self.heartbeat_period_s
        mav = self._conn.mav
        mav.heartbeat_send(
            mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
            mavlink.MAV_AUTOPILOT_INVALID,
            0,
            0,
            mavlink.MAV_STATE_ACTIVE,
        )
        self.heartbeats_sent += 1

    def send(self, msg: Any) -> bool:
        """Send the pymavlink message ``msg`` from our system and component (signed when a
        key is set), opening the link if it is not open; ``False`` (counted in
        :attr:`link_errors`, never raised) when it cannot be sent now. A ``udpin`` link sends
        to the peer it last heard from (nothing before it has heard one)."""
        if self._closed:
            return False
        if self._conn is None:
            if time.monotonic() < self._retry_at:
                return False
            try:
                self.open()
            except OSError as exc:
                self._drop_link(exc)
                return False
        try:
            self._conn.mav.send(msg)
        except OSError as exc:
            self._drop_link(exc)
            return False
        return True

    def close(self) -> None:
        self._closed = True
        self._close_link()

    def _close_link(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(AttributeError, OSError):  # a TCP link mid-reconnect
                conn.close()

    def _drop_link(self, exc: OSError) -> None:
        """Count and log a failure, close the link, and schedule the next try (back-off
        0.5 s doubling to 8 s; reset by the next message)."""
        self.link_errors += 1
        if self.link_errors == 1 or self.link_errors % 100 == 0:
            log.warning(
                "MAVLink link %s failed (%d so far): %s", self.source, self.link_errors, exc
            )
        self._close_link()
        self._retry_at = time.monotonic() + self._backoff
        self._backoff = min(8.0, 2 * self._backoff)

    @property
    def connected(self) -> bool:
        """True while the link is open (a UDP input is open even when nothing arrives)."""
        return self._conn is not None

    def recv(self, timeout_s: float | None = None) -> tuple[float, Any] | None:
        """The next message as ``(t_arrival_s, message)``, or ``None`` if none came within
        ``timeout_s`` (default :attr:`poll_s`). Opens the link, and reopens it after a
        failure with a back-off (0.5 s doubling to 8 s); sends the heartbeat when due. Link
        failures are counted in :attr:`link_errors`, never raised."""
        if self._closed:
            return None
        timeout = self.poll_s if timeout_s is None else timeout_s
        now = time.monotonic()
        if self._conn is None:
            if now < self._retry_at:
                time.sleep(max(0.0, min(timeout, self._retry_at - now)))
                return None
            try:
                self.open()
            except OSError as exc:
                self._drop_link(exc)
                return None
        try:
            self._heartbeat(now)
            if self._fast is not None:
                msg = self._recv_datagram(timeout)
            else:
                msg = self._conn.recv_match(blocking=True, timeout=timeout)
        except OSError as exc:
            self._drop_link(exc)
            return None
        if msg is None:
            return None
        self._backoff = 0.5
        key = type_key(msg)
        if key == "UNKNOWN":  # pymavlink keeps the last message of each type: not of these
            self._forget(msg)
        self.counts[key] += 1
        return self.clock(), msg

    def _recv_datagram(self, timeout_s: float) -> Any:
        """The next message of a UDP input link (the datagram path): the latest datagram's
        next one, else the first of a datagram arriving within ``timeout_s``, else ``None``.
        The sender is remembered as pymavlink remembers it (a ``udpin`` link sends to the
        peers it has heard from)."""
        pending = self._pending
        if pending:
            return pending.popleft()
        conn = self._conn
        sock = conn.port  # (non-blocking: read first, wait only when nothing is queued)
        try:
            data, addr = sock.recvfrom(65535)
        except (BlockingIOError, InterruptedError, ConnectionRefusedError):
            if not select.select([sock], [], [], timeout_s)[0]:
                return None
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                return None
        conn.clients.add(addr)
        conn.clients_last_alive[addr] = time.time()
        if conn.first_byte:  # our own frames' version follows the peer's, as pymavlink's
            conn.auto_mavlink_version(data)
        pending.extend(datagram_frames(data, self._fast.decode))  # type: ignore[union-attr]
        return pending.popleft() if pending else None

    def _forget(self, msg: Any) -> None:
        """Drop a message from pymavlink's last-message-per-type tables (the link's and its
        sender's), where each unknown message id would otherwise stay as a type of its own."""
        name = msg.get_type()
        self._conn.messages.pop(name, None)
        state = self._conn.sysid_state.get(msg.get_srcSystem())
        if state is not None:
            state.messages.pop(name, None)

    def __iter__(self) -> Iterator[tuple[float, Any]]:
        start = time.monotonic()
        last_msg = start
        try:
            while not self._closed:
                now = time.monotonic()
                if self.duration_s is not None and now - start >= self.duration_s:
                    return
                if self.idle_timeout_s is not None and now - last_msg >= self.idle_timeout_s:
                    return
                item = self.recv()
                if item is None:
                    continue
                last_msg = time.monotonic()
                yield item
        finally:
            self.close()
