"""The live map and the replay report in a real browser (headless Chromium, driven by
Selenium through chromedriver): the page beside a service fed by the emitter shows what the
service published; the report opens from disk. Screenshots in ``MAV_OBSERVER_FIGURES`` when
set (``docs/figures``), else the test's temporary folder.

Chromium and chromedriver are Debian's (``.ci/run`` installs them); without them these tests
skip on a developer's machine and fail under CI."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import http_json, wait_for

from mav_observer.app import replay as rp
from sim import emitter, scenarios
from sim.live import free_port, service_command, stop_process

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    missing = [p for p in (CHROMIUM, CHROMEDRIVER) if not Path(p).exists()]
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service as DriverService
    except ImportError:
        missing.append("selenium")
    if missing:
        if os.environ.get("CI"):
            pytest.fail(f"browser tests need {missing} (.ci/run installs them)")
        pytest.skip(f"no {missing}: apt-get install chromium chromium-driver")
    os.environ["SE_OFFLINE"] = "true"  # Selenium Manager must not look for drivers online
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
              "--no-first-run", "--disable-background-networking", "--disable-component-update",
              "--disable-sync", "--window-size=1400,900"):  # fmt: skip
        opts.add_argument(a)
    drv = webdriver.Chrome(options=opts, service=DriverService(CHROMEDRIVER))
    try:
        yield drv
    finally:
        drv.quit()


def figures(tmp_path: Path) -> Path:
    d = os.environ.get("MAV_OBSERVER_FIGURES")
    return Path(d) if d else tmp_path


def test_the_live_page_shows_what_the_service_published(browser: Any, tmp_path: Path) -> None:
    mav, zen, web = free_port(), free_port(), free_port()
    log = tmp_path / "service.log"
    with open(log, "wb") as fh:
        proc = subprocess.Popen(
            service_command(mav, zen, "--web", f"127.0.0.1:{web}", "--log-level", "INFO"),
            stdout=fh, stderr=subprocess.STDOUT,
        )  # fmt: skip
    stop = threading.Event()
    try:
        url = f"http://127.0.0.1:{web}/"
        assert wait_for(lambda: http_json(url + "state") is not None, 60.0), log.read_text()
        em = emitter.Emitter(
            scenarios.orbit(duration_s=120.0),
            emitter.EmitterConfig(bearing="gimbal", duration_s=120.0, bearing_noise_deg=0.5),
        )
        th = threading.Thread(target=emitter.run, args=(em,), daemon=True,
                              kwargs={"to": f"udpout:127.0.0.1:{mav}", "speed": 10.0,
                                      "stop": stop})  # fmt: skip
        th.start()
        browser.get(url)
        row = 'tr[data-key="1/gimbal"]'
        appeared = wait_for(lambda: browser.find_elements("css selector", row + "[data-n]"), 20.0)
        assert appeared, log.read_text()
        assert wait_for(lambda: browser.find_element("css selector", row).get_attribute(
            "data-status") == "converged", 60.0)  # fmt: skip
        time.sleep(1.0)
        stop.set()
        th.join(timeout=10)
        time.sleep(1.0)  # the last events reach the page
        el = browser.find_element("css selector", row)
        shown = {k: float(el.get_attribute(f"data-{k}")) for k in ("n", "e", "t")}
        st = http_json(url + "state")
        published = st["targets"]["1/gimbal"]["record"]
        assert shown["t"] == pytest.approx(published["t_boot_s"], abs=1e-6)
        assert shown["n"] == pytest.approx(published["target_pos_ned_m"][0], abs=1e-6)
        assert shown["e"] == pytest.approx(published["target_pos_ned_m"][1], abs=1e-6)
        # the row's text, rewritten at most every 0.5 s, ends on the last estimate too
        tp = published["target_pos_ned_m"]
        assert el.find_element("css selector", ".ne").text == f"{tp[0]:.2f}, {tp[1]:.2f}"
        assert el.find_element("css selector", ".age").text == f"t {published['t_boot_s']:.1f} s"
        count = browser.find_element("id", "count")  # its text held back too, then written
        assert count.text == f"{count.get_attribute('data-events')} events"
        median = float(browser.find_element("id", "latency").get_attribute("data-median"))
        assert median < 200.0  # published -> shown in the page's DOM, ms
        browser.save_screenshot(str(figures(tmp_path) / "live_map.png"))
    finally:
        stop.set()
        stop_process(proc)


def test_the_replay_report_opens_from_disk(browser: Any, tmp_path: Path) -> None:
    tlog = tmp_path / "f.tlog"
    em = emitter.Emitter(scenarios.orbit(duration_s=120.0), emitter.EmitterConfig(
        bearing="gimbal", duration_s=120.0, bearing_noise_deg=0.5))  # fmt: skip
    emitter.run(em, tlog=tlog)
    report = tmp_path / "report.html"
    subprocess.run([sys.executable, "-m", "mav_observer", "replay", str(tlog), "--html",
                    str(report), "-q"], capture_output=True, timeout=300, check=True)  # fmt: skip
    summary = rp.replay(str(tlog))
    final = summary.targets["1/gimbal"].final
    assert final is not None
    t0 = time.perf_counter()
    browser.get(report.as_uri())
    body = browser.find_element("tag name", "body")
    assert wait_for(lambda: body.get_attribute("data-ready"), 20.0)
    opened_s = time.perf_counter() - t0
    el = browser.find_element("css selector", 'tr[data-key="1/gimbal"]')
    assert el.get_attribute("data-status") == "converged"
    assert float(el.get_attribute("data-n")) == pytest.approx(final.target_pos_ned_m[0], abs=0.01)
    assert opened_s < 5.0
    browser.save_screenshot(str(figures(tmp_path) / "replay_report.png"))


def test_a_fleet_on_one_map_each_vehicle_from_its_origin_and_a_fused_target(
    browser: Any, tmp_path: Path
) -> None:
    """Three vehicles see one target from local frames whose origins lie up to 120 m apart
    (the third's origin known only from its published records, as ``mav-observer map`` gets
    them), and ``fuse`` publishes the target: the page draws all four at one place."""
    import numpy as np

    from mav_observer.core.samples import Estimate, Status
    from mav_observer.fleet.fusion import FusedEstimate
    from mav_observer.geo.geodesy import Origin, to_geodetic
    from mav_observer.outputs.records import EstimateRecord
    from mav_observer.outputs.web import MapFeed, MapServer

    lat0, lon0 = -35.36, 149.16
    o1 = Origin(lat0, lon0, 584.0, "GPS_GLOBAL_ORIGIN")
    offsets = {1: (0.0, 0.0), 2: (100.0, 50.0), 3: (-80.0, 90.0)}  # m, north and east of o1
    origins = {
        v: Origin(*to_geodetic(o1, (dn, de, 0.0))[:2], 584.0, "GPS_GLOBAL_ORIGIN")
        for v, (dn, de) in offsets.items()
    }

    def rec(sysid: int, t: float) -> EstimateRecord:
        o_n, o_e = offsets[sysid]
        vp = (10.0 - o_n, -5.0 - o_e, -20.0)  # every vehicle at (10, -5) from o1
        est = Estimate(
            t_s=t, x_m=np.array([30.0, 35.0, 20.0]), a_mps=np.zeros(3), range_m=50.0,
            excitation=0.1, cond_m=3.0, status=Status.CONVERGED, corrected=True,
            bearing_age_s=0.0, velocity_age_s=0.0, correction_rel=0.0,
            x_std_m=np.array([0.5, 0.4, 0.3]), a_std_mps=np.array([0.01] * 3), range_std_m=0.2,
            nis=1.0,
        )  # fmt: skip
        return EstimateRecord(1.7e9 + t, t, sysid, "gimbal", "GIMBAL_DEVICE_ATTITUDE_STATUS",
                              est, vp, origins[sysid])  # fmt: skip

    feed = MapFeed()
    srv = MapServer(feed).start()
    try:
        feed.add(rec(1, 100.0), None, o1.to_dict())  # in /state when the page loads
        browser.get(srv.url)
        assert wait_for(lambda: browser.find_elements("css selector", 'tr[data-key="1/gimbal"]'),
                        20.0)  # fmt: skip
        geo = rec(1, 101.0).target_geodetic()
        assert geo is not None
        fused = FusedEstimate("mast", "converged", 40, 1.7e9 + 101.0, (lat0, lon0, 584.0),
                              (40.0, 30.0, 0.0), ((0.09, 0.03, 0.0), (0.03, 0.04, 0.0),
                                                  (0.0, 0.0, 0.01)), geo[:3], 50.0, ())  # fmt: skip
        for t in (101.0, 102.0):  # by events, after the page loaded
            feed.add(rec(2, t), None, origins[2].to_dict())
            feed.add_published(rec(3, t).to_json())
        feed.add_fused(json.dumps(fused.to_dict()))
        keys = ("1/gimbal", "2/gimbal", "3/gimbal", "fused/mast")

        def drawn() -> dict[str, list[float]] | None:
            out = {}
            for k in keys:
                els = browser.find_elements("css selector", f'tr[data-key="{k}"][data-map-ne]')
                if not els:
                    return None
                out[k] = [float(x) for x in els[0].get_attribute("data-map-ne").split(",")]
            return out

        assert wait_for(drawn, 20.0)
        where = drawn()
        assert where is not None
        for k in keys:  # the target at (40, 30) from the first origin, to a centimetre
            assert where[k] == pytest.approx([40.0, 30.0], abs=0.01), (k, where)
        ne = browser.find_element("css selector", 'tr[data-key="3/gimbal"] .ne')
        assert wait_for(lambda: ne.text == "40.00, 30.00", 5.0), ne.text  # from the map's origin
        row = browser.find_element("css selector", 'tr[data-key="fused/mast"]')
        assert row.get_attribute("data-status") == "converged" and row.get_attribute(
            "data-rays") == "40"  # fmt: skip
        st = http_json(srv.url + "state")
        assert st is not None and st["fused"]["mast"]["record"]["rays"] == 40
        # the first vehicle's origin, the grid's, is found 10 m further north (its local frame
        # unchanged): what the others and fuse placed moves 10 m south on the grid
        origins[1] = Origin(*to_geodetic(o1, (10.0, 0.0, 0.0))[:2], 584.0, "HOME_POSITION")
        feed.add(rec(1, 103.0), None, origins[1].to_dict())
        expected = {"1/gimbal": [40.0, 30.0], "2/gimbal": [30.0, 30.0], "3/gimbal": [30.0, 30.0],
                    "fused/mast": [30.0, 30.0]}  # fmt: skip

        def moved() -> bool:
            now = drawn()
            return now is not None and all(
                abs(now[k][0] - v[0]) < 0.01 and abs(now[k][1] - v[1]) < 0.01
                for k, v in expected.items()
            )

        assert wait_for(moved, 10.0), drawn()
        assert ne.text == "30.00, 30.00"  # the table's text too
        browser.save_screenshot(str(tmp_path / "fleet_map.png"))
    finally:
        srv.close()


def test_a_fusion_report_opens_from_disk(browser: Any, tmp_path: Path) -> None:
    """``fuse --rays ... --html``'s page: the vehicles from their rays and the fused target,
    in metres from the first ray's position, at the slider's time."""
    from mav_observer.fleet.fusion import FusedEstimate
    from mav_observer.fleet.rays import Ray
    from mav_observer.geo.geodesy import Origin, to_geodetic
    from mav_observer.outputs.html_report import FusedReportData, write_html

    first = Origin(-35.36, 149.16, 600.0, "GPS_GLOBAL_ORIGIN")
    data = FusedReportData()
    for k in range(50):
        t = 1.7e9 + 0.2 * k
        for sysid, (n, e) in ((1, (0.0, 0.0)), (2, (0.0, 60.0 + k))):
            lat, lon, alt = to_geodetic(first, (n, e, 0.0))
            data.add_ray(Ray(sysid, "gimbal", t, 100.0 + t - 1.7e9, "autopilot", lat, lon, alt,
                             (0.6, 0.0, 0.8), 0.01))  # fmt: skip
        geo = to_geodetic(first, (40.0, 30.0, 20.0))
        data.add_fused(FusedEstimate("mast", "converged" if k > 10 else "converging", 2 * k + 2,
                                     t, (-35.36, 149.16, 600.0), (40.0, 30.0, 20.0),
                                     ((0.04, 0.0, 0.0), (0.0, 0.09, 0.0), (0.0, 0.0, 0.01)),
                                     geo, 50.0, ()))  # fmt: skip
    report = tmp_path / "fused.html"
    write_html(report, data, "fusion", "mast: converged", None)
    browser.get(report.as_uri())
    body = browser.find_element("tag name", "body")
    assert wait_for(lambda: body.get_attribute("data-ready"), 20.0)
    row = browser.find_element("css selector", 'tr[data-key="fused/mast"]')
    assert row.get_attribute("data-status") == "converged"
    assert float(row.get_attribute("data-n")) == pytest.approx(40.0, abs=0.01)
    assert float(row.get_attribute("data-e")) == pytest.approx(30.0, abs=0.01)
    assert browser.find_element("id", "t").text.startswith("t from the first ray 9.8")
    browser.save_screenshot(str(figures(tmp_path) / "fusion_report.png"))
