"""The target on the map on the shared SITL log: its published latitude, longitude and altitude
against the region of interest the simulated autopilot pointed its gimbal at.

``python -m bench.accuracy.geo [--gimbal-angles auto|flags|body ...]``

``ardupilot_sitl_servo_mount_roi.tlog`` (ArduCopter SITL, a servo mount pointed at a region of
interest 40 m north and 30 m east of home, on the ground) has the ROI's latitude and longitude
in the ``.json`` beside it. The log is replayed with the default settings (or the given
``TrackerConfig.gimbal_angles``) and every record over the last third of its estimates is
scored: the horizontal distance of ``target_lat_deg, target_lon_deg`` from the ROI (pymap3d),
its median, the vertical error's median, and the share of records whose horizontal error is
within twice their ``target_h_std_m``; and how many estimates say ``converged``, with that share
over every estimate from the first of them on ("after convergence" as the product declares it).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d

from mav_observer.app.replay import replay
from mav_observer.tracking.tracker import TrackerConfig
from sim.tlogs import find_tlogs

LOG = "ardupilot_sitl_servo_mount_roi.tlog"


def map_errors(recs: list[dict[str, Any]], lat_t: Any, lon_t: Any, alt_t: Any) -> dict[str, float]:
    """Records' ``target_lat_deg``, ``target_lon_deg``, ``target_alt_m`` against the true
    latitude, longitude and altitude (scalars or one per record): the median horizontal and
    vertical errors (m, pymap3d) and the share of records whose horizontal error is within
    twice their ``target_h_std_m``."""
    lat = np.array([r["target_lat_deg"] for r in recs])
    lon = np.array([r["target_lon_deg"] for r in recs])
    alt = np.array([r["target_alt_m"] for r in recs])
    h_std = np.array([r["target_h_std_m"] for r in recs], dtype=float)
    n, e, d = pymap3d.geodetic2ned(lat, lon, alt, lat_t, lon_t, alt_t)
    h = np.hypot(n, e)
    return {
        "h_median_m": float(np.median(h)),
        "v_median_m": float(np.median(np.abs(d))),
        "within_2sd": float(np.mean(h <= 2.0 * h_std)),
        "h_std_median_m": float(np.median(h_std)),
    }


def after_convergence(recs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The records from the first whose ``status`` is ``converged`` on (empty if none is):
    "after convergence" as the product declares it."""
    first = next((i for i, r in enumerate(recs) if r["status"] == "converged"), None)
    return [] if first is None else recs[first:]


def score_log(
    log: Path, meta: dict[str, Any], tracker: TrackerConfig, from_s: float | None = None
) -> dict[str, Any]:
    """Replay ``log`` and score its records against the ROI of ``meta``: those of the last
    third, or with ``from_s`` those from that boot time (s) on."""
    roi = (meta["roi_lat"], meta["roi_lon"], meta["home_alt_amsl_m"] + meta["roi_alt_rel_home_m"])
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "est.jsonl"
        summary = replay(str(log), tracker_config=tracker, output_jsonl=out)
        recs = [json.loads(x) for x in out.read_text().splitlines() if x.strip()]
    recs = [r for r in recs if r["target_lat_deg"] is not None]
    if not recs:
        return {"records": 0}
    t = np.array([r["t_boot_s"] for r in recs])
    last = t >= (t[0] + (t[-1] - t[0]) * 2.0 / 3.0 if from_s is None else from_s)
    sel = [r for r, k in zip(recs, last, strict=True) if k]
    after = after_convergence(recs)
    origin = None
    for ts in summary.targets.values():
        if ts.final is not None and ts.final.origin is not None:
            origin = ts.final.origin.source
    return {
        "records": len(recs),
        "scored": len(sel),
        **map_errors(sel, *roi),
        "converged_n": sum(r["status"] == "converged" for r in recs),
        "after_convergence_n": len(after),
        "within_2sd_after_convergence": map_errors(after, *roi)["within_2sd"] if after else None,
        "origin": origin,
        "events": dict(summary.events),
    }


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.geo", description=__doc__)
    p.add_argument(
        "--gimbal-angles",
        nargs="+",
        default=["auto", "flags", "body"],
        choices=["auto", "flags", "body"],
        help="TrackerConfig.gimbal_angles to run (default: auto, the default, flags and body)",
    )
    p.add_argument(
        "--from-s",
        type=float,
        default=None,
        help="score the records from this boot time (s) on instead of the last third "
        "(55: from when the SITL log's gimbal turns to its ROI)",
    )
    args = p.parse_args(argv)
    log = find_tlogs() / LOG
    if not log.is_file():
        p.error(f"no such log: {log}")
    meta = json.loads(log.with_suffix(".json").read_text())
    print("| gimbal_angles | records scored | horizontal error, median | vertical, median "
          "| within 2 target_h_std_m | target_h_std_m, median | estimates `converged` "
          "| within 2 sigma after convergence | origin from |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for ga in args.gimbal_angles:
        r = score_log(log, meta, TrackerConfig(gimbal_angles=ga), args.from_s)
        if not r["records"]:
            print(f"| {ga} | 0 | - | - | - | - | - | - | - |")
            continue
        w = r["within_2sd_after_convergence"]
        after = "never converged" if w is None else f"{100 * w:.0f} % of {r['after_convergence_n']}"
        print(
            f"| {ga} | {r['scored']} | {r['h_median_m']:.2f} m | {r['v_median_m']:.2f} m "
            f"| {100 * r['within_2sd']:.0f} % | {r['h_std_median_m']:.2f} m "
            f"| {r['converged_n']} of {r['records']} | {after} | {r['origin']} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
