"""``mav-observer map`` (mav_observer/app/map_cmd.py): the live map on another process than the
service, fed over Zenoh, shows what the service published. Free loopback ports; every process
started here is ended here."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from conftest import http_json, wait_for

from sim import emitter, scenarios
from sim.live import free_port, service_command, stop_process

pytestmark = pytest.mark.slow


def test_the_map_command_shows_the_services_estimates(tmp_path: Path) -> None:
    mav, zen, web = free_port(), free_port(), free_port()
    log = tmp_path / "service.log"
    with open(log, "wb") as fh:
        svc = subprocess.Popen(service_command(mav, zen, "--log-level", "INFO"),
                               stdout=fh, stderr=subprocess.STDOUT)  # fmt: skip
    mp = subprocess.Popen(
        [sys.executable, "-m", "mav_observer", "map", "--connect", f"tcp/127.0.0.1:{zen}",
         "--web", f"127.0.0.1:{web}", "--duration", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    stop = threading.Event()
    try:
        url = f"http://127.0.0.1:{web}/"
        assert wait_for(lambda: http_json(url + "state") is not None, 60.0)
        em = emitter.Emitter(
            scenarios.orbit(duration_s=60.0),
            emitter.EmitterConfig(bearing="gimbal", duration_s=60.0, bearing_noise_deg=0.5),
        )
        th = threading.Thread(target=emitter.run, args=(em,), daemon=True,
                              kwargs={"to": f"udpout:127.0.0.1:{mav}", "speed": 10.0,
                                      "stop": stop})  # fmt: skip
        th.start()
        th.join(timeout=60)
        wait_for(lambda: "1/gimbal" in (http_json(url + "state") or {"targets": {}})["targets"],
                 20.0)  # fmt: skip
        st = http_json(url + "state")
        assert st is not None and "1/gimbal" in st["targets"], log.read_text()
        rec = st["targets"]["1/gimbal"]["record"]
        assert rec["sysid"] == 1 and rec["status"] in ("converged", "converging")
        assert st["events"] > 100 and len(st["vehicles"]["1"]["track"]) > 10
        origin = st["vehicles"]["1"]["origin"]  # from the service's status
        assert origin["lat_deg"] == pytest.approx(rec["target_lat_deg"], abs=1e-3)
        tp = rec["target_pos_ned_m"]  # the orbit's target at (40, 30, 0)
        assert abs(tp[0] - 40.0) < 2.0 and abs(tp[1] - 30.0) < 2.0
    finally:
        stop.set()
        stop_process(mp)
        stop_process(svc)


def test_the_services_page_shows_a_fused_target_published_beside_it(tmp_path: Path) -> None:
    """``run --web`` follows ``mav_observer/fused/*``: a record a ``fuse`` node publishes on
    the service's Zenoh reaches the page's ``/state`` and ``/fused/NAME``."""
    from mav_observer.outputs.zenoh_io import open_session, session_config
    from sim.live import wait_for_peer

    mav, zen, web = free_port(), free_port(), free_port()
    log = tmp_path / "service.log"
    with open(log, "wb") as fh:
        svc = subprocess.Popen(service_command(mav, zen, "--web", f"127.0.0.1:{web}"),
                               stdout=fh, stderr=subprocess.STDOUT)  # fmt: skip
    session = None
    try:
        url = f"http://127.0.0.1:{web}/"
        assert wait_for(lambda: http_json(url + "state") is not None, 60.0), log.read_text()
        session = open_session(session_config(listen=[], connect=[f"tcp/127.0.0.1:{zen}"]))
        assert wait_for_peer(session, 20.0)
        fused = {"schema": 1, "target": "mast", "status": "converged", "t_unix_s": 1.7e9,
                 "lat_deg": -35.36, "lon_deg": 149.16, "alt_m": 584.0, "rays": 7,
                 "pos_ned_m": [1.0, 2.0, 0.0], "pos_std_ned_m": [0.1, 0.1, 0.1]}  # fmt: skip

        def shown() -> bool:
            session.put("mav_observer/fused/mast", json.dumps(fused))
            time.sleep(0.3)
            return "mast" in (http_json(url + "state") or {}).get("fused", {})

        assert wait_for(shown, 20.0), log.read_text()
        assert http_json(url + "fused/mast")["record"]["rays"] == 7
    finally:
        if session is not None:
            session.close()
        stop_process(svc)
