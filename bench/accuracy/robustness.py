"""Field robustness: real logs with injected bearings, and the faults real links have.

``python -m bench.accuracy.robustness [--corpus DIR] [--seeds N] [--write-docs] [--json F]``

Every case is a real log through the product's replay with default settings, bearings and a
wind-like velocity error injected as :mod:`bench.accuracy.reallogs` does, scored against the
injected truth and the batch least-squares fit of the same data:

* the shared logs, each as recorded, and with a fault of a real link applied after the
  injection (:mod:`sim.tlog_faults`): a telemetry gap (LOCAL_POSITION_NED only, or every
  message), a simulator log at 4x speed, a sped-up log whose recorder stalls, bursty stamps;
* with ``--corpus DIR``, every ``.tlog`` of DIR as recorded (``DIR/manifest.json``, when
  there is one, says what each is and where it comes from).

Scores per case (over the seeds): the position RMS relative to the range over the last third
against its bar, ``max(2x the batch fit, 1 %)``; the share of the injected span with the error
above 5 % of the range after the first ``converged`` estimate (goal: at most 1 %); the worst
error over the published sigma (the 1-sigma radius, ``sqrt(trace P_xx)``) after it (goal: at
most 5) and the share of estimates outside twice it; ``replay --smooth`` over the whole span
against ``max(1.5x the batch fit, 1 %)``; the re-acquisitions.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.accuracy import blocks
from bench.accuracy.reallogs import run_log
from sim import tlog_faults
from sim.tlogs import find_tlogs

ROOT = Path(__file__).resolve().parents[2]
#: Where each public corpus log comes from (repository, path, commit, blob) and what it is.
CORPUS_MANIFEST = Path(__file__).with_name("corpus.json")
#: A batch fit further off than this (relative RMS, last third) has no geometry to hold the
#: product to: the vehicle parked, hovering or flying one straight line at a steady speed.
WEAK_GEOMETRY_REL = 0.05
LPN = "32"  # LOCAL_POSITION_NED's message id

#: (case, shared log, fault, what it stands for)
SHARED_CASES = (
    ("1 Hz real copter", "real_copter_bruno_mission_132614.tlog", "none",
     "real ArduCopter mission, LOCAL_POSITION_NED at 1 Hz"),
    ("1 Hz, 3.5 s position gap", "real_copter_bruno_mission_132614.tlog", f"gap:0.7:3.5:{LPN}",
     "the same, LOCAL_POSITION_NED lost for 3.5 s at 70 % of the flight (bearings go on)"),
    ("1 Hz, 12 s position gap", "real_copter_bruno_mission_132614.tlog", f"gap:0.8:12:{LPN}",
     "the same, LOCAL_POSITION_NED lost for 12 s at 80 % of the flight in a turn"),
    ("1 Hz, 30 s link loss", "real_copter_bruno_mission_132614.tlog", "gap:0.5:30",
     "the same, every message lost for 30 s"),
    ("1.2 Hz real copter", "real_copter_phoenix_m2.tlog", "none",
     "real ArduCopter (APM 3.5), 23 min, LOCAL_POSITION_NED at 1.2 Hz with gaps"),
    ("damaged real log", "bad_zeroholes_tsback_132613.tlog", "none",
     "real flight, two zero-filled holes, tlog stamps back by 500 s after each"),
    ("real ROV", "gimbal_ardusub_bluerov_small.tlog", "none",
     "real BlueROV2 (ArduSub), 3 Hz, a 2 m range"),
    ("simulator", "ardupilot_sitl_servo_mount_roi.tlog", "none",
     "ArduCopter simulator, 8 Hz, circle and landing"),
    ("simulator at 4x", "ardupilot_sitl_servo_mount_roi.tlog", "speed:4",
     "the same recorded at 4x speed: time_boot_ms advances 4 s per tlog second"),
    ("4x, recorder stall", "ardupilot_sitl_servo_mount_roi.tlog", "stall:4:0.3:20",
     "at 4x, the recorder stalls: 80 s of the autopilot's clock lost, the tlog's stamps do "
     "not advance across it"),
    ("bursty stamps", "ardupilot_sitl_servo_mount_roi.tlog", "burst:0.25",
     "records stamped in 250 ms bursts, 50 us apart within one"),
)  # fmt: skip

#: The corpus' target: ``--target auto`` moved this far north (m), off the track: a vertical
#: take-off and landing straight above it would see it along the line of sight only.
CORPUS_OFFSET_NED_M = (30.0, 0.0, 0.0)

RMS_BAR_BATCH, RMS_BAR_REL = 2.0, 0.01
SMOOTH_BAR_BATCH = 1.5
TIME_ABOVE_GOAL = 0.01
SIGMA_GOAL = 5.0


def cases(corpus: Path | None) -> list[dict[str, Any]]:
    """The shared cases whose log is there, then the corpus' logs."""
    shared = find_tlogs()
    out = [
        {"case": c, "log": shared / f, "fault": fault, "about": about}
        for c, f, fault, about in SHARED_CASES
        if (shared / f).exists()
    ]
    if corpus is not None:
        about = {}
        manifest = corpus / "manifest.json"
        if not manifest.exists():
            manifest = CORPUS_MANIFEST
        about = {d["file"]: d for d in json.loads(manifest.read_text())}
        for p in sorted(corpus.glob("*.tlog")):
            d = about.get(p.name, {})
            src = f"{d['repo']}: `{d['path']}` @ {d['commit'][:10]}" if "repo" in d else ""
            what = (d.get("note") or "").split(". ")[0].split(" (")[0].rstrip(".")
            src = f"{what} ({src})" if what and src else src
            out.append({"case": p.stem, "log": p, "fault": "none", "offset": CORPUS_OFFSET_NED_M,
                        "about": src or p.name})  # fmt: skip
    return out


def _resets(events: dict[str, int]) -> int:
    """The vehicle resets of a run: its autopilot's clock restarted (a telemetry gap is not)."""
    return sum(v for k, v in events.items() if k in ("autopilot_reboot", "autopilot_clock_jump"))


def summarise(
    case: dict[str, Any], runs: list[dict[str, Any]], clean_batch: float | None = None
) -> dict[str, Any]:
    """One row of the table from a case's runs (one per seed); ``clean_batch``: the batch
    fit's error on the same log without its fault (the flight's geometry), when it has one."""

    def mean(k: str) -> float:
        return sum(r[k] for r in runs) / len(runs)

    prod, batch = mean("product_rel_rms"), mean("batch_rel_rms")
    sm, ba = mean("smoothed_rel_rms_all"), mean("batch_rel_rms_all")
    ratios = [r["worst_sigma_ratio"] for r in runs if math.isfinite(r["worst_sigma_ratio"])]
    after = sum(r["after_convergence"] for r in runs)
    row = {
        "case": case["case"],
        "log": case["log"].name,
        "fault": case["fault"],
        "about": case["about"],
        "seeds": len(runs),
        "lpn_hz": runs[0]["lpn_hz"],
        "range_m": sum(r["range_last_third_m"] for r in runs) / len(runs),
        "product": prod,
        "product_worst": max(r["product_rel_rms"] for r in runs),
        # the spread of the mean over the seeds (its standard error)
        "product_se": _stderr([r["product_rel_rms"] for r in runs]),
        # the seeds whose own RMS is within the bar of their own batch fit
        "seeds_within": sum(
            r["product_rel_rms"] <= max(RMS_BAR_BATCH * r["batch_rel_rms"], RMS_BAR_REL)
            for r in runs
        ),
        "batch": batch,
        "bar": max(RMS_BAR_BATCH * batch, RMS_BAR_REL),
        "time_above": max(r["time_above_5pct_share"] for r in runs),
        "sigma_ratio": max(ratios) if ratios else math.nan,
        "uncovered": sum(r["uncovered"] for r in runs) / after if after else math.nan,
        "sigma_ratio_all": max(
            (r["worst_sigma_ratio_all"] for r in runs if math.isfinite(r["worst_sigma_ratio_all"])),
            default=math.nan,
        ),
        "smoothed": sm,
        "batch_all": ba,
        "smooth_bar": max(SMOOTH_BAR_BATCH * ba, RMS_BAR_REL),
        "reacquired": sum(r["reacquired"] for r in runs),
        "reacquiring_s": sum(r["reacquiring_s"] for r in runs),
        "resets": sum(_resets(r["events"]) for r in runs),
        "converged": after > 0,
    }
    row["weak"] = not (batch if clean_batch is None else clean_batch) <= WEAK_GEOMETRY_REL
    row["ok"] = {
        "rms": row["weak"] or prod <= row["bar"],
        "time": row["time_above"] <= TIME_ABOVE_GOAL,
        "sigma": not row["sigma_ratio"] > SIGMA_GOAL,
        "smooth": row["weak"] or row["smoothed"] <= row["smooth_bar"],
    }
    return row


def _stderr(xs: list[float]) -> float:
    """The standard error of the mean of ``xs`` (nan for fewer than two)."""
    if len(xs) < 2 or not all(math.isfinite(x) for x in xs):
        return math.nan
    m = sum(xs) / len(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1) / len(xs))


def _pct(x: float, digits: int = 2) -> str:
    return "-" if not math.isfinite(x) else f"{100 * x:.{digits}f} %"


def _num(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.1f}"


def _mark(ok: bool) -> str:
    return "" if ok else " ✗"


def markdown(rows: list[dict[str, Any]], *, seeds: int, wall_s: float, corpus: bool) -> str:
    cmd = "python -m bench.accuracy.robustness" + (" --corpus DIR" if corpus else "")
    lines = [
        "## Field robustness: real logs and the faults of real links",
        "",
        f"`{cmd} --seeds {seeds} --write-docs` ({wall_s:.0f} s): each case is a real log "
        "with the bearings and the (2, -1, 0) m/s velocity error of the block above injected, "
        "then a fault of a real link applied to the injected log (`sim/tlog_faults.py`), "
        "replayed with the default settings. Per case, over the seeds: the position RMS over "
        "the last third (the mean over the seeds ± its standard error; in brackets the worst "
        "seed, and how many seeds are within the bar of their own batch fit) against its bar "
        "`max(2x batch fit, 1 %)`, the batch fit's mean over the seeds: a log's figure is the "
        "mean, since one seed's error after convergence is close to one constant; the "
        "share of the span with the error above 5 % of the range after the first `converged` "
        "estimate (goal <= 1 %); the worst error over the published sigma (the 1-sigma radius "
        "`sqrt(trace P_xx)`) after it (goal <= 5) and the share of estimates outside twice "
        "it, and the worst error over sigma of every estimate (converged or not); "
        "`replay --smooth` over the whole span against `max(1.5x batch fit, 1 %)`; the "
        "re-acquisitions and the vehicle resets (clock jumps, reboots) over all seeds. ✗: a "
        "goal not met.",
        "",
        "The shared logs first, as recorded and with a fault; then the public corpus, each log "
        "as recorded, its target 30 m north of the `--target auto` point (off the track: a "
        "vertical take-off and landing straight above the target would see it along the line "
        "of sight only). `bench/accuracy/corpus.json` gives each corpus log's repository, "
        "path, commit and blob: `git clone https://github.com/REPO r && git -C r show "
        "COMMIT:PATH > DIR/FILE` rebuilds DIR.",
        "",
        "| case | what | LOCAL_POSITION_NED | range | product, last third (worst seed; seeds "
        "within their own bar) "
        "| bar | time above 5 % | worst error / sigma | outside 2 sigma | worst error / sigma, "
        "every estimate | smoothed "
        "| smoothing bar | re-acquired | resets |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ok = r["ok"]
        sr = r["sigma_ratio"]
        lines.append(
            f"| {r['case']} | {r['about']} | {r['lpn_hz']:.1f} Hz | {r['range_m']:.0f} m "
            f"| {_pct(r['product'])} ± {_pct(r['product_se'])}{_mark(ok['rms'])} "
            f"({_pct(r['product_worst'])}; {r['seeds_within']}/{r['seeds']}) "
            f"| {'weak geometry' if r['weak'] else _pct(r['bar'])} "
            f"| {_pct(r['time_above'], 1)}{_mark(ok['time'])} "
            f"| {'-' if not math.isfinite(sr) else f'{sr:.1f}'}{_mark(ok['sigma'])} "
            f"| {_pct(r['uncovered'], 1)} | {_num(r['sigma_ratio_all'])} "
            f"| {_pct(r['smoothed'])}{_mark(ok['smooth'])} "
            f"| {'-' if r['weak'] else _pct(r['smooth_bar'])} | {r['reacquired']} "
            f"| {r['resets']} |"
        )
    n = len(rows)
    weak = sum(r["weak"] for r in rows)
    met = {k: sum(r["ok"][k] for r in rows) for k in ("rms", "time", "sigma", "smooth")}
    lines += [
        "",
        f"Goals met on {met['rms'] - weak} of {n - weak} cases with a geometry (RMS), "
        f"{met['smooth'] - weak} of {n - weak} (smoothed), {met['time']} of {n} (time above "
        f"5 %), {met['sigma']} of {n} (error / sigma). `weak geometry`: the batch fit itself, "
        f"on the log without its fault, is off by more than {100 * WEAK_GEOMETRY_REL:.0f} % "
        "of the range (the vehicle parked, "
        "hovering, or flying one straight line at a steady speed, which no bearing-only "
        "method resolves with an unknown velocity bias): the RMS and smoothing bars do not "
        "apply; the sigma must still cover the error.",
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.robustness", description=__doc__)
    p.add_argument("--corpus", type=Path, help="a folder of public .tlog files (manifest.json)")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--only", help="cases whose name contains this")
    p.add_argument("--json", type=Path)
    p.add_argument("--write-docs", action="store_true", help="the block of docs/accuracy.md")
    args = p.parse_args(argv)
    todo = [c for c in cases(args.corpus) if not args.only or args.only in c["case"]]
    rows = []
    t0 = time.perf_counter()
    for c in todo:
        fault = tlog_faults.parse(c["fault"])
        off = c.get("offset")
        runs = [run_log(c["log"], seed=s, fault=fault, target_offset_ned_m=off)
                for s in range(args.seeds)]  # fmt: skip
        clean = None
        if c["fault"] != "none":  # the flight's geometry, judged without the fault
            clean = run_log(c["log"], seed=0, target_offset_ned_m=off)["batch_rel_rms"]
        row = summarise(c, runs, clean)
        rows.append(row)
        print(
            f"{row['case']}: product {_pct(row['product'])} (bar {_pct(row['bar'])}), "
            f"time above 5 % {_pct(row['time_above'], 1)}, error/sigma "
            f"{row['sigma_ratio']:.1f}, smoothed {_pct(row['smoothed'])}, "
            f"re-acquired {row['reacquired']}, resets {row['resets']}",
            file=sys.stderr,
        )
    wall = time.perf_counter() - t0
    text = markdown(rows, seeds=args.seeds, wall_s=wall, corpus=args.corpus is not None)
    print(text)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str))
    if args.write_docs:
        blocks.put_block(ROOT / "docs" / "accuracy.md", "robustness", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
