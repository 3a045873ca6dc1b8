"""Live MAVLink links on 127.0.0.1: emitter -> UDP or TCP -> reader -> tracker."""

import os
import socket
import threading
import time
import tty

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.errors import ConfigError
from mav_observer.mavlink.connection import (
    BAD_CRC_REASON,
    JUNK_REASON,
    TRUNCATED_REASON,
    ConnectionReader,
    datagram_frames,
    datagram_recv_msg,
    is_file_source,
    split_serial,
)
from mav_observer.mavlink.dialect import codec, mavlink
from mav_observer.mavlink.fastdecode import FastDecoder
from mav_observer.tracking.tracker import Tracker
from sim import fuzz, scenarios
from sim.emitter import Emitter, EmitterConfig, run
from sim.live import free_port


def track(reader: ConnectionReader, sender: threading.Thread) -> tuple[Tracker, int]:
    """Open the reader (listening) first, then start the sender; return tracker and estimates."""
    reader.open()
    sender.start()
    tracker = Tracker()
    n = 0
    try:
        for t, msg in reader:
            n += len(tracker.handle(t, msg))
        n += len(tracker.flush())  # the end of the stream: bearings waiting for an attitude
    finally:
        reader.close()
        sender.join(timeout=10)
    return tracker, n


def read_link(reader_url: str, emitter_url: str, duration_s: float = 30.0) -> Tracker:
    """The emitter sends ``duration_s`` of the orbit at 30 times real time."""
    em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=duration_s))
    reader = ConnectionReader(reader_url, duration_s=20.0, idle_timeout_s=2.0)
    th = threading.Thread(target=run, args=(em,), kwargs={"to": emitter_url, "speed": 30.0})
    tracker, n = track(reader, th)
    assert n > 200
    return tracker


@pytest.mark.slow
def test_udp_loopback() -> None:
    port = free_port(socket.SOCK_DGRAM)
    tr = read_link(f"udpin:127.0.0.1:{port}", f"udpout:127.0.0.1:{port}")
    assert tr.targets() == {(1, "gimbal"): "GIMBAL_DEVICE_ATTITUDE_STATUS"}
    assert "bad_data" not in tr.skipped


@pytest.mark.slow
def test_tcp_loopback() -> None:
    """The reader listens (tcpin), the emitter connects as a client (tcp)."""
    port = free_port(socket.SOCK_STREAM)
    tr = read_link(f"tcpin:127.0.0.1:{port}", f"tcp:127.0.0.1:{port}")
    assert tr.targets() == {(1, "gimbal"): "GIMBAL_DEVICE_ATTITUDE_STATUS"}


@pytest.mark.slow
def test_reader_as_udp_client() -> None:
    """udpout: the emitter is a UDP server (as an autopilot's udpin port is): it sends only once
    the reader's heartbeat has told it where we are."""
    port = free_port(socket.SOCK_DGRAM)
    # the first heartbeat may go out before the server is up; the next comes 1 s later
    tr = read_link(f"udpout:127.0.0.1:{port}", f"udpin:127.0.0.1:{port}", duration_s=90.0)
    assert tr.targets() == {(1, "gimbal"): "GIMBAL_DEVICE_ATTITUDE_STATUS"}


@pytest.mark.slow
def test_reader_as_tcp_client() -> None:
    """tcp: the emitter listens (tcpin, as SITL's port 5760 does), the reader connects."""
    port = free_port(socket.SOCK_STREAM)
    em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=30.0))
    th = threading.Thread(
        target=run, args=(em,), kwargs={"to": f"tcpin:127.0.0.1:{port}", "speed": 10.0}
    )  # 3 s: the 0.3 s before the reader connects cost 3 s of the 30 s scenario
    th.start()
    time.sleep(0.3)  # the server must listen before the client connects
    reader = ConnectionReader(f"tcp:127.0.0.1:{port}", duration_s=20.0, idle_timeout_s=2.0)
    tracker, n = track(reader, threading.Thread(target=lambda: None))
    th.join(timeout=10)
    assert n > 200
    assert tracker.targets() == {(1, "gimbal"): "GIMBAL_DEVICE_ATTITUDE_STATUS"}


@pytest.mark.slow
def test_heartbeat_only_where_needed() -> None:
    """Silent on every link but udpout; never from the ground station's system id 255."""
    assert ConnectionReader("udpout:127.0.0.1:14550").heartbeat_period_s == 1.0
    assert ConnectionReader("udpin:127.0.0.1:14550").heartbeat_period_s is None
    assert ConnectionReader("tcp:127.0.0.1:5760").heartbeat_period_s is None
    with pytest.raises(ConfigError, match="heartbeat_period_s"):
        ConnectionReader("udpout:127.0.0.1:14550", heartbeat_period_s=0.0)
    port = free_port(socket.SOCK_DGRAM)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as server:
        server.bind(("127.0.0.1", port))
        server.settimeout(3.0)
        reader = ConnectionReader(f"udpout:127.0.0.1:{port}", duration_s=1.5)
        for _ in reader:
            pass
        data, _ = server.recvfrom(512)
    msg = mavlink.MAVLink(None).decode(bytearray(data))
    assert msg.get_type() == "HEARTBEAT"
    assert (msg.get_srcSystem(), msg.get_srcComponent()) == (254, 191)
    assert msg.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    assert reader.heartbeats_sent == 2


@pytest.mark.slow
def test_serial_device_with_baud() -> None:
    """A serial link (a pseudo-terminal pair standing in for the port): DEVICE,BAUD."""
    master, slave = os.openpty()
    tty.setraw(slave)
    device = os.ttyname(slave)
    em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=20.0))
    frames = [e.frame for e in em.emissions()]
    reader = ConnectionReader(f"{device},115200", duration_s=15.0, idle_timeout_s=1.5)

    def write_all() -> None:
        for i in range(0, len(frames), 50):
            os.write(master, b"".join(frames[i : i + 50]))
            time.sleep(0.002)

    try:
        tracker, n = track(reader, threading.Thread(target=write_all))
    finally:
        os.close(master)
        os.close(slave)
    assert n > 150
    assert tracker.targets() == {(1, "gimbal"): "GIMBAL_DEVICE_ATTITUDE_STATUS"}


def test_source_strings() -> None:
    assert split_serial("/dev/ttyACM0,115200") == ("/dev/ttyACM0", {"baud": 115200})
    assert split_serial("udpin:127.0.0.1:14550") == ("udpin:127.0.0.1:14550", {})
    assert not is_file_source("udpin:127.0.0.1:14550")
    assert not is_file_source("/dev/ttyACM0")


@pytest.mark.slow
def test_a_udp_link_reports_what_the_kernel_dropped() -> None:
    """Datagrams sent faster than anyone reads them overflow the socket: the reader says so."""
    port = free_port(socket.SOCK_DGRAM)
    reader = ConnectionReader(f"udpin:127.0.0.1:{port}", heartbeat_period_s=None)
    reader.open()
    try:
        assert reader.kernel_drops() == 0
        frame = bytes(mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(
            mavlink.MAVLink(None, 1, 1)))  # fmt: skip
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(200_000):  # about 4 MB of small datagrams, more than the buffer
                s.sendto(frame, ("127.0.0.1", port))
        drops = reader.kernel_drops()
        assert drops is not None and drops > 0
    finally:
        reader.close()
    tcp = ConnectionReader("tcp:127.0.0.1:1")
    assert tcp.kernel_drops() is None


@pytest.mark.slow
def test_a_serial_port_that_is_missing_is_retried_until_it_appears(tmp_path) -> None:
    """The device is absent at start (unplugged): the reader counts the failure, backs off and
    reads once the device is there."""
    master, slave = os.openpty()
    tty.setraw(slave)
    link = tmp_path / "ttyFC"
    frame = bytes(
        mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(mavlink.MAVLink(None, 1, 1))
    )
    reader = ConnectionReader(f"{link},57600", heartbeat_period_s=None)
    got = None
    try:
        t0 = time.monotonic()
        assert reader.recv(0.1) is None and reader.link_errors == 1  # no device yet
        link.symlink_to(os.ttyname(slave))
        while got is None and time.monotonic() - t0 < 10.0:
            os.write(master, frame)
            got = reader.recv(0.1)
        took = time.monotonic() - t0
    finally:
        reader.close()
        os.close(master)
        os.close(slave)
    assert got is not None and got[1].get_type() == "HEARTBEAT"
    assert reader.link_errors == 1
    assert 0.4 <= took < 3.0  # the first back-off is 0.5 s


def test_a_malformed_address_is_a_config_error_not_a_retry() -> None:
    reader = ConnectionReader("udpin:127.0.0.1:99999")
    with pytest.raises(ConfigError, match=r"udpin:127\.0\.0\.1:99999"):
        reader.recv(0.1)
    reader.close()


class _FakeUdp:
    """Just what :func:`datagram_recv_msg` uses of a pymavlink UDP link: datagrams in a queue."""

    def __init__(self, datagrams: list[bytes]) -> None:
        self.mav = codec()
        self.mav.robust_parsing = True
        self.first_byte = False
        self._queue = list(datagrams)

    def pre_message(self) -> None:
        pass

    def post_message(self, _msg: object) -> None:
        pass

    def recv(self) -> bytes:
        return self._queue.pop(0) if self._queue else b""


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(junk=st.lists(st.binary(min_size=0, max_size=300), max_size=5))
def test_a_damaged_datagram_never_costs_the_next_one(junk: list[bytes]) -> None:
    """Whatever bytes came before (any number of datagrams of anything), a datagram holding a
    good frame is decoded: a datagram's tail never swallows the next one."""
    good = codec(1, 1).heartbeat_encode(2, 3, 0, 0, 4).pack(codec(1, 1))
    link = _FakeUdp([*junk, bytes(good)])
    msgs = []
    for _ in range(10_000):
        msg = datagram_recv_msg(link)
        if msg is None and not link._queue and link.mav.buf_len() == 0:
            break
        if msg is not None:
            msgs.append(msg)
    assert [m.get_type() for m in msgs if m.get_type() != "BAD_DATA"][-1:] == ["HEARTBEAT"]


def test_unknown_message_ids_do_not_pile_up_in_pymavlink() -> None:
    """pymavlink keeps the last message of every type it has seen, and names each unknown id
    a type of its own: 3,000 garbage frames of random unknown ids must not leave 3,000
    entries behind (the soak's memory grew with them)."""
    port = free_port(socket.SOCK_DGRAM)
    reader = ConnectionReader(f"udpin:127.0.0.1:{port}", heartbeat_period_s=None)
    reader.open()
    rng = np.random.default_rng(0)
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for _ in range(3000):
                s.sendto(fuzz.unknown_msgid_frame(rng, 1), ("127.0.0.1", port))
        got = 0
        while reader.recv(0.2) is not None:
            got += 1
        assert got == 3000 and reader.counts == {"UNKNOWN": 3000}
        conn = reader._conn
        assert len(conn.messages) < 10
        assert all(len(st.messages) < 10 for st in conn.sysid_state.values())
    finally:
        reader.close()


def test_a_datagram_splits_into_its_frames_decoded_as_pymavlink_decodes_them() -> None:
    """Two good frames, junk, a frame with a bad CRC, one cut short: the good ones decoded
    field for field as pymavlink decodes them, each bad part one BAD_DATA naming why."""
    c = codec(7, 1)
    att = bytes(c.attitude_encode(1000, 0.1, -0.2, 0.3, 0.01, 0.02, 0.03).pack(c))
    txt = bytes(c.statustext_encode(6, b"hello").pack(c))
    bad = bytearray(att)
    bad[-1] ^= 0xFF
    data = att + txt + b"\x00\x01\x02" + bytes(bad) + att[:9]
    msgs = datagram_frames(data, FastDecoder().decode)
    assert [m.get_type() for m in msgs] == [
        "ATTITUDE", "STATUSTEXT", "BAD_DATA", "BAD_DATA", "BAD_DATA",
    ]  # fmt: skip
    assert [getattr(m, "reason", None) for m in msgs[2:]] == [
        JUNK_REASON, BAD_CRC_REASON, TRUNCATED_REASON,
    ]  # fmt: skip
    ref = codec().decode(bytearray(att))
    got = msgs[0]
    assert got.get_srcSystem() == 7 and got.get_srcComponent() == 1
    assert all(getattr(got, k) == getattr(ref, k) for k in ref.get_fieldnames())
    assert msgs[1].text == "hello"


def test_a_udp_input_decodes_what_pymavlink_decodes_and_replies_to_its_peer() -> None:
    """The datagram path of a ``udpin`` link: every message of an emitter's stream arrives
    with pymavlink's field values, and what the reader sends goes to the peer it heard."""
    port = free_port(socket.SOCK_DGRAM)
    reader = ConnectionReader(f"udpin:127.0.0.1:{port}", heartbeat_period_s=None)
    reader.open()
    em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=3.0))
    frames = [e.frame for e in em.emissions()]
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            s.settimeout(2.0)
            got = []
            for f in frames:
                s.sendto(f, ("127.0.0.1", port))
                item = reader.recv(1.0)
                assert item is not None
                got.append(item[1])
            ref = codec()
            for f, msg in zip(frames, got, strict=True):
                want = ref.decode(bytearray(f))
                assert msg.get_type() == want.get_type()
                for k in want.get_fieldnames():  # NaN (an unknown rate) equal to NaN
                    assert repr(getattr(msg, k)) == repr(getattr(want, k)), k
            c = codec(254, 191)
            assert reader.send(c.heartbeat_encode(18, 8, 0, 0, 4))
            back = codec().decode(bytearray(s.recv(300)))
            assert back.get_type() == "HEARTBEAT" and back.get_srcSystem() == 254
    finally:
        reader.close()
    assert sum(reader.counts.values()) == len(frames) and "BAD_DATA" not in reader.counts
