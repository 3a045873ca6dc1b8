"""Command line of the accuracy harness: ``python -m bench.accuracy --help``."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from . import core, estimators, report
from .run import Result, Task, default_jobs, run_all

ROOT = Path(__file__).resolve().parents[2]


def _floats(values: Sequence[str]) -> list[float]:
    return [float(v) for item in values for v in item.split(",") if v]


def _names(values: Sequence[str], allowed: Sequence[str], what: str) -> list[str]:
    out = [v for item in values for v in item.split(",") if v]
    for v in out:
        if v not in allowed:
            raise SystemExit(f"unknown {what} {v!r}; choose from {', '.join(allowed)}")
    return out


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m bench.accuracy",
        description="Monte Carlo accuracy of the estimators against the Cramér-Rao bound. "
        "Lists take several values or commas.",
    )
    p.add_argument("--scenarios", nargs="+", default=list(core.SCENARIOS))
    p.add_argument("--bearing-noise", nargs="+", default=["0", "0.5", "2"], help="deg")
    p.add_argument("--velocity-noise", nargs="+", default=["0", "0.05"], help="m/s")
    p.add_argument("--estimators", nargs="+", default=list(estimators.ALL))
    p.add_argument("--runs", type=int, default=100, help="runs per case (batched estimators)")
    p.add_argument(
        "--runs-per-sample",
        type=int,
        default=20,
        help="runs per case of the estimators driven through BiasObserver (about 0.5 s a run)",
    )
    p.add_argument("--range-factor", type=float, default=1.0, help="r0 = factor * true range")
    p.add_argument(
        "--random-init",
        action="store_true",
        help="r0 = true range * 10**U(-1, 1) per run (overrides --range-factor)",
    )
    p.add_argument(
        "--per-sample",
        action="store_true",
        help="drive riccati through BiasObserver(ObserverConfig()) too (needs the product's "
        "estimator setting); baselines without a product form are skipped",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--duration", type=float, default=None, help="s simulated (default: the scenario's)"
    )
    p.add_argument("--jobs", type=int, default=default_jobs(), help="worker processes")
    p.add_argument(
        "--write-docs",
        action="store_true",
        help="run the documented set (grid, random init, 1,000-run timing) and regenerate "
        "docs/accuracy.md and docs/figures/accuracy_*.png (ignores the other options but "
        "--jobs and --seed)",
    )
    return p


def tasks_for(args: argparse.Namespace, cases: list[core.Case], names: list[str]) -> list[Task]:
    if args.per_sample:
        skipped = [e for e in names if e not in estimators.SERVICE_FORMS]
        if skipped:
            print(f"note: no product form, skipped with --per-sample: {skipped}", file=sys.stderr)
        names = [e for e in names if e in estimators.SERVICE_FORMS]
    out = []
    for c in cases:
        for e in names:
            slow = e in estimators.PER_RUN or (args.per_sample and e == "riccati")
            out.append(
                Task(
                    c,
                    e,
                    args.runs_per_sample if slow else args.runs,
                    seed=args.seed,
                    range_factor=args.range_factor,
                    random_init=args.random_init,
                    per_sample=args.per_sample,
                    duration_s=args.duration,
                )
            )
    return out


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if args.write_docs:
        from .docs import write_docs

        return write_docs(ROOT, jobs=args.jobs, seed=args.seed)
    scen = _names(args.scenarios, core.SCENARIOS, "scenario")
    names = _names(args.estimators, estimators.KNOWN, "estimator")
    cases = [
        core.Case(s, b, v)
        for s in scen
        for b in _floats(args.bearing_noise)
        for v in _floats(args.velocity_noise)
    ]
    tasks = tasks_for(args, cases, names)
    t0 = time.perf_counter()
    results = run_all(tasks, jobs=args.jobs)
    wall = time.perf_counter() - t0
    print(summary(results, random_init=args.random_init))
    print(f"\nwall time {wall:.1f} s for {len(tasks)} tasks ({args.jobs} jobs)")
    return 1 if any(r.error for r in results) else 0


def summary(results: list[Result], *, random_init: bool = False) -> str:
    init = "random (r0 = true range * 10**U(-1, 1))" if random_init else "fixed"
    parts = [f"Initial range guess: {init}.", "", report.grid_table(results)]
    head = report.headline_tables(results)
    if head and not random_init:
        parts += ["", head]
    errors = sorted({r.error for r in results if r.error})
    parts += [f"\nnot run: {e}" for e in errors]
    return "\n".join(parts)
