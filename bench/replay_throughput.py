"""Replay throughput against a plain pymavlink loop, on real logs and a long emitter log.

Run: ``python bench/replay_throughput.py`` (a few minutes; ``--quick`` skips the long log).

For each file, messages of the file per second for:

* the plain loop: ``mavutil.mavlink_connection(path)`` then ``recv_match()`` until None (it
  decodes every message);
* the whole replay: ``mav-observer replay`` as a function, observers and an estimates JSON
  Lines file included (sources ``auto``; a log with no bearing stream ends in the "no usable
  bearing" error after reading the whole file, and is also timed with the synthetic ``home``
  source, which runs an observer on every LOCAL_POSITION_NED).

Runs alternate (plain, replay, plain, replay, ...) and each figure is the median of
``--repeat`` runs, because the machine's speed drifts. The long log is an hour of the orbit
scenario from the emitter (gimbal at 10 Hz, attitude at 20 Hz, position at 10 Hz) plus
100 messages/s of other telemetry; it is generated once into ``bench/.cache/``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mav_observer.mavlink.dialect import connect  # noqa: E402
from mav_observer.mavlink.tracker import TrackerConfig  # noqa: E402
from mav_observer.replay import ReplayError, replay  # noqa: E402
from sim.tlogs import find_tlogs  # noqa: E402

TLOGS = find_tlogs()
CACHE = ROOT / "bench" / ".cache"
LONG = CACHE / "long_orbit_1h.tlog"


def plain_loop(path: Path) -> tuple[int, float]:
    t0 = time.perf_counter()
    conn = connect(str(path))
    n = 0
    while conn.recv_match() is not None:
        n += 1
    conn.close()
    return n, time.perf_counter() - t0


def run_replay(path: Path, sources: tuple[str, ...]) -> tuple[float, int, str]:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        try:
            s = replay(
                str(path),
                tracker_config=TrackerConfig(sources=sources),
                output_jsonl=Path(tmp) / "estimates.jsonl",
            )
            outcome = f"{s.estimates_written} estimates"
        except ReplayError as exc:
            no_bearing = exc.exit_code == 3
            outcome = f"exit {exc.exit_code} (no bearing stream)" if no_bearing else str(exc)
            s = None
        wall = time.perf_counter() - t0
    return wall, 0 if s is None else s.messages_read, outcome


def make_long_log() -> None:
    if LONG.exists():
        return
    CACHE.mkdir(parents=True, exist_ok=True)
    print(f"generating {LONG} (an hour of emitter traffic) ...", flush=True)
    subprocess.run(
        [
            sys.executable, "-m", "sim", "emit", "--scenario", "orbit", "--bearing", "gimbal",
            "--duration", "3600", "--background-hz", "100", "--bearing-noise-deg", "0.5",
            "--tlog", str(LONG),
        ],
        cwd=ROOT,
        check=True,
    )  # fmt: skip


def measure(path: Path, sources: tuple[str, ...], repeat: int) -> dict[str, object]:
    plain, rep = [], []
    n_plain = 0
    outcome = ""
    for _ in range(repeat):
        n_plain, w = plain_loop(path)
        plain.append(w)
        w, _, outcome = run_replay(path, sources)
        rep.append(w)
    p, r = statistics.median(plain), statistics.median(rep)
    return {
        "file": path.name,
        "sources": ",".join(sources),
        "messages": n_plain,
        "plain_msgs_per_s": n_plain / p,
        "replay_msgs_per_s": n_plain / r,
        "ratio": p / r,
        "outcome": outcome,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="real logs only")
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    args = parser.parse_args()
    files = sorted(TLOGS.glob("*.tlog"))
    if not args.quick:
        make_long_log()
        files.append(LONG)
    results = []
    head = f"{'file':40s} {'sources':7s} {'msgs':>7s} {'plain/s':>9s} {'replay/s':>9s}"
    print(f"{head} {'ratio':>6s}  outcome")
    for f in files:
        runs = [("auto",)]
        r = measure(f, ("auto",), args.repeat)
        if r["outcome"].startswith("exit 3"):  # type: ignore[union-attr]
            runs.append(("home",))
        for sources in runs:
            if sources != ("auto",):
                r = measure(f, sources, args.repeat)
            results.append(r)
            print(
                f"{r['file']:40s} {r['sources']:7s} {r['messages']:7d} "
                f"{r['plain_msgs_per_s']:9.0f} {r['replay_msgs_per_s']:9.0f} "
                f"{r['ratio']:6.2f}  {r['outcome']}"
            )
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
