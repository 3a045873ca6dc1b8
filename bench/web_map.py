"""The live map's cost to the service, its delay to the page, and the replay report's size.

Run: ``python bench/web_map.py [--pairs N] [--json FILE]`` (about thirty minutes with 6 pairs).

* **Many targets** (the goal's case): ``bench/service_targets.py``'s run, 10 vehicles of 10
  targets each at 10 Hz (every vehicle's whole stream; 1,000 estimates a second, every one
  published, the latest of each target sent to the page five times a second), without and with
  the page open in a headless Chromium on the same machine, alternating, ``--pairs`` of each:
  the service's latency (a bearing sent to its estimate received) with the page over without
  it, p50 and p99 (goal: within 1.1x); the share of estimates delivered, the service's CPU and
  Chromium's, the page's median delay from an estimate's publication to its DOM showing it
  (goal: under 200 ms). Twice: with ATTITUDE at 20 Hz, as autopilots stream it (a
  LANDING_TARGET waits for the attitude after it, so the latency is mostly that wait), and at
  100 Hz (the wait at most 10 ms: the sharper measure); with the page's events read by
  ``curl`` instead of a browser (what the service itself spends on a page).
* **One target at 100 Hz** (harder than the goal's case): ``bench/service_latency.py``'s run (a
  gimbal at 100 Hz, every estimate published, 0.4 ms from a bearing to its estimate), without
  and with the page, and with the page's events read by ``curl`` instead of a browser (what
  the service itself spends on a page, without a browser's rendering on its cores).
* **The replay report of a one-hour flight** (the orbit scenario, 10 Hz gimbal, ``bench/.cache``):
  ``replay --html``'s file size (goal: under 20 MB) and the time the headless browser takes to
  open it from disk and show it (goal: under 2 s).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT))

import service_latency  # noqa: E402
import service_targets  # noqa: E402
from _browser import open_page  # noqa: E402

CACHE = ROOT / "bench" / ".cache"


def latency(pairs: int) -> dict[str, Any]:
    args = argparse.Namespace(
        updates=3000, warmup=200, bearing_hz=100.0, position_hz=100.0, attitude_hz=200.0,
        background_hz=0.0, speed=1.0, drain_s=1.0, seed=0, service_log_level="WARNING",
        breakdown=False,
    )  # fmt: skip
    without, with_page, with_reader = [], [], []
    for _ in range(pairs):
        without.append(service_latency.run(args))
        with_page.append(service_latency.run(args, web_page="browser"))
        with_reader.append(service_latency.run(args, web_page="reader"))
    med = statistics.median
    return {
        "reader_p50_ratio": med(
            w["p50_ms"] / b["p50_ms"] for w, b in zip(with_reader, without, strict=True)
        ),
        "reader_p99_ratio": med(
            w["p99_ms"] / b["p99_ms"] for w, b in zip(with_reader, without, strict=True)
        ),
        "p50_ratio": med(
            w["p50_ms"] / b["p50_ms"] for w, b in zip(with_page, without, strict=True)
        ),
        "p99_ratio": med(
            w["p99_ms"] / b["p99_ms"] for w, b in zip(with_page, without, strict=True)
        ),
        "p50_ms": med(b["p50_ms"] for b in without),
        "p50_ms_page": med(w["p50_ms"] for w in with_page),
        "dom_latency_p50_ms": med(w["dom_latency_p50_ms"] for w in with_page),
        "lost_page": sum(w["lost"] for w in with_page),
    }


def targets(pairs: int, attitude_hz: float) -> dict[str, Any]:
    args = argparse.Namespace(targets=100, vehicles=10, bearing_hz=10.0, duration_s=20.0,
                              settle_s=10.0, seed=0, attitude_hz=attitude_hz)  # fmt: skip
    runs, reader = [], []
    for _ in range(pairs):
        runs.append((service_targets.run(args), service_targets.run(args, True)))
        reader.append(service_targets.run(args, "reader"))
    med = statistics.median
    base = [b for b, _ in runs]
    return {
        # pair by pair: (p50, p99) with the page over without, and with curl over without
        "pairs_page": [(w["latency_p50_ms"] / b["latency_p50_ms"],
                        w["latency_p99_ms"] / b["latency_p99_ms"]) for b, w in runs],
        "pairs_reader": [(r["latency_p50_ms"] / b["latency_p50_ms"],
                          r["latency_p99_ms"] / b["latency_p99_ms"])
                         for b, r in zip(base, reader, strict=True)],
        "reader_p50_ratio": med(
            r["latency_p50_ms"] / b["latency_p50_ms"] for b, r in zip(base, reader, strict=True)
        ),
        "reader_p99_ratio": med(
            r["latency_p99_ms"] / b["latency_p99_ms"] for b, r in zip(base, reader, strict=True)
        ),
        "attitude_hz": attitude_hz,
        "without": runs[-1][0],
        "page": runs[-1][1],
        # a bearing sent to its estimate received, with the page over without, pair by pair
        "p50_ratio": med(w["latency_p50_ms"] / b["latency_p50_ms"] for b, w in runs),
        "p99_ratio": med(w["latency_p99_ms"] / b["latency_p99_ms"] for b, w in runs),
        "p50_ms": med(b["latency_p50_ms"] for b, _ in runs),
        "p99_ms": med(b["latency_p99_ms"] for b, _ in runs),
        "dom_latency_p50_ms": med(w["dom_latency_p50_ms"] for _, w in runs),
        "browser_cpu_pct": med(w["browser_cpu_pct"] for _, w in runs),
        "service_cpu_pct_page": med(w["service_cpu_pct"] for _, w in runs),
        "service_cpu_pct": med(b["service_cpu_pct"] for b, _ in runs),
    }


def report() -> dict[str, Any]:
    CACHE.mkdir(parents=True, exist_ok=True)
    tlog, html = CACHE / "orbit_1h.tlog", CACHE / "orbit_1h.html"
    if not tlog.exists():
        subprocess.run([sys.executable, "-m", "sim", "emit", "--scenario", "orbit", "--tlog",
                        str(tlog), "--duration", "3600", "--bearing-noise-deg", "0.5"],
                       cwd=ROOT, check=True, capture_output=True)  # fmt: skip
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "mav_observer", "replay", str(tlog), "--html",
                    str(html), "-q"], cwd=ROOT, check=True, capture_output=True)  # fmt: skip
    write_s = time.perf_counter() - t0
    drv = open_page("about:blank")
    try:
        t0 = time.perf_counter()
        drv.get(html.as_uri())
        while not drv.find_element("tag name", "body").get_attribute("data-ready"):
            time.sleep(0.02)
        open_s = time.perf_counter() - t0
    finally:
        drv.quit()
    return {"bytes": html.stat().st_size, "open_s": open_s, "replay_with_html_s": write_s}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", type=int, default=2)
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    res = {
        "latency": latency(args.pairs),
        "targets": targets(args.pairs, 20.0),
        "targets_sharp": targets(args.pairs, 100.0),
        "report": report(),
    }
    lat, tg, rep = res["latency"], res["targets"], res["report"]
    print(f"service latency with the page open over without: p50 {lat['p50_ratio']:.2f}x, "
          f"p99 {lat['p99_ratio']:.2f}x; published to the page's DOM: p50 "
          f"{lat['dom_latency_p50_ms']:.0f} ms; events read by curl instead of a browser: p50 "
          f"{lat['reader_p50_ratio']:.2f}x, p99 {lat['reader_p99_ratio']:.2f}x")  # fmt: skip
    for name, r in ((k, tg[k]) for k in ("without", "page")):
        page = ""
        if name == "page":
            page = (f", page events {r.get('page_events', 0):.0f}, DOM p50 "
                    f"{r.get('dom_latency_p50_ms', float('nan')):.0f} ms")  # fmt: skip
        late_ms = 1000 * r["drain_after_last_send_s"]
        print(f"10 vehicles x 10 targets at 10 Hz, {name}: "
              f"{100 * r['received_share']:.2f} % delivered, "
              f"service CPU {r['service_cpu_pct']:.0f} %, last estimate {late_ms:.0f} ms "
              f"after the last bearing{page}")  # fmt: skip
    for t in (tg, res["targets_sharp"]):
        print(f"10 x 10, ATTITUDE at {t['attitude_hz']:g} Hz, the service's latency with the "
              f"page over without: p50 {t['p50_ratio']:.2f}x, p99 {t['p99_ratio']:.2f}x "
              f"(without: p50 {t['p50_ms']:.2f} ms, p99 {t['p99_ms']:.2f} ms); curl instead: "
              f"p50 {t['reader_p50_ratio']:.2f}x, p99 {t['reader_p99_ratio']:.2f}x; Chromium "
              f"{t['browser_cpu_pct']:.0f} % of a core, the service "
              f"{t['service_cpu_pct_page']:.0f} % ({t['service_cpu_pct']:.0f} % without); DOM p50 "
              f"{t['dom_latency_p50_ms']:.0f} ms")  # fmt: skip
    print(
        f"one-hour report: {rep['bytes'] / 1e6:.1f} MB, opened and shown in {rep['open_s']:.2f} s"
    )
    if args.json:
        args.json.write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
