"""Real flight logs with synthetic bearings: the product against the offline optimum.

``python -m bench.accuracy.reallogs [LOG.tlog ...] [--seeds N] [--noise-deg D]
[--vel-error N,E,D] [--settings FILE] [--json F]``

For every log (default: every shared log in ``../shared/tlogs`` with LOCAL_POSITION_NED):

1. ``sim.inject`` adds a gimbal bearing stream toward a fixed point of the autopilot's local
   frame (``--target auto``: under the middle of the flight, 2 m below its lowest point), with
   isotropic noise and a wind-like error added to LOCAL_POSITION_NED's velocity, and writes
   the truth;
2. the product replays the new log (:func:`mav_observer.app.replay.replay`, default settings unless
   ``--settings`` names a settings file's ``[observer]`` table);
3. the same bearings and the log's own LOCAL_POSITION_NED go to the batch least-squares fit
   over the whole log (:func:`mav_observer.core.batch_fit.fit_batch`, told the true noise): the best
   the data allows;
4. both are scored against the truth over the last third of the injected span: position RMS
   relative to the range (RMS of ``|error| / range``), and the ratio of the two.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.accuracy import blocks
from bench.accuracy.report import markdown_table
from mav_observer.app import reference
from mav_observer.app.replay import ReplayError, replay
from mav_observer.core.batch_fit import NotObservableError, displacement_at, fit_batch
from mav_observer.core.observer import ObserverConfig
from mav_observer.tracking.tracker import TrackerConfig
from sim import inject as inj
from sim.tlogs import find_tlogs

ROOT = Path(__file__).resolve().parents[2]


def shared_logs() -> list[Path]:
    """Every shared log with LOCAL_POSITION_NED (the others cannot carry an injection)."""
    out = []
    for p in sorted(find_tlogs().glob("*.tlog")):
        recs = inj.split_records(p.read_bytes())
        if inj.vehicles_with_local_position(recs):
            out.append(p)
    return out


def _last_third(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    return t >= t0 + 2.0 * (t1 - t0) / 3.0


def _shared_times(t_s: np.ndarray, tt: np.ndarray) -> int:
    """How many of the times ``t_s`` (s) are truth times ``tt`` (to the ms)."""
    return len(np.intersect1d(np.round(t_s, 3), np.round(tt, 3)))


def epoch_records(est: list[dict[str, Any]], tt: np.ndarray) -> list[dict[str, Any]]:
    """The target's estimate records of the truth's epoch: a log whose autopilot clock
    restarts has records of several epochs whose times overlap (the records are in log
    order; a time going back by more than :data:`sim.inject.REBOOT_BACK_S` starts the next),
    and the epoch scored is the one whose times are the truth's."""
    segments: list[list[dict[str, Any]]] = []
    last = -math.inf
    for r in est:
        if not segments or r["t_boot_s"] < last - inj.REBOOT_BACK_S:
            segments.append([])
        segments[-1].append(r)
        last = r["t_boot_s"]
    if not segments:
        return []
    return max(segments, key=lambda seg: _shared_times(np.array([r["t_boot_s"] for r in seg]), tt))


def injected(
    log: Path,
    *,
    seed: int,
    noise_deg: float,
    vel_error: tuple[float, float, float],
    target_offset_ned_m: tuple[float, float, float] | None = None,
) -> inj.InjectResult:
    """``log`` with the bench's bearing stream injected (``--target auto``, moved by
    ``target_offset_ned_m``): a log with a gimbal of its own gets it as a second gimbal
    device."""
    records = inj.split_records(log.read_bytes())
    probe = inj.InjectConfig(target_ned_m=None, noise_deg=noise_deg, seed=seed)
    sysid = max(inj.vehicles_with_local_position(records).items(), key=lambda kv: kv[1])[0][0]
    dev = 2 if inj.same_target_frames(records, sysid, probe) else 1
    target = None
    if target_offset_ned_m is not None:
        auto = inj.auto_target(inj.read_flight(records, sysid=sysid))
        target = tuple(float(v) for v in auto + np.asarray(target_offset_ned_m))
    cfg = inj.InjectConfig(
        target_ned_m=target,
        noise_deg=noise_deg,
        vel_error_ned_mps=vel_error,
        seed=seed,
        gimbal_device_id=dev,
    )
    return inj.inject(records, cfg)


def run_log(
    log: Path,
    *,
    seed: int = 0,
    noise_deg: float = 0.5,
    vel_error: tuple[float, float, float] = (2.0, -1.0, 0.0),
    observer: dict[str, Any] | None = None,
    workdir: Path | None = None,
    live: bool = False,
    fault: Callable[[list[bytes]], list[bytes]] | None = None,
    target_offset_ned_m: tuple[float, float, float] | None = None,
) -> dict[str, Any]:
    """Inject, replay, fit and score one log (``live``: ``replay --live``, what the service
    publishes, instead of replay's default; ``fault``: applied to the injected log's records,
    :mod:`sim.tlog_faults`)."""
    res = injected(log, seed=seed, noise_deg=noise_deg, vel_error=vel_error,
                   target_offset_ned_m=target_offset_ned_m)  # fmt: skip
    if fault is not None:
        res.records[:] = fault(res.records)
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        path = Path(tmp) / "injected.tlog"
        path.write_bytes(b"".join(res.records))
        out = Path(tmp) / "est.jsonl"
        t_wall = time.perf_counter()
        tc = TrackerConfig(observer=ObserverConfig(**(observer or {})))
        summary = None
        try:
            summary = replay(str(path), tracker_config=tc, output_jsonl=out, smooth=True, live=live)
            events = dict(summary.events)
        except ReplayError as exc:
            events = {"replay_error": str(exc)}
        replay_s = time.perf_counter() - t_wall
        est = [json.loads(x) for x in out.read_text().splitlines() if x.strip()]
        flight = inj.read_flight(inj.split_records(path.read_bytes()), sysid=res.sysid)
    est = [r for r in est if r["sysid"] == res.sysid and r["target"] == res.target]
    truth = res.truth
    # the epoch with most bearings (a log whose clock restarts has several)
    epochs = [d.get("epoch", 0) for d in truth]
    ep = max(set(epochs), key=epochs.count)
    truth = [d for d in truth if d.get("epoch", 0) == ep]
    tt = np.array([d["t_boot_s"] for d in truth])
    xt = np.array([d["rel_pos_ned_m"] for d in truth])
    yt = np.array([d["bearing_ned"] for d in truth])
    t0, t1 = float(tt[0]), float(tt[-1])
    sel_t = _last_third(tt, t0, t1)
    rng_t = np.linalg.norm(xt, axis=1)

    # the product
    est = epoch_records(est, tt)
    te = np.array([r["t_boot_s"] for r in est]) if est else np.zeros(0)
    inside = (te >= t0) & (te <= t1)
    te = te[inside]
    xe = np.array([r["rel_pos_ned_m"] for r in est], dtype=float).reshape(-1, 3)[inside]
    xi = np.column_stack([np.interp(te, tt, xt[:, i]) for i in range(3)])
    rel = np.linalg.norm(xe - xi, axis=1) / np.linalg.norm(xi, axis=1)
    sel_e = _last_third(te, t0, t1)
    prod = math.sqrt(float(np.mean(rel[sel_e] ** 2))) if sel_e.any() else math.inf
    prod_max = float(np.max(rel[sel_e])) if sel_e.any() else math.inf
    # the sigma's honesty: the target's horizontal error (``target_pos_ned_m``, the map's
    # position in the local frame, against the injected point) within twice the published
    # ``target_h_std_m``, over the last third and from the first ``converged`` on. (The
    # relative position ``rel_pos_ned_m`` also carries the vehicle's path between two
    # LOCAL_POSITION_NED samples, which the truth draws as a straight line and the product as
    # the velocity's shape: a few cm on the 1 Hz logs that cancel in the target's position.)
    nan3 = [math.nan] * 3
    tgt_e = np.array([r["target_pos_ned_m"] or nan3 for r in est], dtype=float).reshape(-1, 3)
    sd_h = np.array(  # target_h_std_m's value, also where the map's origin is not known
        [math.nan if r["rel_pos_std_ned_m"] is None else math.hypot(*r["rel_pos_std_ned_m"][:2])
         for r in est],
        dtype=float,
    ).reshape(-1)[inside]  # fmt: skip
    truth_tgt = np.array([d.get("target_pos_ned_m", res.target_ned_m) for d in truth], float)
    tgt_t = np.column_stack([np.interp(te, tt, truth_tgt[:, i]) for i in range(3)])
    # (the truth's target in the local frame of each time: it moves with a frame reset)
    err_h = np.hypot(*(tgt_e[inside] - tgt_t)[:, :2].T)
    within = err_h <= 2.0 * sd_h  # (an estimate without a target position counts as outside)
    status = np.array([r["status"] for r in est])[inside]
    conv = np.nonzero(status == "converged")[0]
    # after the first convergence: the target position's error over its published sigma (the
    # 1-sigma radius; the target's, not the relative position's, for the reason above) and
    # the time above 5 % of the range, as the replay's --truth summary counts them
    sd3 = np.array(
        [math.nan if r["rel_pos_std_ned_m"] is None else math.hypot(*r["rel_pos_std_ned_m"])
         for r in est],
        dtype=float,
    ).reshape(-1)[inside]  # fmt: skip
    hon = reference.honesty({
        "t_boot_s": te, "pos_err_m": np.linalg.norm(tgt_e[inside] - tgt_t, axis=1),
        "pos_sigma_m": sd3,
        "converged": np.array([r["status"] for r in est])[inside] == "converged",
        "range_true_m": np.linalg.norm(xi, axis=1),
    })  # fmt: skip
    with np.errstate(invalid="ignore", divide="ignore"):
        hon_all = np.linalg.norm(tgt_e[inside] - tgt_t, axis=1) / sd3
    within_last = float(np.mean(within[sel_e])) if sel_e.any() else math.nan
    within_conv = float(np.mean(within[conv[0] :])) if len(conv) else math.nan

    # the batch optimum over the same bearings and velocity
    lpn = flight.local_position[ep]
    d = displacement_at(tt, lpn.t_boot_s, lpn.values[:, 3:6], lpn.values[:, :3])
    try:
        fit = fit_batch(tt, yt, d, sigma_rad=math.radians(max(noise_deg, 0.01)))
    except NotObservableError:  # too little motion for the batch fit too: no reference
        batch = batch_all = math.inf
    else:
        rel_b = np.linalg.norm(fit.rel_pos_at() - xt, axis=1) / rng_t
        batch = math.sqrt(float(np.mean(rel_b[sel_t] ** 2)))
        batch_all = math.sqrt(float(np.mean(rel_b**2)))
    # the product's smoother (replay --smooth) over the whole injected span
    smoothed = math.inf
    # (of the truth's epoch: the replay's key of each epoch after the first ends in #k)
    key = f"{res.sysid}/{res.target}"
    tracks = [] if summary is None else [
        v for k, v in summary.smoothed.items() if k == key or k.startswith(key + "#")
    ]  # fmt: skip
    sm = max(tracks, key=lambda v: _shared_times(v.t_s, tt), default=None)
    if sm is not None:
        ok = (sm.t_s >= t0) & (sm.t_s <= t1) & (sm.window >= 0)
        if ok.any():
            xs = sm.rel_pos_ned_m[ok]
            xi_s = np.column_stack([np.interp(sm.t_s[ok], tt, xt[:, i]) for i in range(3)])
            rel_s = np.linalg.norm(xs - xi_s, axis=1) / np.linalg.norm(xi_s, axis=1)
            smoothed = math.sqrt(float(np.mean(rel_s**2)))
    return {
        "log": log.name,
        "seed": seed,
        "sysid": res.sysid,
        "target": res.target,
        "injected": res.injected,
        "lpn_hz": res.lpn_rate_hz,
        "range_m": [float(np.min(rng_t)), float(np.max(rng_t))],
        "range_last_third_m": float(np.mean(rng_t[sel_t])),
        "product_rel_rms": prod,
        "product_rel_max": prod_max,
        "within_2sd_last_third": within_last,
        "within_2sd_conv": within_conv,
        "conv_n": int(len(within) - conv[0]) if len(conv) else 0,
        "converged_share": float(np.mean(status == "converged")) if len(status) else 0.0,
        "worst_sigma_ratio": hon["worst_sigma_ratio"],
        # from the first estimate on, converged or not (a flight without the geometry for it)
        "worst_sigma_ratio_all": float(np.nanmax(hon_all))
        if np.isfinite(hon_all).any()
        else math.nan,
        "uncovered": hon["uncovered"],
        "after_convergence": hon["after_convergence"],
        "time_above_5pct_share": hon["time_above_s"] / (t1 - t0) if t1 > t0 else 0.0,
        "batch_rel_rms": batch,
        "ratio": prod / batch if batch > 0 else math.inf,
        "smoothed_rel_rms_all": smoothed,
        "batch_rel_rms_all": batch_all,
        "estimates": len(est),
        # the scored target's own (the log's own gimbal, another target, may re-acquire too)
        "reacquired": _noise_of(summary, key, "reacquisitions"),
        "reacquiring_s": _noise_of(summary, key, "reacquiring_s"),
        "events": events,
        "skipped": {} if summary is None else dict(summary.skipped),
        "replay_s": replay_s,
    }


def _noise_of(summary: Any, key: str, name: str) -> float:
    """A field of target ``key``'s noise summary (0 without one)."""
    ts = None if summary is None else summary.targets.get(key)
    noise = None if ts is None else ts.noise
    return 0 if noise is None else getattr(noise, name)


def table(rows: list[dict[str, Any]]) -> str:
    lines = []
    for r in rows:
        lines.append(
            f"| {r['log']} (seed {r['seed']}) | {r['lpn_hz']:.1f} Hz "
            f"| {r['range_last_third_m']:.1f} m | {100 * r['product_rel_rms']:.2f} % "
            f"| {100 * r['batch_rel_rms']:.2f} % | {r['ratio']:.2f}x "
            f"| {100 * r['product_rel_max']:.1f} % |"
        )
    columns = (
        "log",
        "LPN rate",
        "range (last third)",
        "product: position RMS / range",
        "batch least squares",
        "product / batch",
        "worst, last third",
    )
    return markdown_table(columns, lines)


def summary_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per log over its seeds: mean of the product's and the batch's relative RMS, the worst."""
    out = []
    for log in dict.fromkeys(r["log"] for r in rows):
        rs = [r for r in rows if r["log"] == log]
        p = float(np.mean([r["product_rel_rms"] for r in rs]))
        b = float(np.mean([r["batch_rel_rms"] for r in rs]))
        sm = float(np.mean([r["smoothed_rel_rms_all"] for r in rs]))
        ba = float(np.mean([r["batch_rel_rms_all"] for r in rs]))
        conv_n = sum(r["conv_n"] for r in rs)
        out.append(
            {
                "log": log,
                "seeds": len(rs),
                "within_last": float(np.nanmean([r["within_2sd_last_third"] for r in rs])),
                "within_conv": (
                    sum(r["within_2sd_conv"] * r["conv_n"] for r in rs if r["conv_n"]) / conv_n
                    if conv_n
                    else math.nan
                ),
                "conv_share": float(np.mean([r["converged_share"] for r in rs])),
                "lpn_hz": rs[0]["lpn_hz"],
                "range_m": rs[0]["range_last_third_m"],
                "product": p,
                "product_worst": max(r["product_rel_rms"] for r in rs),
                "batch": b,
                "ratio": p / b if b > 0 else math.inf,
                "max": max(r["product_rel_max"] for r in rs),
                "smoothed_all": sm,
                "batch_all": ba,
                "smoothed_ratio": sm / ba if ba > 0 else math.inf,
            }
        )
    return out


def _share(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.0f} %"


#: What the logs given on the command line are, by default (``--about``).
OTHER_LOGS = "Logs not in the shared set, given on the command line"


def markdown(
    rows: list[dict[str, Any]],
    *,
    noise_deg: float,
    vel: tuple[float, ...],
    wall_s: float,
    other: str | None = None,
) -> str:
    """The real-logs block; ``other``: what the logs are when they are not the shared ones
    (the block of logs given on the command line)."""
    s = summary_rows(rows)
    seeds = s[0]["seeds"] if s else 0
    if other is None:
        head = "## Real flight logs with injected bearings"
        what = (
            f"Every shared log with LOCAL_POSITION_NED (`python -m bench.accuracy.reallogs "
            f"--seeds {seeds} --write-docs`, {wall_s:.0f} s)"
        )
    else:
        head = "### Real logs not in the shared set"
        what = (
            f"{other} (`python -m bench.accuracy.reallogs LOG ... --seeds {seeds} "
            f"--write-docs --about ...`, {wall_s:.0f} s)"
        )
    lines = [
        head,
        "",
        f"{what}: `python -m sim inject` adds a {noise_deg:g} "
        "deg, 10 Hz gimbal bearing (yaw in the vehicle frame, from the autopilot's component) "
        "toward a point 2 m below the flight's lowest point under its middle, and a wind-like "
        f"error of {tuple(vel)} m/s on the log's velocity (positions untouched). The product "
        "replays it with the **default settings** (each bearing's estimate published once the "
        "velocity after it is known, replay's default; the service's live ones: "
        "[estimator.md](estimator.md#what-a-live-estimator-can-do-on-the-sparse-logs)); the "
        "batch least-squares fit of `x0` and a "
        "constant `a` over the whole log (`mav_observer.core.batch_fit`, told the true noise, "
        "the same "
        "velocity and positions) is the offline reference. Position RMS relative to the range "
        "(RMS of `|error| / range`) over the last third of the injected span, mean over seeds. "
        "Then `replay --smooth` (batch fits on windows, the product's "
        "post-flight answer) against the batch fit, both over the whole injected span. The "
        "last columns: the sigma's honesty, the share of the product's estimates whose "
        "target position is horizontally within twice `target_h_std_m` of the injected point "
        "(about 95 % for an honest sigma), "
        "over the last third and from the first estimate `converged` on (pooled over the "
        "seeds), and the share of estimates `converged`.",
        "",
        "| log | LOCAL_POSITION_NED | range, last third | product (worst seed) | batch least "
        "squares | product / batch | worst single error, last third | smoothed, whole span "
        "| batch, whole span | smoothed / batch | within 2 sigma, last third | within 2 sigma, "
        "after convergence | converged |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in s:
        lines.append(
            f"| {r['log']} | {r['lpn_hz']:.1f} Hz | {r['range_m']:.0f} m "
            f"| {100 * r['product']:.2f} % ({100 * r['product_worst']:.2f} %) "
            f"| {100 * r['batch']:.2f} % | {r['ratio']:.2f}x | {100 * r['max']:.1f} % "
            f"| {100 * r['smoothed_all']:.2f} % | {100 * r['batch_all']:.2f} % "
            f"| {r['smoothed_ratio']:.2f}x | {_share(r['within_last'])} "
            f"| {_share(r['within_conv'])} | {100 * r['conv_share']:.0f} % |"
        )
    if other is None:
        lines += [
            "",
            "The injected target stands still in the world: where a log's local frame resets "
            "(the Phoenix log lands and takes a new origin at 827 s), its local coordinates "
            "move with the frame (`python -m sim inject`, [cli.md](cli.md)); the product and "
            "the batch fit both find the reset in the positions.",
        ]
    else:
        lines += [
            "",
            "Where a log is outside the bar (2x the batch fit or 1 % of the range), why: "
            '[estimator.md](estimator.md), "Real logs not in the shared set".',
        ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.reallogs", description=__doc__)
    p.add_argument("logs", nargs="*", type=Path, help="default: the shared logs with LPN")
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--noise-deg", type=float, default=0.5)
    p.add_argument("--vel-error", default="2,-1,0", help="N,E,D m/s added to the velocity")
    p.add_argument("--settings", type=Path, help="a settings file: its [observer] table")
    p.add_argument("--json", type=Path)
    p.add_argument("--write-docs", action="store_true", help="the block of docs/accuracy.md")
    p.add_argument(
        "--about",
        default=OTHER_LOGS,
        help="with LOG ... and --write-docs: what those logs are (where they come from)",
    )
    args = p.parse_args(argv)
    logs = args.logs or shared_logs()
    vel = tuple(float(v) for v in args.vel_error.split(","))
    observer = None
    if args.settings:
        observer = tomllib.loads(args.settings.read_text()).get("observer", {})
    rows = []
    t0 = time.perf_counter()
    for log in logs:
        for seed in range(args.seeds):
            r = run_log(log, seed=seed, noise_deg=args.noise_deg, vel_error=vel, observer=observer)
            rows.append(r)
            print(
                f"{log.name} seed {seed}: product {100 * r['product_rel_rms']:.2f} % of range, "
                f"batch {100 * r['batch_rel_rms']:.2f} %, events {r['events']}",
                file=sys.stderr,
            )
    wall = time.perf_counter() - t0
    print(table(rows))
    print(f"{len(rows)} runs in {wall:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if args.write_docs:
        other = args.about if args.logs else None
        text = markdown(rows, noise_deg=args.noise_deg, vel=vel, wall_s=wall, other=other)
        name = "real-logs-other" if args.logs else "real-logs"
        blocks.put_block(ROOT / "docs" / "accuracy.md", name, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
