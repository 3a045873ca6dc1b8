"""Replay throughput against a plain pymavlink loop, on real logs and emitter logs.

Run: ``python bench/replay_throughput.py`` (a few minutes; ``--quick`` skips the long log;
``--no-process`` the whole-process figures).

Two figures per file, each a ratio against its baseline measured in the same run:

* **whole processes** (start-up included): ``mav-observer replay LOG -o
  out.jsonl`` (as ``python -m mav_observer`` from this checkout) against ``python -c`` of the
  plain loop below, each a fresh interpreter, runs alternating, the best of ``--repeat``.
  Both run with byte-code caching on (an installed package has its byte code; this sandbox
  sets ``PYTHONDONTWRITEBYTECODE``, under which every one of our modules would be compiled at
  every start), after one untimed run of each. The
  start-up alone is reported too: ``python -c "import mav_observer.app.replay"`` against ``python
  -c "from pymavlink import mavutil"``, the floor of each side;
* **in this process** (the work alone):

For each file, messages of the file per second for:

* the plain loop: ``mavutil.mavlink_connection(path)`` then ``recv_match()`` until None (it
  decodes every message);
* the whole replay: ``mav-observer replay`` as a function, observers and an estimates JSON
  Lines file included (sources ``auto``; a log with no bearing stream ends in the "no usable
  bearing" error after reading the whole file, and is also timed with the synthetic ``home``
  source, which runs an observer on every LOCAL_POSITION_NED).

Runs alternate (plain, replay, plain, replay, ...) and each in-process figure is the median
of ``--repeat`` runs, because the machine's speed drifts. The emitter logs, generated once into
``bench/.cache/``: a dense 240 s figure-8 with a 25 Hz gimbal (position at 25 Hz, attitude
at 50 Hz), and (not with ``--quick``) an hour of the orbit scenario (gimbal at 10 Hz, attitude
at 20 Hz, position at 10 Hz) plus 100 messages/s of other telemetry.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mav_observer.app.replay import ReplayError, replay  # noqa: E402
from mav_observer.mavlink.dialect import connect  # noqa: E402
from mav_observer.tracking.tracker import TrackerConfig  # noqa: E402
from sim.tlogs import find_tlogs  # noqa: E402

TLOGS = find_tlogs()
CACHE = ROOT / "bench" / ".cache"
LONG = CACHE / "long_orbit_1h.tlog"
FIG8 = CACHE / "figure8_25hz_240s.tlog"
PLAIN_LOOP = (
    "import sys\n"
    "from pymavlink import mavutil\n"
    "c = mavutil.mavlink_connection(sys.argv[1])\n"
    "n = 0\n"
    "while c.recv_match() is not None:\n"
    "    n += 1\n"
)


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


def make_log(path: Path, what: str, emit_args: list[str]) -> None:
    """Generate the emitter log ``path`` once (``python -m sim emit ARGS --tlog path``)."""
    if path.exists():
        return
    CACHE.mkdir(parents=True, exist_ok=True)
    print(f"generating {path} ({what}) ...", flush=True)
    subprocess.run(
        [sys.executable, "-m", "sim", "emit", *emit_args, "--tlog", str(path)],
        cwd=ROOT,
        check=True,
        stdout=subprocess.DEVNULL,
    )


def make_long_log() -> None:
    make_log(
        LONG, "an hour of emitter traffic",
        ["--scenario", "orbit", "--bearing", "gimbal", "--duration", "3600",
         "--background-hz", "100", "--bearing-noise-deg", "0.5"],
    )  # fmt: skip


def make_fig8_log() -> None:
    make_log(
        FIG8, "a dense figure-8",
        ["--scenario", "figure8", "--bearing", "gimbal", "--duration", "240",
         "--bearing-hz", "25", "--position-hz", "25", "--attitude-hz", "50",
         "--bearing-noise-deg", "0.5", "--seed", "3"],
    )  # fmt: skip


def _env() -> dict[str, str]:
    """The environment of the timed processes: byte-code caching on (see the docstring)."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _wall(cmd: list[str]) -> float:
    """Wall time (s) of ``cmd`` run to its end; exit 3 (a log with no bearing stream, read
    to its end) counts as done, any other failure stops the bench."""
    t0 = time.perf_counter()
    done = subprocess.run(
        cmd, check=False, cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    if done.returncode not in (0, 3):
        raise RuntimeError(f"{cmd} exited {done.returncode}: {done.stderr.decode()[-500:]}")
    return wall


def _cli() -> list[str]:
    """``mav-observer`` as ``python -m mav_observer`` run from this checkout (its own
    package first on the path: the code measured is this checkout's)."""
    return [sys.executable, "-m", "mav_observer"]


def measure_process(path: Path, repeat: int) -> dict[str, object]:
    """Whole processes, best of ``repeat`` alternating runs after one untimed run of each."""
    with tempfile.TemporaryDirectory() as tmp:
        plain_cmd = [sys.executable, "-c", PLAIN_LOOP, str(path)]
        replay_cmd = [*_cli(), "replay", str(path), "-o", str(Path(tmp) / "out.jsonl")]
        _wall(plain_cmd), _wall(replay_cmd)
        plain, rep = [], []
        for _ in range(repeat):
            plain.append(_wall(plain_cmd))
            rep.append(_wall(replay_cmd))
    p, r = min(plain), min(rep)
    return {"file": path.name, "plain_s": p, "replay_s": r, "ratio": p / r}


def measure_startup(repeat: int) -> dict[str, float]:
    """The floor of each side: a fresh interpreter importing what it needs, best of
    ``repeat`` alternating runs."""
    ours = [sys.executable, "-c", "import mav_observer.app.replay"]
    theirs = [sys.executable, "-c", "from pymavlink import mavutil"]
    bare = [sys.executable, "-c", "pass"]
    for cmd in (ours, theirs, bare):
        _wall(cmd)
    o, t, b = [], [], []
    for _ in range(repeat):
        o.append(_wall(ours))
        t.append(_wall(theirs))
        b.append(_wall(bare))
    return {"replay_import_s": min(o), "mavutil_import_s": min(t), "python_s": min(b)}


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
    parser.add_argument("--quick", action="store_true", help="no hour-long emitter log")
    parser.add_argument("--no-process", action="store_true", help="skip the whole-process figures")
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    args = parser.parse_args()
    files = sorted(TLOGS.glob("*.tlog"))
    make_fig8_log()
    files.append(FIG8)
    if not args.quick:
        make_long_log()
        files.append(LONG)
    results: dict[str, object] = {"in_process": [], "process": [], "startup": None}
    if not args.no_process:
        print("whole processes (start-up included), best of", args.repeat, "alternating runs")
        print(f"{'file':40s} {'plain_s':>8s} {'replay_s':>8s} {'ratio':>6s}")
        for f in files:
            r = measure_process(f, args.repeat)
            results["process"].append(r)  # type: ignore[attr-defined]
            print(f"{r['file']:40s} {r['plain_s']:8.3f} {r['replay_s']:8.3f} {r['ratio']:6.2f}")
        st = measure_startup(args.repeat)
        results["startup"] = st
        print(
            f"start-up: python alone {st['python_s']:.3f} s; import mav_observer.app.replay "
            f"{st['replay_import_s']:.3f} s; import pymavlink.mavutil "
            f"{st['mavutil_import_s']:.3f} s"
        )
        print()
    print("in this process, median of", args.repeat, "alternating runs")
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
            results["in_process"].append(r)  # type: ignore[attr-defined]
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
