"""A headless Chromium page for the benches (Debian's chromium and chromedriver, through
Selenium; nothing fetched from the network)."""

from __future__ import annotations

import os
import time
from typing import Any


def open_page(url: str, timeout_s: float = 20.0) -> Any:
    """A headless Chromium showing ``url`` (the live map), its first data loaded."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    os.environ["SE_OFFLINE"] = "true"
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
              "--no-first-run", "--disable-background-networking", "--disable-component-update",
              "--disable-sync", "--window-size=1400,900"):  # fmt: skip
        opts.add_argument(a)
    drv = webdriver.Chrome(options=opts, service=Service("/usr/bin/chromedriver"))
    drv.set_page_load_timeout(timeout_s)
    drv.get(url)
    end = time.monotonic() + timeout_s
    while url.startswith("http") and time.monotonic() < end:
        if drv.find_elements("id", "conn") and drv.find_element("id", "conn").text == "live":
            break
        time.sleep(0.1)
    return drv


def page_figures(drv: Any) -> dict[str, float]:
    """What the page measured: the median time (ms) from an estimate's publication to the page
    showing it, and the events it received."""
    lat = drv.find_element("id", "latency").get_attribute("data-median") or "nan"
    events = drv.find_element("id", "count").get_attribute("data-events") or "0"
    return {"dom_latency_p50_ms": float(lat), "page_events": float(events)}


def browser_cpu_ticks() -> int:
    """CPU ticks (user and system) of every Chromium process on this machine so far (the
    benches' own page: nothing else runs a Chromium here)."""
    total = 0
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/comm") as f:
                if "chrom" not in f.read():
                    continue
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])
        except (OSError, IndexError, ValueError):
            pass  # a process that ended meanwhile
    return total
