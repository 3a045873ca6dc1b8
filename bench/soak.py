"""Soak: the service for ten minutes at an accelerated rate with 1 % of fuzzed garbage.

Run: ``python bench/soak.py`` (about eleven minutes; ``--duration-s 60`` for a check).

What is measured, on the run of ``bench/service_memory.py`` (the service as its own process,
the emitter's orbit with gimbal bearings at 7 times the typical mix: about 1,900 messages/s,
1.15 million in 600 s) with one ``sim.fuzz`` frame (random bytes, bit flips, cut and
over-long frames, bad checksums, unknown ids, NaN and absurd fields) per hundred valid ones,
interleaved, and every estimate published (``--estimate-rate-hz 0``):

* the service is still running at the end, and counted every valid message;
* kernel drops on its socket, and what it skipped, by reason;
* resident memory growth (goal: under 5 MB);
* the largest gap between consecutive estimates, in the data's own time (the autopilot clock),
  against the input's own gap between bearings (goal: no longer);
* the final accuracy: position error (relative to the range) and bias error over the last
  600 estimates, against the truth, beside the same over a clean run: the same seeded stream
  without the garbage, fed to the tracker in this process (goal: as accurate).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import service_memory  # noqa: E402

from mav_observer.mavlink.dialect import codec  # noqa: E402
from mav_observer.tracking.tracker import Tracker  # noqa: E402
from sim import emitter, scenarios  # noqa: E402

FUZZ_SHARE = 0.01
GOAL_GROWTH_MB = 5.0


def _emitter(args: argparse.Namespace) -> emitter.Emitter:
    sim_s = args.duration_s * args.speed + 5.0
    return emitter.Emitter(
        scenarios.orbit(duration_s=sim_s),
        emitter.EmitterConfig(
            duration_s=sim_s,
            bearing="gimbal",
            bearing_noise_deg=0.5,
            seed=args.seed,
            **service_memory.MIX_HZ,
        ),
    )


def _truths(args: argparse.Namespace) -> dict[int, dict[str, Any]]:
    """The emitter's truth by bearing time (ms): the same seeded stream as the run's."""
    out = {}
    for e in _emitter(args).emissions():
        if e.truth is not None:
            out[round(e.truth["t_boot_s"] * 1000)] = e.truth
        if e.t_emit_s > args.duration_s * args.speed:
            break
    return out


def _errors(ests: list[dict[str, Any]], truths: dict[int, dict[str, Any]]) -> tuple[float, float]:
    """Largest relative position error and largest bias error (m/s) over ``ests``."""
    rel, bias = [], []
    for d in ests:
        t = truths.get(round(d["t_boot_s"] * 1000))
        if t is None:
            continue
        xt = t["rel_pos_ned_m"]
        rel.append(math.dist(d["rel_pos_ned_m"], xt) / math.hypot(*xt))
        bias.append(math.dist(d["bias_ned_mps"], t["bias_ned_mps"]))
    return (max(rel), max(bias)) if rel else (math.nan, math.nan)


def _clean_run(args: argparse.Namespace, n_last: int) -> list[dict[str, Any]]:
    """The same stream without garbage through the tracker here: its last estimates."""
    m = codec()
    m.robust_parsing = True
    tr = Tracker()
    last: list[dict[str, Any]] = []
    t_end = args.duration_s * args.speed
    for e in _emitter(args).emissions():
        if e.t_emit_s > t_end:
            break
        arrival = 1.8e9 + e.t_emit_s / args.speed
        for msg in m.parse_buffer(e.frame) or []:
            for r in tr.handle(arrival, msg):
                last.append(r.to_dict())
        if len(last) > 2 * n_last:
            del last[:-n_last]
    return last[-n_last:]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    service_memory.add_run_arguments(parser)
    args = parser.parse_args()
    args.estimate_rate_hz = 0.0
    print(
        f"soak: {args.duration_s:g} s at {args.speed:g} x the typical mix "
        f"(~{273 * args.speed:.0f} messages/s) with {100 * FUZZ_SHARE:g} % fuzz",
        flush=True,
    )
    r = service_memory.run(args, fuzz_share=FUZZ_SHARE)
    t_est = np.array(r.pop("estimate_t_boot_s"))
    ests = r.pop("last_estimates")
    gaps = np.diff(t_est[t_est >= t_est[0] + 5.0]) if len(t_est) > 2 else np.array([math.inf])
    truths = _truths(args)
    t_in = np.array(sorted(truths)) / 1000.0
    t_in = t_in[(t_in >= t_est[0]) & (t_in <= t_est[-1])]
    input_gap = float(np.diff(t_in).max())
    rel, bias = _errors(ests, truths)
    clean_rel, clean_bias = _errors(_clean_run(args, len(ests)), truths)
    out = {
        **r,
        "max_estimate_gap_s": float(gaps.max()),
        "input_bearing_gap_s": input_gap,
        "final_max_rel_pos_err": rel,
        "final_max_bias_err_mps": bias,
        "clean_max_rel_pos_err": clean_rel,
        "clean_max_bias_err_mps": clean_bias,
    }
    print(
        f"service alive at the end: {r['service_alive_at_end']}; sent {r['msgs_sent']:,} valid "
        f"+ {r['fuzz_sent']:,} garbage frames; counted {r['messages_counted']:,}; "
        f"kernel drops {r['udp_drops']}"
    )
    print("skipped by reason:", json.dumps(r["skipped"], sort_keys=True))
    print(
        f"RSS {r['start_rss_mb']:.2f} -> {r['end_rss_mb']:.2f} MB: growth {r['growth_mb']:.2f} MB "
        f"(goal < {GOAL_GROWTH_MB:g}); estimates received {r['estimates_received']:,}"
    )
    print(
        f"largest gap between estimates {1000 * out['max_estimate_gap_s']:.1f} ms of data time; "
        f"the input's own largest gap between bearings {1000 * input_gap:.1f} ms"
    )
    print(
        f"last {len(ests)} estimates: worst position error {100 * rel:.3f} % of range, bias "
        f"{bias:.4f} m/s; clean run: {100 * clean_rel:.3f} %, {clean_bias:.4f} m/s"
    )
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
