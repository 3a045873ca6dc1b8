"""The live map's feed and server (mav_observer/outputs/web.py): what the page reads, the
events it is sent, and that the service's side never waits for a page."""

from __future__ import annotations

import json
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator

import numpy as np
import pytest

from mav_observer.core.samples import Estimate, Status
from mav_observer.geo.geodesy import Origin
from mav_observer.outputs.records import EstimateRecord
from mav_observer.outputs.web import MapFeed, MapServer

ORIGIN = Origin(-35.36, 149.16, 584.0, "GPS_GLOBAL_ORIGIN")


def record(i: int, target: str = "gimbal", sysid: int = 1) -> EstimateRecord:
    est = Estimate(
        t_s=100.0 + i, x_m=np.array([20.0 + 0.01 * i, 10.0, 10.0]), a_mps=np.zeros(3),
        range_m=24.5, excitation=0.1, cond_m=3.0, status=Status.CONVERGED, corrected=True,
        bearing_age_s=0.0, velocity_age_s=0.0, correction_rel=0.0,
        x_std_m=np.array([0.3, 0.2, 0.1]), a_std_mps=np.array([0.01] * 3), range_std_m=0.2,
        nis=1.0,
    )  # fmt: skip
    return EstimateRecord(1.7e9 + i, 100.0 + i, sysid, target, "GIMBAL_DEVICE_ATTITUDE_STATUS",
                          est, (float(i), 0.0, -10.0), ORIGIN)  # fmt: skip


@pytest.fixture
def server() -> Iterator[MapServer]:
    srv = MapServer(MapFeed(max_clients=2, queue_len=4)).start()
    try:
        yield srv
    finally:
        srv.close()


def get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def test_the_page_and_its_libraries_are_served_from_here_only(server: MapServer) -> None:
    assert server.url.startswith("http://127.0.0.1:")
    code, page = get(server.url)
    assert code == 200 and b'src="/leaflet.js"' in page and b"window.MAP_CONFIG = {" in page
    for path in ("leaflet.js", "map.js", "leaflet.css", "LICENSE-leaflet.txt"):
        code, body = get(server.url + path)
        assert (code == 200 and len(body) > 1000) or path == "LICENSE-leaflet.txt"
    _, js = get(server.url + "map.js")
    assert b"//cdn" not in js and b"https://" not in js  # nothing fetched from elsewhere


def test_state_and_unknown_vehicles_and_targets(server: MapServer) -> None:
    for i in range(3):
        server.feed.add(record(i), yaw_rad=0.5, origin={"lat_deg": -35.36, "lon_deg": 149.16})
    code, body = get(server.url + "state")
    st = json.loads(body)
    assert code == 200 and st["events"] == 3
    tgt = st["targets"]["1/gimbal"]
    assert tgt["record"]["target_pos_ned_m"] == pytest.approx([22.02, 10.0, 0.0])
    assert len(tgt["history"]) == 3 and st["vehicles"]["1"]["yaw_deg"] == pytest.approx(
        28.648, 1e-3
    )
    assert get(server.url + "vehicle/1")[0] == 200
    assert get(server.url + "vehicle/7")[0] == 404
    assert get(server.url + "target/1/gimbal")[0] == 200
    assert get(server.url + "target/1/nope")[0] == 404
    assert get(server.url + "nothing")[0] == 404


def test_tracks_gain_a_point_a_second_and_stay_bounded() -> None:
    """An hour at 10 Hz leaves the page TRACK_POINTS points a track, one a second (a page
    opened late draws no more than one opened early); a reboot's clock going back adds one."""
    from dataclasses import replace

    from mav_observer.outputs import web

    feed = MapFeed()
    base = record(0)
    for k in range(2000):  # 200 s at 10 Hz
        feed.add(replace(base, t_boot_s=100.0 + 0.1 * k))
    st = feed.snapshot()
    assert len(st["targets"]["1/gimbal"]["history"]) == 200
    assert len(st["vehicles"]["1"]["track"]) == 200
    for k in range(2000, 10000):
        feed.add(replace(base, t_boot_s=100.0 + 1.0 * k))
    st = feed.snapshot()
    assert len(st["targets"]["1/gimbal"]["history"]) == web.TRACK_POINTS
    feed = MapFeed()
    for t, n in ((100.0, 1), (100.5, 1), (101.0, 2), (5.0, 3), (5.5, 3), (6.0, 4)):  # a reboot
        feed.add(replace(base, t_boot_s=t))
        assert len(feed.snapshot()["targets"]["1/gimbal"]["history"]) == n, t


def _events(url: str) -> socket.socket:
    host, port = url.split("//")[1].rstrip("/").split(":")
    s = socket.create_connection((host, int(port)), timeout=5)
    s.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")
    return s


def _read_until(s: socket.socket, needle: bytes, timeout_s: float = 5.0) -> bytes:
    buf = b""
    end = time.monotonic() + timeout_s
    while needle not in buf and time.monotonic() < end:
        buf += s.recv(65536)
    return buf


def test_events_reach_a_page_and_a_slow_page_loses_the_oldest(server: MapServer) -> None:
    s = _events(server.url)
    try:
        assert b"200" in _read_until(s, b": connected")
        server.feed.add(record(0))
        got = _read_until(s, b"}}]\n\n")
        batch = json.loads(got.split(b"data: ", 1)[1].split(b"\n\n")[0])
        assert [ev["key"] for ev in batch] == ["1/gimbal"]
        assert batch[0]["record"]["t_boot_s"] == 100.0
        recs = [record(i) for i in range(1, 2000)]
        t0 = time.perf_counter()
        for r in recs:  # the page reads nothing meanwhile: add never waits
            server.feed.add(r)
        assert time.perf_counter() - t0 < 0.1
        for r in recs:  # a batch each
            server.feed.add(r)
            server.feed.pump()
        assert server.feed.dropped >= 1500  # (what the socket buffers took was not dropped)
    finally:
        s.close()


def test_a_batch_carries_the_latest_estimate_of_each_target() -> None:
    """Ten estimates of one target and one of another between two batches: a page is sent two
    events, the latest of each, while ``/state`` counts all eleven."""
    from dataclasses import replace

    feed = MapFeed()
    q = feed.subscribe()
    assert q is not None
    for k in range(10):
        feed.add(replace(record(0), t_boot_s=100.0 + 0.01 * k))
    feed.add(record(0, target="other"))
    feed.pump()
    batch = json.loads(q.get_nowait().removeprefix(b"data: "))
    assert {ev["key"]: ev["record"]["t_boot_s"] for ev in batch} == {
        "1/gimbal": 100.09,
        "1/other": 100.0,
    }
    assert q.empty() and feed.snapshot()["events"] == 11


def test_too_many_pages_are_refused_and_a_closed_one_is_let_go(server: MapServer) -> None:
    a, b = _events(server.url), _events(server.url)
    _read_until(a, b": connected")
    _read_until(b, b": connected")
    assert get(server.url + "events")[0] == 503  # the third
    a.close()
    b.close()
    end = time.monotonic() + 5.0
    while server.feed.snapshot()["clients"] and time.monotonic() < end:
        server.feed.add(record(0))  # a write to a closed page ends its stream
        time.sleep(0.1)
    assert server.feed.snapshot()["clients"] == 0


def test_a_published_record_feeds_the_page_and_garbage_is_counted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """``mav-observer map``'s path: the JSON the service published, not a record object; a
    text that is not a record is counted in ``/state``'s ``bad`` and logged, the first one a
    warning naming it."""
    feed = MapFeed()
    feed.add_published(record(3).to_json())
    feed.add_published("not json")
    feed.add_published('{"sysid": 1}')
    st = feed.snapshot()
    assert st["events"] == 1 and feed.bad == 2 and st["bad"] == 2
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and "'not json'" in warned[0] and "JSONDecodeError" in warned[0]
    assert st["targets"]["1/gimbal"]["record"]["t_boot_s"] == 103.0
    assert st["vehicles"]["1"]["pos_ned_m"] == [3.0, 0.0, -10.0]


def fused_json(t_unix_s: float, name: str = "mast", range_m: float = 30.0) -> str:
    from mav_observer.fleet.fusion import FusedEstimate

    est = FusedEstimate(name, "converged", 12, t_unix_s, (-35.36, 149.16, 584.0), (5.0, 6.0, 0.5),
                        ((0.04, 0.01, 0.0), (0.01, 0.09, 0.0), (0.0, 0.0, 0.01)),
                        (-35.35995, 149.16007, 583.5), range_m, ())  # fmt: skip
    return json.dumps(est.to_dict())


def test_a_fused_target_feeds_the_page_state_and_events(server: MapServer) -> None:
    """``mav-observer fuse``'s records: in ``/state`` and ``/fused/NAME`` with a point of
    history a second, sent to pages as ``fused/NAME``; a NaN the page could not parse is
    null, and a text that is not a fused record is counted."""
    feed = server.feed
    q = feed.subscribe()
    assert q is not None
    for k in range(5):
        feed.add_fused(fused_json(1.7e9 + 0.5 * k, range_m=float("nan") if k == 4 else 30.0))
    feed.add_fused('{"target": "x"}')
    feed.pump()
    batch = json.loads(q.get_nowait().removeprefix(b"data: "))
    assert [ev["key"] for ev in batch] == ["fused/mast"]
    assert batch[0]["record"]["range_m"] is None and batch[0]["record"]["rays"] == 12
    st = feed.snapshot()
    assert feed.bad == 1 and st["events"] == 5
    hist = st["fused"]["mast"]["history"]
    assert [h[:2] for h in hist] == [[-35.35995, 149.16007]] * 3  # t = 0, 1, 2 s
    code, body = get(server.url + "fused/mast")
    assert code == 200 and json.loads(body)["record"]["status"] == "converged"
    assert get(server.url + "fused/none")[0] == 404
    feed.unsubscribe(q)


def test_a_status_gives_a_vehicle_its_origin_for_the_map_command() -> None:
    """``mav-observer map`` gets the estimate records without an origin: a vehicle's status
    carries it to ``/state`` and to the vehicle's next events; garbage is counted."""
    feed = MapFeed()
    q = feed.subscribe()
    assert q is not None
    origin = {"lat_deg": -35.36, "lon_deg": 149.16, "alt_m": 584.0, "source": "HOME_POSITION",
              "frame": "ardupilot"}  # fmt: skip
    feed.add_status(json.dumps({"schema": 1, "sysid": 2, "origin": origin}))
    feed.add_status('{"sysid": 2, "origin": {"lat_deg": "north"}}')
    feed.add_published(record(0, sysid=2).to_json())
    feed.pump()
    (ev,) = json.loads(q.get_nowait().removeprefix(b"data: "))
    assert ev["key"] == "2/gimbal" and ev["origin"] == origin
    assert feed.snapshot()["vehicles"]["2"]["origin"] == origin and feed.bad == 1


def test_texts_with_bad_numbers_are_counted_and_the_batch_still_goes_out() -> None:
    """A published record whose position is not numbers, a fused target whose latitude is
    text, a status whose origin is a number: each counted in ``bad``, none stops the feed's
    batch, which still carries the good estimate sent with them."""
    feed = MapFeed()
    q = feed.subscribe()
    assert q is not None
    doc = json.loads(record(1).to_json())
    feed.add_published(json.dumps({**doc, "vehicle_pos_ned_m": "north"}))
    feed.add_published(json.dumps({**doc, "target_pos_ned_m": [1.0]}))
    feed.add_fused(json.dumps({**json.loads(fused_json(1.7e9)), "lat_deg": "x"}))
    feed.add_status('{"sysid": 1, "origin": 5}')
    feed.add_published(record(2).to_json())
    feed.pump()
    (ev,) = json.loads(q.get_nowait().removeprefix(b"data: "))
    assert ev["key"] == "1/gimbal" and ev["record"]["t_boot_s"] == 102.0
    assert feed.bad == 4 and feed.snapshot()["events"] == 1
