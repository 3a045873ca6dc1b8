"""What the compiled estimator costs a process: its compile on a machine's first run (an empty
numba cache), and its load from a warm cache at every start.

Run: ``python bench/compile_start.py`` (``--repeat N``, ``--json``).

* **compile**: ``python -c "...compiled.kernels()"`` with ``NUMBA_CACHE_DIR`` set to a new
  empty folder, so numba compiles every kernel (the in-tree cache is left alone), the whole
  process timed; ``--repeat`` runs, each with its own empty folder.
* **start-up**: the same with the warm cache, against ``python -c "import
  mav_observer.replay"`` (replay's own start-up without the estimator), whole processes,
  runs alternating, the best of ``--repeat`` of each: the difference is what loading the
  compiled estimator adds to a start.
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
LOAD = "import mav_observer.replay; from mav_observer.core import compiled; compiled.kernels()"
BASE = "import mav_observer.replay"


def _run(code: str, env: dict[str, str]) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, check=True,
                   capture_output=True)  # fmt: skip
    return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--compiles", type=int, default=1, help="cold compiles timed")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
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
