"""Our estimate against the point-of-interest method: one ray from the gimbal to the ground.

``python -m bench.accuracy.poi [--cases NAME ...] [--seeds N] [--duration S]``

ArduPilot's answer to "where is the camera looking" intersects one ray from the gimbal with the
terrain, or with the home altitude when it has no terrain data. Ours needs no ground: it comes
from the bearings and the vehicle's motion. Both are scored here on the same emitter runs (the
e2e cases, default settings, through replay), over the last third, as horizontal errors (m):

* ours: the published target (``target_pos_ned_m``, the map's ``target_lat_deg``/``lon`` in
  the local frame) against the truth;
* the point of interest: each bearing (the truth's line of sight with the stream's noise, 0.5
  deg, seeded) from the vehicle's true position, intersected with the ground it assumes, the
  home altitude, in three worlds that differ only in where the ground is:

  - **on flat ground**: the target stands on the ground at home altitude (the method's own
    assumption);
  - **8 m above the ground**: the target is on a roof or a mast, the ground 8 m below it;
  - **over sloping ground**: the target stands on ground that rises 10 % from home (home is
    the local origin), so it is ``0.1 x`` its horizontal distance from home above the home
    altitude the method assumes.

Bearings that do not reach the ground (at or above the horizon) give no point of interest and
are counted.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from bench.accuracy import e2e
from sim.stream import perturb_bearings

WORLDS = (("on flat ground", 0.0, 0.0), ("8 m above the ground", 8.0, 0.0),
          ("over sloping ground (10 %)", 0.0, 0.1))  # fmt: skip


def point_of_interest(
    vehicle_ned_m: np.ndarray, los_ned: np.ndarray, ground_d_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Each ray ``vehicle + s los`` (s > 0) intersected with the plane ``d = ground_d_m``:
    the points (N, 3) and which rays reach it (N,)."""
    dz = ground_d_m - vehicle_ned_m[:, 2]
    ok = (los_ned[:, 2] > 1e-6) & (dz > 0.0)
    s = np.where(ok, dz / np.where(ok, los_ned[:, 2], 1.0), np.nan)
    return vehicle_ned_m + s[:, None] * los_ned, ok


def run(args: tuple[str, int, float]) -> dict[str, Any]:
    case, seed, duration_s = args
    with tempfile.TemporaryDirectory() as tmp:
        m = e2e.run_one(case, seed, duration_s, workdir=tmp, defaults=True, keep_records=True)
    records, truth = m["records"], m["truth"]
    tt = np.array([d["t_boot_s"] for d in truth])
    t0 = tt[0] + (tt[-1] - tt[0]) * (1.0 - e2e.STEADY_FRACTION)
    tr = [d for d in truth if d["t_boot_s"] >= t0]
    target = np.array([d["target_pos_ned_m"] for d in tr])
    vehicle = np.array([d["vehicle_pos_ned_m"] for d in tr])
    los = np.array([d["rel_pos_ned_m"] for d in tr])
    los = perturb_bearings(los / np.linalg.norm(los, axis=1, keepdims=True),
                           math.radians(e2e.CASES[case].bearing_deg),
                           np.random.default_rng(seed))  # fmt: skip
    out: dict[str, Any] = {"case": case, "seed": seed}
    recs = [r for r in records if r["t_boot_s"] >= t0 and r["target_pos_ned_m"] is not None]
    t = np.array([r["t_boot_s"] for r in recs])
    tp = np.array([r["target_pos_ned_m"] for r in recs])
    ti = np.column_stack([np.interp(t, tt, np.array([d["target_pos_ned_m"] for d in truth])[:, i])
                          for i in range(3)])  # fmt: skip
    out["ours"] = np.hypot(*(tp - ti)[:, :2].T)
    home_dist = np.hypot(target[:, 0], target[:, 1])  # home is the local origin
    for name, above_m, slope in WORLDS:
        ground = target[:, 2] + above_m + slope * home_dist  # home altitude, as D
        poi, ok = point_of_interest(vehicle, los, ground[0])
        err = np.hypot(*(poi - target)[:, :2].T)
        out[name] = err[ok]
        out[name + " missed"] = int(np.sum(~ok))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.poi", description=__doc__)
    p.add_argument("--cases", nargs="+", default=["gimbal_vehicle_fig8", "mount_status_orbit"],
                   choices=list(e2e.CASES))  # fmt: skip
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--duration", type=float, default=300.0)
    p.add_argument("--jobs", type=int, default=2)
    args = p.parse_args(argv)
    tasks = [(c, s, args.duration) for c in args.cases for s in range(args.seeds)]
    with ProcessPoolExecutor(args.jobs) as ex:
        res = list(ex.map(run, tasks))
    cols = ["ours", *(w[0] for w in WORLDS)]
    print("| case | " + " | ".join(f"{c}: median (95th percentile)" for c in cols) + " |")
    print("|---|" + "---|" * len(cols))
    for case in args.cases:
        rs = [r for r in res if r["case"] == case]
        cells = []
        for c in cols:
            v = np.concatenate([r[c] for r in rs])
            missed = sum(r.get(c + " missed", 0) for r in rs)
            extra = f", {missed} rays missed the ground" if missed else ""
            cells.append(f"{np.median(v):.2f} m ({np.percentile(v, 95):.2f} m){extra}")
        print(f"| {case} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
