"""What the compiled estimator costs a process: its compile on a machine's first run (an empty
numba cache), and its load from a warm cache at every start.

Run: ``python bench/compile_start.py`` (``--repeat N``, ``--json``).

* **compile**: ``python -c "...compiled.kernels()"`` with ``NUMBA_CACHE_DIR`` set to a new
  empty folder, so numba compiles every kernel (the in-tree cache is left alone), the whole
  process timed; ``--repeat`` runs, each with its own empty folder.
* **start-up**: the same with the warm cache, against ``python -c "import
  mav_observer.app.replay"`` (replay's own start-up without the estimator), whole processes,
  runs alternating, the best of ``--repeat`` of each: the difference is what loading the
  compiled estimator adds to a start.

``--profile``: one compile in this process with an empty cache, and the seconds spent in each
compiled function, its callees' compiles excluded (numba's compile events).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOAD = "import mav_observer.app.replay; from mav_observer.core import compiled; compiled.kernels()"
BASE = "import mav_observer.app.replay"


def _run(code: str, env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, check=True,
                   capture_output=True)  # fmt: skip
    return time.perf_counter() - t0


def profile(top: int = 12) -> list[tuple[str, int, float]]:
    """Compile the kernels in this process into an empty cache: ``(function, signatures,
    seconds)`` by the time spent in each, callees excluded, the most first."""
    with tempfile.TemporaryDirectory() as cache:
        os.environ["NUMBA_CACHE_DIR"] = cache
        from numba.core import event

        stack: list[list[float]] = []
        spent: dict[str, list[float]] = {}

        class Listener(event.Listener):
            def on_start(self, ev: event.Event) -> None:
                stack.append([time.perf_counter(), 0.0])

            def on_end(self, ev: event.Event) -> None:
                t0, children = stack.pop()
                f = ev.data["dispatcher"].py_func
                name = f"{f.__module__.rsplit('.', 1)[-1]}.{f.__name__}"
                took = time.perf_counter() - t0
                spent.setdefault(name, []).append(took - children)
                if stack:
                    stack[-1][1] += took

        event.register("numba:compile", Listener())
        sys.path.insert(0, str(ROOT))
        from mav_observer.core import compiled

        compiled.kernels()
    rows = sorted(((k, len(v), sum(v)) for k, v in spent.items()), key=lambda r: -r[2])
    rest = rows[top:]
    return [*rows[:top], ("(the others)", sum(r[1] for r in rest), sum(r[2] for r in rest))]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--compiles", type=int, default=1, help="cold compiles timed")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--profile", action="store_true", help="where the compile goes")
    args = parser.parse_args()
    if args.profile:
        rows = profile()
        print(f"{'function':40s} {'signatures':>10s} {'seconds':>8s}")
        for name, count, secs in rows:
            print(f"{name:40s} {count:10d} {secs:8.2f}")
        print(f"{'total':40s} {'':10s} {sum(r[2] for r in rows):8.2f}")
        return 0
    if args.repeat < 1 or args.compiles < 1:
        parser.error("--repeat and --compiles must be at least 1")
    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)
    _run(LOAD, env)  # the warm cache made (or checked)
    compiles = []
    for _ in range(args.compiles):
        with tempfile.TemporaryDirectory() as cache:
            compiles.append(_run(LOAD, dict(env, NUMBA_CACHE_DIR=cache)))
    warm, base = [], []
    for _ in range(args.repeat):
        base.append(_run(BASE, env))
        warm.append(_run(LOAD, env))
    out = {
        "compile_s": min(compiles),
        "start_with_estimator_s": min(warm),
        "start_without_s": min(base),
        "estimator_load_s": min(warm) - min(base),
        "cpus": os.cpu_count(),
    }
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"first run on a machine (empty cache), compile, whole process: {out['compile_s']:.1f} s "
          f"(best of {args.compiles}; {out['cpus']} cores)")  # fmt: skip
    print(f"start-up with a warm cache: {out['start_with_estimator_s']:.3f} s against "
          f"{out['start_without_s']:.3f} s without the estimator: +{out['estimator_load_s']:.3f} s "
          f"(best of {args.repeat} alternating)")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
