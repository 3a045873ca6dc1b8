"""Discretisation accuracy: the observer fed sampled data against a fine RK4 of the continuous
equations driven by the true, continuous inputs.

Run: ``python bench/discretisation.py`` (about a minute). For each scenario, gains and input
rate, prints the largest difference to RK4 relative to the range over the run, and the error
to the truth at the end, for linear interpolation (the default) and the zero-order hold.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mav_observer import BiasObserver, ObserverConfig
from sim import scenarios
from sim.reference import rk4_reference
from sim.runner import run
from sim.stream import generate

CASES = (
    ("paper", 0.5, 5.0, 20.0),
    ("paper", 0.5, 5.0, 10.0),
    ("paper", 0.2, 0.2, 20.0),
    ("orbit", 0.2, 0.2, 20.0),
    ("orbit", 0.2, 0.2, 5.0),
    ("moving_target", 0.2, 0.2, 20.0),
)


def main() -> int:
    print(
        f"{'scenario':14s} {'k':>4s} {'k*':>4s} {'rate':>5s}  {'interp':7s} "
        f"{'max |xhat-rk4|/|x|':>19s} {'end |x-xhat| m':>15s} {'rk4 end m':>10s}"
    )
    for name, k, ks, rate in CASES:
        sc = scenarios.make(name)
        stream = generate(sc, bearing_rate_hz=rate, velocity_rate_hz=rate)
        ref = None
        for interp in ("linear", "hold"):
            cfg = ObserverConfig(
                estimator="paper",
                k_per_s=k,
                k_star_per_s=ks,
                interpolation=interp,
                static_hold=False,
            )
            res = run(BiasObserver(cfg), stream)
            if ref is None:
                ref = rk4_reference(sc, k=k, k_star=ks, t_out_s=res.t_s, dt_s=0.01)
            rel = np.linalg.norm(res.xhat_m - ref.xhat_m, axis=1) / res.range_m
            rk4_end = np.linalg.norm(ref.xhat_m[-1] - res.x_true_m[-1])
            print(
                f"{name:14s} {k:4.1f} {ks:4.1f} {rate:5.1f}  {interp:7s} {rel.max():19.2e} "
                f"{res.pos_err_m[-1]:15.2e} {rk4_end:10.2e}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
