"""``mav-observer listen``: rows and JSON lines from what arrives."""

from __future__ import annotations

import io
import json
import threading
import time

import pytest

from mav_observer.app.listen import HEADER, format_row, listen
from mav_observer.outputs.zenoh_io import Publications

EST = {
    "status": "converged",
    "range_m": 18.03,
    "rel_pos_ned_m": [15.0, 0.1, 10.0],
    "bias_ned_mps": [-3.0, 2.0, 0.0],
    "pe": 0.35,
}


def test_rows_for_estimates_and_status() -> None:
    row = format_row("mav_observer/1/gimbal/estimate", json.dumps(EST), 0.0)
    assert "converged" in row and "18.03" in row and "-3.00" in row
    status = {
        "link": {"state": "stale"},
        "rates_hz": {"A": 10.0, "B": 5.0},
        "skipped": {"x": 2},
        "link_skipped": {"bad_data": 1},
        "observers": {"gimbal": {"status": "stale"}},
    }
    row = format_row("mav_observer/1/status", json.dumps(status), 0.0)
    assert "link stale, 15 msg/s, 3 skipped; gimbal: stale" in row
    assert "not json" in format_row("other/key", "not json", 0.0)


@pytest.mark.slow
def test_listen_prints_json_lines_and_stops_by_itself(pair) -> None:
    server, client = pair
    pubs = Publications(server)
    out = io.StringIO()
    done: list[int] = []
    th = threading.Thread(
        target=lambda: done.append(
            listen(client, "mav_observer/**", out=out, json_lines=True, count=3, duration_s=5)
        )
    )
    th.start()
    time.sleep(0.3)
    pubs.vehicle(1)
    time.sleep(0.2)
    pubs.estimate(1, "gimbal", json.dumps(EST))
    pubs.status(1, '{"sysid": 1}')
    th.join(6)
    assert done == [3]
    lines = [json.loads(x) for x in out.getvalue().splitlines()]
    assert lines[0] == {**lines[0], "key": "mav_observer/1/alive", "liveliness": "alive"}
    assert lines[1]["key"] == "mav_observer/1/gimbal/estimate" and lines[1]["value"] == EST
    assert lines[2]["value"] == {"sysid": 1}
    pubs.close()


def test_listen_table_has_a_header_and_ends_after_its_duration(pair) -> None:
    _, client = pair
    out = io.StringIO()
    t0 = time.monotonic()
    assert listen(client, "mav_observer/**", out=out, duration_s=0.3) == 0
    assert 0.25 < time.monotonic() - t0 < 2.0
    assert out.getvalue().splitlines() == [HEADER]
