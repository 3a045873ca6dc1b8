"""The adaptive end-to-end cases with the noise told as a number instead of learnt.

``python -m bench.accuracy.told_vs_learnt [--seeds 4] [--jobs 2]``: the cases of
:data:`bench.accuracy.e2e.ADAPTIVE` but the velocity one, replayed with ``bearing_noise_deg =
0.5`` and ``velocity_noise_mps = 0`` in the settings (the old default's bearing noise; robust
weighting on), scored as :mod:`bench.accuracy.e2e` scores them. Compare with its
``--adaptive`` run (the noise learnt): the table of ``docs/tuning.md``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

from bench.accuracy import e2e

CASES = ("noise_0p2deg", "noise_2deg", "outliers_5pct", "outliers_20pct")
TOLD = {"bearing_noise_deg": 0.5, "velocity_noise_mps": 0.0, "bias_walk_mps_per_sqrt_s": 0.0}


def _one(task: tuple[str, int]) -> tuple[str, dict]:
    name, seed = task
    e2e.CASES[name] = replace(e2e.CASES[name], settings=dict(TOLD))
    return name, e2e.run_one(name, seed, 300.0)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.told_vs_learnt", description=__doc__)
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--jobs", type=int, default=2)
    args = p.parse_args(argv)
    tasks = [(c, s) for c in CASES for s in range(args.seeds)]
    with ProcessPoolExecutor(args.jobs) as ex:
        results = list(ex.map(_one, tasks))
    for name in CASES:
        pooled = e2e.pooled([m for n, m in results if n == name])
        print(
            f"{name}: told {TOLD}: {pooled['ratio']:.3g}x the CRLB "
            f"(worst seed {pooled['worst_ratio']:.3g}x), NEES per axis {pooled['nees_axis']:.3g}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
