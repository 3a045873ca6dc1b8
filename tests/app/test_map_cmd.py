"""``mav-observer map`` (mav_observer/app/map_cmd.py): the live map on another process than the
service, fed over Zenoh, shows what the service published. Free loopback ports; every process
started here is ended here."""

from __future__ import annotations

import subprocess
import sys
import threading
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
        tp = rec["target_pos_ned_m"]  # the orbit's target at (40, 30, 0)
        assert abs(tp[0] - 40.0) < 2.0 and abs(tp[1] - 30.0) < 2.0
    finally:
        stop.set()
        stop_process(mp)
        stop_process(svc)
