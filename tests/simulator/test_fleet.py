"""The fleet emitter (sim/fleet.py): several vehicles, one target, consistent on WGS84."""

import json
import math
import socket
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from mav_observer.mavlink.dialect import codec, mavutil
from mav_observer.tracking.directions import gimbal_boresight
from sim import scenarios
from sim.__main__ import main
from sim.emitter import (
    ORIGIN_ALT_M,
    ORIGIN_LAT_DEG,
    ORIGIN_LON_DEG,
    Emitter,
    EmitterConfig,
    ardupilot_offset,
)
from sim.fleet import (
    Fleet,
    ardupilot_local,
    make_fleet,
    ned_to_ecef_rotation,
    run_live,
    write_tlogs,
)


def gap_m(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """The distance (m) between two geodetic points, exact."""
    return float(np.linalg.norm(pymap3d.geodetic2ned(*a, *b)))


def decoded(fleet: Fleet, sysid: int) -> list[tuple[float, object]]:
    member = fleet.member(sysid)
    mav = codec()
    return [(e.t_emit_s, mav.decode(bytearray(e.frame))) for e in member.emissions()]


def test_ardupilot_local_round_trip_is_exact() -> None:
    origin = (ORIGIN_LAT_DEG + 0.001, ORIGIN_LON_DEG - 0.002, 590.0)
    worst = 0.0
    for ned in ((0.0, 0.0, 0.0), (73.0, -41.0, -25.0), (-900.0, 1200.0, 30.0), (3e3, 5e3, -1e2)):
        point = tuple(float(v) for v in pymap3d.ned2geodetic(*ned, *origin))
        back = ardupilot_offset(*origin, *ardupilot_local(origin, point))
        worst = max(worst, gap_m(tuple(float(v) for v in back), point))
    assert worst < 1e-6
    # through the vehicles: the reported local position maps back onto the true position
    fleet = make_fleet("fleet_moving", vehicles=3, duration_s=10.0)
    for m in fleet.members:
        for t in (0.0, 3.3, 9.7):
            s = m.vehicle.state(t)
            back = ardupilot_offset(*m.origin_geodetic, *s.pos_ned_m)
            assert gap_m(tuple(float(v) for v in back), m.vehicle.geodetic(t)) < 1e-3
        assert np.allclose(m.vehicle.state(0.0).pos_ned_m[:2], 0.0, atol=1e-9)  # take-off point


def test_line_of_sight_is_the_physical_geometry() -> None:
    fleet = make_fleet("fleet_moving", vehicles=3, duration_s=10.0)
    target_ecef = np.array(pymap3d.geodetic2ecef(*fleet.target_geodetic))
    for m in fleet.members:
        for t in (0.0, 4.2):
            s = m.vehicle.state(t)
            here = m.vehicle.geodetic(t)
            los = ned_to_ecef_rotation(*here[:2]).T @ (
                target_ecef - np.array(pymap3d.geodetic2ecef(*here))
            )
            assert np.linalg.norm(s.rel_pos_ned_m - los) < 1e-6
            # ArduPilot's sphere: the reported frame's difference is centimetres off
            assert np.linalg.norm(s.target_pos_ned_m - s.pos_ned_m - los) > 0.01
            # measured = true (a horizontal 0.96 m/s circle) minus the vehicle's own error
            assert np.allclose(s.vel_true_ned_mps - s.vel_meas_ned_mps, m.vel_error_ned_mps)
            assert math.hypot(*s.vel_true_ned_mps[:2]) == pytest.approx(0.96, abs=1e-6)
            assert abs(s.vel_true_ned_mps[2]) < 1e-4
        assert np.allclose(m.emitter.scenario.a_mps, -np.asarray(m.vel_error_ned_mps))


def test_hover_lines_of_sight_are_60_to_90_degrees_apart() -> None:
    fleet = make_fleet("fleet_hover", vehicles=2)
    a, b = (m.vehicle.state(5.0).rel_pos_ned_m for m in fleet.members)
    angle = math.degrees(math.acos(a @ b / np.linalg.norm(a) / np.linalg.norm(b)))
    assert 60.0 < angle < 90.0
    assert angle == pytest.approx(68.83, abs=0.01)
    assert [m.sysid for m in fleet.members] == [1, 2]
    assert gap_m(fleet.members[0].origin_geodetic, fleet.members[1].origin_geodetic) > 50.0


def test_the_emitted_gimbal_bearing_is_the_true_line_of_sight(tmp_path: Path) -> None:
    fleet = make_fleet("fleet_hover", vehicles=2, duration_s=3.0, bearing_noise_deg=0.0)
    write_tlogs(fleet, tmp_path)
    rays = [json.loads(x) for x in (tmp_path / "fleet_rays_truth.jsonl").read_text().splitlines()]
    assert {r["sysid"] for r in rays} == {1, 2} and len(rays) == 2 * 30
    for m in fleet.members:
        mine = [r for r in rays if r["sysid"] == m.sysid]
        yaw, n = None, 0
        for _, msg in decoded(fleet, m.sysid):
            if msg.get_type() == "ATTITUDE":
                yaw = msg.yaw
            elif msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS":
                b = gimbal_boresight(msg.q, msg.flags, 0, vehicle_yaw=yaw)
                assert np.linalg.norm(np.subtract(b, mine[n]["los_ned"])) < 1e-6
                n += 1
        assert n == len(mine)
        g = mine[-1]["vehicle_geodetic"]
        assert gap_m(tuple(g), m.vehicle.geodetic(3.0)) < 1e-6


def test_clock_offset_moves_only_system_time() -> None:
    plain = make_fleet("fleet_hover", vehicles=2, duration_s=3.0, seed=4)
    off = make_fleet("fleet_hover", vehicles=2, duration_s=3.0, seed=4, clock_offsets_s={2: 0.5})
    assert [e.frame for e in plain.member(1).emissions()] == [
        e.frame for e in off.member(1).emissions()
    ]
    a, b = decoded(plain, 2), decoded(off, 2)
    assert len(a) == len(b)
    n = 0
    for (ta, ma), (tb, mb) in zip(a, b, strict=True):
        assert ta == tb and ma.get_type() == mb.get_type()
        if ma.get_type() == "SYSTEM_TIME":
            assert mb.time_unix_usec - ma.time_unix_usec == 500_000
            assert mb.time_boot_ms == ma.time_boot_ms
            n += 1
        else:
            assert ma.get_msgbuf() == mb.get_msgbuf()
    assert n == 3


def test_drop_stops_that_vehicle_only() -> None:
    fleet = make_fleet("fleet_hover", vehicles=3, duration_s=6.0, drop=(2, 2.5))
    last = {m.sysid: max(e.t_emit_s for e in m.emissions()) for m in fleet.members}
    assert 2.4 < last[2] < 2.5
    assert last[1] > 5.9 and last[3] > 5.9
    sysids = [m.sysid for m, e in fleet.emissions() if e.t_emit_s >= 2.5]
    assert sysids and 2 not in sysids
    with pytest.raises(ValueError, match="sysid 3"):
        make_fleet("fleet_hover", vehicles=2, drop=(3, 1.0))


def test_default_emitter_frames_unchanged() -> None:
    sc = scenarios.orbit(duration_s=5.0)
    kw = {"duration_s": 5.0, "bearing_noise_deg": 0.5, "velocity_noise_mps": 0.1, "seed": 5}
    default = [e.frame for e in Emitter(sc, EmitterConfig(**kw)).emissions()]
    origin = (ORIGIN_LAT_DEG, ORIGIN_LON_DEG, ORIGIN_ALT_M)
    explicit = EmitterConfig(**kw, origin_geodetic=origin, system_time_offset_s=0.0)
    assert default == [e.frame for e in Emitter(sc, explicit).emissions()]
    # another origin changes GLOBAL_POSITION_INT and nothing else
    moved = EmitterConfig(**kw, origin_geodetic=(ORIGIN_LAT_DEG + 0.01, ORIGIN_LON_DEG, 600.0))
    mav = codec()
    changed = {
        mav.decode(bytearray(a)).get_type()
        for a, b in zip(default, [e.frame for e in Emitter(sc, moved).emissions()], strict=True)
        if a != b
    }
    assert changed == {"GLOBAL_POSITION_INT"}


def test_write_tlogs_are_readable(tmp_path: Path) -> None:
    fleet = make_fleet("fleet_moving", vehicles=2, duration_s=2.0, drop=(1, 1.0))
    paths = write_tlogs(fleet, tmp_path)
    assert all(p.exists() for p in paths)
    for sysid, n_expected in ((1, 10), (2, 20)):
        conn = mavutil.mavlink_connection(str(tmp_path / f"vehicle_{sysid}.tlog"))
        n = 0
        while (msg := conn.recv_match(type="LOCAL_POSITION_NED")) is not None:
            assert msg.get_srcSystem() == sysid
            assert conn.timestamp >= fleet.members[0].emitter.config.t0_unix_s
            n += 1
        conn.close()
        assert n == n_expected
    truth = json.loads((tmp_path / "fleet_truth.json").read_text())
    assert [m["boot_at_start_s"] for m in truth["members"]] == [120.0, 157.0]
    assert truth["members"][0]["drop_after_s"] == 1.0
    assert truth["members"][1]["bias_ned_mps"] == [1.0, -1.5, -0.0]


def test_cli_and_live_links(tmp_path: Path) -> None:
    argv = ["fleet", "--vehicles", "3", "--duration", "1", "--tlog-dir", str(tmp_path)]
    assert main([*argv, "--clock-offset", "3=0.25", "--drop", "2@0.5"]) == 0
    truth = json.loads((tmp_path / "fleet_truth.json").read_text())
    assert [m["clock_offset_s"] for m in truth["members"]] == [0.0, 0.0, 0.25]
    socks = []
    for _ in range(2):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.settimeout(2.0)
        socks.append(s)
    try:
        fleet = make_fleet("fleet_hover", vehicles=2, duration_s=1.0)
        run_live(fleet, [f"udpout:127.0.0.1:{s.getsockname()[1]}" for s in socks], speed=None)
        mav = codec()
        for sysid, s in zip((1, 2), socks, strict=True):
            msg = mav.decode(bytearray(s.recv(2048)))
            assert msg.get_srcSystem() == sysid
    finally:
        for s in socks:
            s.close()
