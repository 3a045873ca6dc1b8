"""Accuracy per log format: the same flights as a tlog, an ArduPilot .bin and a PX4 .ulg.

``python -m bench.accuracy.formats [--cases NAME ...] [--seeds N] [--jobs J] [--write-docs]``

Each run of an end-to-end case (:mod:`bench.accuracy.e2e`: the emitter's tlog of a gimbal
flight, its truth) is replayed three times through the product with the case's settings: the
tlog itself, and its DataFlash and ULog twins written by :mod:`sim.logwriters` (the gimbal's
attitude as ``MNT`` and ``gimbal_device_attitude_status``; a gimbal with its own clock logged
on the autopilot's, as an autopilot's logger stamps what it receives). Scored as the e2e
block: position RMS over the last third against the Cramér-Rao bound, pooled over the seeds,
with the spread of the per-seed ratios; a format agrees with the tlog when its ratio is
within that spread.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from bench.accuracy import blocks
from bench.accuracy.e2e import DOCS, pooled, run_one
from bench.accuracy.report import markdown_table

FORMATS = ("tlog", "bin", "ulg")
#: Gimbal cases (the bearing a DataFlash MNT and a ULog gimbal topic carry).
DEFAULT_CASES = ("gimbal_vehicle_fig8", "gimbal_earth_fig8", "yaw_60dps", "velocity_1hz")
BLOCK = "formats"


def _task(args: tuple[str, int, float, str]) -> dict[str, Any]:
    case, seed, duration_s, fmt = args
    r = run_one(case, seed, duration_s, log_format=fmt)
    r["format"] = fmt
    return r


def run(cases: Sequence[str], seeds: int, duration_s: float, jobs: int) -> dict[str, Any]:
    tasks = [(c, s, duration_s, f) for c in cases for s in range(seeds) for f in FORMATS]
    if jobs <= 1:
        results = [_task(t) for t in tasks]
    else:
        with ProcessPoolExecutor(jobs) as pool:
            results = list(pool.map(_task, tasks))
    out: dict[str, Any] = {}
    for c in cases:
        for f in FORMATS:
            runs = [r for r in results if r["case"] == c and r["format"] == f]
            p = pooled(runs)
            ratios = [r["ratio"] for r in runs]
            p["ratio_sd"] = float(np.std(ratios, ddof=1)) if len(ratios) > 1 else float("nan")
            p["replay_s"] = float(np.mean([r["replay_s"] for r in runs]))
            out[f"{c}/{f}"] = p
    return out


def markdown(res: dict[str, Any], cases: Sequence[str], seeds: int, wall_s: float) -> str:
    rows = []
    agree = 0
    for c in cases:
        base = res[f"{c}/tlog"]
        for f in FORMATS:
            p = res[f"{c}/{f}"]
            ok = abs(p["ratio"] - base["ratio"]) <= max(base["ratio_sd"], p["ratio_sd"])
            agree += f != "tlog" and ok
            rows.append(
                f"| {c} | {f} | {1000 * p['rms_m']:.1f} mm | {p['ratio']:.2f}x "
                f"(sd {p['ratio_sd']:.2f}) | {p['nees_axis']:.2f} | {p['range_bias_pct']:+.2f} % "
                f"| {100 * p['converged_share']:.0f} % "
                f"| {'-' if f == 'tlog' else ('yes' if ok else 'no')} |"
            )
    cols = ("case", "format", "position RMS, last third", "ratio to the bound (sd over seeds)",
            "NEES per axis", "range bias", "converged", "within the tlog's spread")  # fmt: skip
    head = (
        "## Accuracy per log format\n\n"
        f"`python -m bench.accuracy.formats --seeds {seeds} --write-docs` ({wall_s:.0f} s): each "
        "run of the end-to-end cases below replayed as its tlog, as the same flight's ArduPilot "
        "DataFlash `.bin` (`XKF1`, `ATT`, `MNT`, `POS`) and as its PX4 `.ulg` "
        "(`vehicle_local_position`, `vehicle_attitude`, `gimbal_device_attitude_status`), "
        "written by `python -m sim convert`; the case's settings; position RMS over the last "
        f"third against the Cramér-Rao bound, pooled over {seeds} seeds, with the standard "
        "deviation of the per-seed ratios. A format agrees with the tlog when the two ratios "
        "differ by at most the larger of their spreads.\n\n"
    )
    n = len(cases) * (len(FORMATS) - 1)
    return head + markdown_table(cols, rows) + f"\n\nWithin the tlog's spread: {agree} of {n}.\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.formats", description=__doc__)
    p.add_argument("--cases", nargs="+", default=list(DEFAULT_CASES))
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--duration", type=float, default=300.0)
    p.add_argument("--jobs", type=int, default=min(4, os.cpu_count() or 1))
    p.add_argument("--json", type=Path)
    p.add_argument("--write-docs", action="store_true")
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    res = run(args.cases, args.seeds, args.duration, args.jobs)
    wall = time.perf_counter() - t0
    text = markdown(res, args.cases, args.seeds, wall)
    print(text)
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    if args.write_docs:
        blocks.put_block(DOCS, BLOCK, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
