"""The live map and the replay report in a real browser (headless Chromium, driven by
Selenium through chromedriver): the page beside a service fed by the emitter shows what the
service published; the report opens from disk. Screenshots in ``MAV_OBSERVER_FIGURES`` when
set (``docs/figures``), else the test's temporary folder.

Chromium and chromedriver are Debian's (``.ci/run`` installs them); without them these tests
skip on a developer's machine and fail under CI."""

from __future__ import annotations

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
