"""The estimate sent back over MAVLink (mav_observer/outputs/mavlink_out.py)."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest

from mav_observer.core.samples import Estimate, Status
from mav_observer.geo.frames import euler_to_dcm
from mav_observer.geo.geodesy import Origin
from mav_observer.mavlink.connection import ConnectionReader
from mav_observer.mavlink.dialect import connect
from mav_observer.outputs.mavlink_out import (
    MavlinkOut,
    OutConfig,
    body_angles,
    landing_target,
    statustext,
)
from mav_observer.outputs.records import EstimateRecord
from mav_observer.tracking import directions as adapters
from sim.live import free_port

ORIGIN = Origin(-35.363261, 149.16523, 584.0, "GPS_GLOBAL_ORIGIN")
KEY = bytes(range(32))


def _rec(status: Status = Status.CONVERGED, x=(10.0, 5.0, 12.0), sd=0.4, t=100.0, origin=ORIGIN):
    est = Estimate(t, np.array(x), np.zeros(3), float(np.linalg.norm(x)), 0.3, 2.0, status,
                   True, 0.0, 0.0, 0.0, x_std_m=np.array([sd, sd, sd]))  # fmt: skip
    return EstimateRecord(1.7e9 + t, t, 1, "gimbal", "G", est, (30.0, 25.0, -12.0), origin)


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (0.1, -0.2, 2.0), (-0.3, 0.25, -1.0)])
def test_the_angles_are_what_the_landing_target_reader_turns_back_into_the_line_of_sight(rpy):
    rel = (3.0, -2.0, 9.0)
    ax, ay = body_angles(rel, rpy)
    r = euler_to_dcm(*rpy)
    los_ned = adapters.landing_target_direction(
        frame=12, angle_x=ax, angle_y=ay, position_valid=0, x=0.0, y=0.0, z=0.0,
        vehicle_dcm=r, vehicle_yaw=rpy[2],
    )  # fmt: skip
    cos = np.dot(los_ned, rel) / (np.linalg.norm(los_ned) * np.linalg.norm(rel))
    assert cos == pytest.approx(1.0, abs=1e-12)
    assert body_angles((3.0, -2.0, -9.0), (0.0, 0.0, 0.0)) == (0.0, 0.0)  # above: no angles
    assert body_angles(rel, None) == (0.0, 0.0)


def test_landing_target_is_the_position_form_and_statustext_the_map_position() -> None:
    r = _rec()
    m = landing_target(r, 2, (0.0, 0.0, 0.0))
    assert (m.frame, m.position_valid, m.target_num, m.time_usec) == (1, 1, 2, 100_000_000)
    assert (m.x, m.y, m.z) == pytest.approx((40.0, 30.0, 0.0))
    assert m.distance == pytest.approx(math.sqrt(100 + 25 + 144), rel=1e-6)
    text = statustext(r)
    assert text is not None and len(text) <= 50
    assert text.startswith("gimbal: -35.36") and text.endswith("m +-0.6m")
    assert statustext(_rec(origin=None)) is None


def test_sent_only_when_converged_at_the_rate_and_the_text_on_converging_and_moving() -> None:
    sent = []
    out = MavlinkOut(OutConfig(enabled=True, rate_hz=2.0), lambda m: sent.append(m) or True)
    out.on_estimate(_rec(Status.CONVERGING), None, 0.0)
    assert sent == []
    for k in range(10):  # 1 s of estimates at 10 Hz: 2 LANDING_TARGET, one text
        out.on_estimate(_rec(t=100.0 + 0.1 * k), None, 0.1 + 0.1 * k)
    assert out.sent == {"LANDING_TARGET": 2, "STATUSTEXT": 1}
    out.on_estimate(_rec(x=(10.2, 5.0, 12.0)), None, 1.15)  # moved 0.2 m, 1-sigma 0.57 m
    assert out.sent["STATUSTEXT"] == 1
    out.on_estimate(_rec(x=(11.0, 5.0, 12.0)), None, 1.2)  # moved 1 m: a new text
    assert out.sent["STATUSTEXT"] == 2
    other = MavlinkOut(OutConfig(enabled=True, targets=("camera",)), lambda m: True)
    other.on_estimate(_rec(), None, 0.0)
    assert other.sent == {"LANDING_TARGET": 0, "STATUSTEXT": 0}  # not a chosen target


def test_with_a_signing_key_what_is_sent_is_signed_and_verifies() -> None:
    """A receiver holding the key and refusing unsigned frames gets both messages, signed on
    our link id, from system 254, component 191."""
    port = free_port(socket.SOCK_DGRAM)
    peer = connect(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    peer.setup_signing(KEY, sign_outgoing=False, allow_unsigned_callback=lambda *_: False)
    link = ConnectionReader(f"udpout:127.0.0.1:{port}", signing_key=KEY, signing_link_id=9,
                            heartbeat_period_s=None)  # fmt: skip
    out = MavlinkOut(OutConfig(enabled=True), link.send)
    got = {}
    try:
        out.on_estimate(_rec(), None, 0.0)
        deadline = time.monotonic() + 5.0
        while len(got) < 2 and time.monotonic() < deadline:
            m = peer.recv_match(type=["LANDING_TARGET", "STATUSTEXT"], blocking=True, timeout=0.1)
            if m is not None:
                got[m.get_type()] = m
    finally:
        link.close()
        peer.close()
    assert set(got) == {"LANDING_TARGET", "STATUSTEXT"}
    for m in got.values():
        buf = bytes(m.get_msgbuf())
        assert buf[2] & 0x01 and buf[-13] == 9  # signed, on our link id
        assert (m.get_srcSystem(), m.get_srcComponent()) == (254, 191)


def test_the_body_frame_form_for_ardupilot_is_the_relative_position_in_the_body_frame() -> None:
    rpy = (0.1, -0.05, 1.2)
    m = landing_target(_rec(), 0, rpy, frame="body_frd")
    assert (m.frame, m.position_valid) == (12, 1)  # MAV_FRAME_BODY_FRD
    r = euler_to_dcm(*rpy)
    back = [sum(r[i][j] * (m.x, m.y, m.z)[j] for j in range(3)) for i in range(3)]
    assert back == pytest.approx([10.0, 5.0, 12.0])  # the relative position, NED
    assert m.distance == pytest.approx(math.sqrt(m.x**2 + m.y**2 + m.z**2))
    assert landing_target(_rec(), 0, None, frame="body_frd") is None  # needs the attitude
