"""Accuracy with a rangefinder on the gimbal: its range fused with each bearing.

``python -m bench.accuracy.ranged [--seeds N] [--duration S] [--jobs J] [--write-docs]``

The end-to-end cases of :data:`bench.accuracy.e2e.RANGED` (the emitter's gimbal at 10 Hz,
0.5 deg, with a DISTANCE_SENSOR of 0.3 m noise from the gimbal's component; a hovering vehicle,
a figure-8, an orbit), replayed through the product with the noise told (``[observer]`` and
``tracker.range_noise_m``); scored as the e2e block against the Cramér-Rao bound with the range
included (:func:`bench.accuracy.core.crlb`, ``range_sigma_m``), plus the time from the first
bearing to the first ``converged`` estimate.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.accuracy import blocks
from bench.accuracy.e2e import DOCS, RANGED, run_cases, table

BLOCK = "range"


def markdown(res: dict[str, Any], seeds: int, duration_s: float, wall_s: float) -> str:
    rows = []
    for name, r in res.items():
        conv = np.array([run["first_converged_s"] for run in r["runs"]])
        p = r["pooled"]
        rows.append(
            f"| {name} | {p['ratio']:.2f}x ({p['worst_ratio']:.2f}x) | {p['nees_axis']:.2f} "
            f"| {np.median(conv):.1f} s / {np.max(conv):.1f} s |"
        )
    return "\n".join(
        [
            "## With a rangefinder on the gimbal",
            "",
            f"`python -m bench.accuracy.ranged --seeds {seeds} --write-docs` "
            f"({len(res) * seeds} runs of {duration_s:g} s, {wall_s:.0f} s): a 0.5 deg gimbal "
            "at 10 Hz and, with each bearing, a DISTANCE_SENSOR from the gimbal (0.3 m noise), "
            "replayed with the noise told; the bound is the Cramér-Rao bound with the range "
            "(every bearing's information plus `u u^T / sigma_r^2`). The hovering vehicle does "
            "not move at all: bearings alone could not tell its range.",
            "",
            table(res),
            "",
            "| case | ratio to the bound with range (worst seed) | NEES per axis "
            "| first `converged` after the first bearing: median / worst |",
            "|---|---|---|---|",
            *rows,
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.ranged", description=__doc__)
    p.add_argument("--seeds", type=int, default=16)
    p.add_argument("--duration", type=float, default=120.0)
    p.add_argument("--jobs", type=int, default=min(4, os.cpu_count() or 1))
    p.add_argument("--json", type=Path)
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    res = run_cases(list(RANGED), args.seeds, args.duration, args.jobs)
    wall = time.perf_counter() - t0
    text = markdown(res, args.seeds, args.duration, wall)
    print(text)
    if args.json:
        args.json.write_text(json.dumps(res, indent=1, default=str))
    if args.write_docs:
        blocks.put_block(DOCS, BLOCK, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
