"""``mav-observer fuse`` and ``router``: shared targets from the command line, the offline
fusion of ``replay --rays`` files, and a live fleet through a router."""

from __future__ import annotations

import json
from pathlib import Path

import pymap3d
import pytest

from mav_observer.app.cli import main
from mav_observer.app.fuse_cmd import Fusion, parse_groups
from mav_observer.errors import ConfigError
from sim.fleet import make_fleet, write_tlogs


def test_shared_targets_come_from_flags_and_a_table_and_bad_ones_are_named() -> None:
    g = parse_groups(["p1=1/gimbal, 2/gimbal"], {"p2": ["3/camera"]})
    assert g == {"p1": ["1/gimbal", "2/gimbal"], "p2": ["3/camera"]}
    for bad in (["p1"], ["p1=gimbal"], ["p1=0/gimbal"], ["a/b=1/gimbal"]):
        with pytest.raises(ConfigError):
            parse_groups(bad)
    with pytest.raises(ConfigError, match="at least one"):
        parse_groups([])


def test_a_bad_ray_is_counted_not_fatal() -> None:
    f = Fusion({"p": ["1/gimbal"]})
    assert f.parse(b"{not json") is None and f.parse('{"sysid": 1}') is None
    assert f.counts["bad_ray"] == 2


def test_two_vehicles_logs_fuse_offline_into_the_target(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fl = make_fleet("fleet_hover", vehicles=2, seed=1, duration_s=8.0)
    write_tlogs(fl, tmp_path)
    rays = []
    for m in fl.members:
        r = tmp_path / f"rays{m.sysid}.jsonl"
        tlog = str(tmp_path / f"vehicle_{m.sysid}.tlog")
        assert main(["replay", tlog, "--rays", str(r), "-q"]) == 0
        rays.append(str(r))
    with Path(rays[0]).open("a") as fh:
        fh.write("not a ray\n")
    out, html = tmp_path / "fused.jsonl", tmp_path / "fused.html"
    assert main(["fuse", "--rays", *rays, "--target", "t=1/gimbal,2/gimbal", "-o", str(out),
                 "--html", str(html)]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "t: converged" in text and "1 rays refused" in text
    last = json.loads(out.read_text().splitlines()[-1])
    assert [v["key"] for v in last["vehicles"]] == ["1/gimbal", "2/gimbal"]
    n, e, d = pymap3d.geodetic2ned(last["lat_deg"], last["lon_deg"], last["alt_m"],
                                   *fl.target_geodetic)  # fmt: skip
    for err, sd in zip((n, e, d), last["pos_std_ned_m"], strict=True):
        assert abs(err) < 5 * sd
    # the map report: both vehicles, and the fused target where the fusion put it
    page = html.read_text()
    report = json.loads(page.split("window.REPORT = ", 1)[1].split(";</script>", 1)[0])
    assert sorted(report["vehicles"]) == ["1", "2"] and report["clock"] == "t from the first ray"
    o = report["vehicles"]["1"]["origin"]
    row = report["targets"]["fused/t"]["series"][-1]
    n0, e0, _ = pymap3d.geodetic2ned(last["lat_deg"], last["lon_deg"], last["alt_m"],
                                     o["lat_deg"], o["lon_deg"], o["alt_m"])  # fmt: skip
    assert row[5] == "converged" and abs(row[1] - n0) < 0.05 and abs(row[2] - e0) < 0.05


def test_a_report_needs_ray_files(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fuse", "--target", "t=1/gimbal,2/gimbal", "--html", "x.html"]) != 0
    assert "--html" in capsys.readouterr().err


@pytest.mark.slow
def test_a_live_fleet_through_a_router_fuses_within_milliseconds() -> None:
    from bench.fleet_live import run

    r = run(duration_s=8.0, fleet="fleet_hover", seed=2)
    last = r["last"]
    assert last["status"] == "converged", r["logs"]
    assert {v["key"] for v in last["vehicles"]} == {"1/gimbal", "2/gimbal"}
    assert r["latency_ms_p50"] < 100.0  # 2-3 ms on an idle machine (docs/performance.md)
    for err, sd in zip(r["last_error_ned_m"], last["pos_std_ned_m"], strict=True):
        assert abs(err) < 5 * sd


def test_a_fused_target_goes_to_the_autopilots_as_follow_target() -> None:
    import socket

    from mav_observer.app.fuse_cmd import _FollowTargetOut
    from mav_observer.fleet.fusion import FusedEstimate
    from mav_observer.mavlink.dialect import connect

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rx = connect(f"udpin:127.0.0.1:{port}")
    out = _FollowTargetOut([f"udpout:127.0.0.1:{port}"], 250, 4.0)
    est = FusedEstimate("p", "converged", 40, 0.0, (-35.0, 149.0, 580.0), (1.0, 2.0, 3.0),
                        ((0.04, 0, 0), (0, 0.09, 0), (0, 0, 0.01)), (-35.36, 149.16, 584.5),
                        54.0, ())  # fmt: skip
    try:
        out.send(est, 100.0)
        out.send(est, 100.1)  # within 1/4 s: not sent again
        msg = rx.recv_match(type="FOLLOW_TARGET", blocking=True, timeout=5)
        assert msg is not None and msg.get_srcSystem() == 250
        assert (msg.lat, msg.lon, msg.alt) == (-353600000, 1491600000, pytest.approx(584.5))
        assert list(msg.position_cov) == pytest.approx([0.04, 0.09, 0.01])
        assert rx.recv_match(type="FOLLOW_TARGET", blocking=True, timeout=0.3) is None
    finally:
        out.close()
        rx.close()
