"""Microseconds per observer update, against one ``numpy.linalg.inv`` of a 3x3.

Run: ``python bench/observer_update.py`` (``--json`` for one JSON line).

Both sides are timed the same way: blocks of calls timed with ``time.perf_counter``, the
median of the per-call time over the blocks. The converged step's ratio is the median over
its blocks of the step's time over that of a block of inverses timed right after it (this
machine's speed drifts by up to 1.8x within minutes: a ratio of two figures timed minutes
apart drifts with it). The observer is fed an orbit scenario at 20 Hz
(bearings and velocity, 0.5 deg bearing noise) after a 60 s warm-up: the default estimator
(riccati: numpy on 6x6 matrices, one or two live filters after the warm-up), and the paper's
observer with k = k* = 0.2 (one sub-step per sample interval) and with the paper's gains
(k* = 5: four sub-steps). Each also reports the converged velocity + bearing step and, apart,
the mean step over the first 10 s of a fresh observer (the acquisition). Last, the default
estimator's arithmetic alone: its four filters' predictions and updates on floats, the floor
under its converged step.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mav_observer import BearingSample, BiasObserver, ObserverConfig
from sim import scenarios
from sim.stream import Noise, generate

BLOCK = 200


def time_inv(blocks: int) -> float:
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3)) + 3.0 * np.eye(3)
    per_call = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(BLOCK):
            np.linalg.inv(a)
        per_call.append((time.perf_counter() - t0) / BLOCK)
    return statistics.median(per_call) * 1e6


def time_observer(cfg: ObserverConfig, seconds: float) -> dict[str, float]:
    stream = generate(
        scenarios.orbit(duration_s=60.0 + seconds), seed=1, noise=Noise(bearing_sigma_deg=0.5)
    )
    events = list(stream.events())
    obs = BiasObserver(cfg)
    warm = [e for e in events if e.t_s < 60.0]
    timed = [e for e in events if e.t_s >= 60.0]
    for ev in warm:
        (obs.update_bearing if isinstance(ev, BearingSample) else obs.update_velocity)(ev)
    vel_blocks: list[float] = []
    bear_blocks: list[float] = []
    ratios: list[float] = []
    rng = np.random.default_rng(0)
    m = rng.normal(size=(3, 3)) + 3.0 * np.eye(3)
    vel_batch = [e for e in timed if not isinstance(e, BearingSample)]
    bear_batch = [e for e in timed if isinstance(e, BearingSample)]
    # interleave in blocks of BLOCK pairs, timing each kind separately
    for i in range(0, min(len(vel_batch), len(bear_batch)) - BLOCK + 1, BLOCK):
        tv = tb = 0.0
        for j in range(i, i + BLOCK):
            t0 = time.perf_counter()
            obs.update_velocity(vel_batch[j])
            t1 = time.perf_counter()
            obs.update_bearing(bear_batch[j])
            t2 = time.perf_counter()
            tv += t1 - t0
            tb += t2 - t1
        vel_blocks.append(tv / BLOCK)
        bear_blocks.append(tb / BLOCK)
        t0 = time.perf_counter()
        for _ in range(BLOCK):
            np.linalg.inv(m)
        ratios.append((tv + tb) / (time.perf_counter() - t0))
    return {
        "velocity_update_us": statistics.median(vel_blocks) * 1e6,
        "bearing_update_us": statistics.median(bear_blocks) * 1e6,
        "blocks": len(vel_blocks),
        "step_ratio_interleaved": statistics.median(ratios),
    }


def time_acquisition(cfg: ObserverConfig, seconds: float, repeats: int) -> float:
    """Microseconds per velocity + bearing pair over the first ``seconds`` of a fresh observer
    (the acquisition: the bank's seven hypotheses, pruned and merged), median of ``repeats``."""
    stream = generate(
        scenarios.orbit(duration_s=seconds), seed=1, noise=Noise(bearing_sigma_deg=0.5)
    )
    events = list(stream.events())
    pairs = sum(1 for e in events if isinstance(e, BearingSample))
    per_pair = []
    for _ in range(repeats):
        obs = BiasObserver(cfg)
        t0 = time.perf_counter()
        for ev in events:
            (obs.update_bearing if isinstance(ev, BearingSample) else obs.update_velocity)(ev)
        per_pair.append((time.perf_counter() - t0) / pairs)
    return statistics.median(per_pair) * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=200.0, help="simulated seconds timed")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    inv_us = time_inv(blocks=200)
    results = {"inv3x3_us": inv_us, "python": platform.python_version(), "numpy": np.__version__}
    configs = (
        ("default", ObserverConfig()),
        ("paper02", ObserverConfig.paper(k_per_s=0.2, k_star_per_s=0.2)),
        ("paper", ObserverConfig.paper()),
    )
    for label, cfg in configs:
        r = time_observer(cfg, args.seconds)
        r["velocity_ratio_to_inv"] = r["velocity_update_us"] / inv_us
        r["bearing_ratio_to_inv"] = r["bearing_update_us"] / inv_us
        r["step_us"] = r["velocity_update_us"] + r["bearing_update_us"]
        r["step_ratio_to_inv"] = r["step_us"] / inv_us
        r["acquisition_step_us"] = time_acquisition(cfg, 10.0, 10)
        r["acquisition_ratio_to_inv"] = r["acquisition_step_us"] / inv_us
        results[label] = r
    if args.json:
        print(json.dumps(results))
        return 0
    print(f"numpy.linalg.inv(3x3): {inv_us:.2f} us (median of 200 blocks of {BLOCK})")
    for label, _ in configs:
        r = results[label]
        print(
            f"{label:8s}: velocity update {r['velocity_update_us']:7.1f} us "
            f"({r['velocity_ratio_to_inv']:.1f}x inv), bearing update "
            f"{r['bearing_update_us']:7.1f} us ({r['bearing_ratio_to_inv']:.1f}x inv), "
            f"median of {r['blocks']} blocks of {BLOCK}"
        )
        print(
            f"{'':8s}  converged velocity + bearing step {r['step_us']:7.1f} us "
            f"({r['step_ratio_to_inv']:.1f}x inv; {r['step_ratio_interleaved']:.1f}x the "
            f"inverses timed between its blocks); the first 10 s (acquisition) "
            f"{r['acquisition_step_us']:7.1f} us per step "
            f"({r['acquisition_ratio_to_inv']:.1f}x inv)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
