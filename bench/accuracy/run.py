"""Running estimators over the cases of the grid (a task per case and estimator, optionally
in parallel processes)."""

from __future__ import annotations

import functools
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field

import numpy as np

from . import core, estimators


@dataclass(frozen=True)
class Task:
    case: core.Case
    estimator: str
    runs: int
    seed: int = 0
    range_factor: float = 1.0
    random_init: bool = False
    per_sample: bool = False
    #: Seconds simulated; None: the scenario's duration.
    duration_s: float | None = None

    @property
    def cost(self) -> float:
        """Rough relative cost, to start the long tasks first."""
        per_run = 0.002
        if self.estimator in estimators.PER_RUN:
            per_run = 0.5
        elif self.per_sample:
            per_run = 3.0
        return self.runs * per_run + 1.0


@dataclass
class Result:
    task: Task
    metrics: dict[str, float]
    wall_s: float
    #: Relative position error (fraction of the range) over time, 1 Hz: t, median, 10 % and
    #: 90 % quantiles over runs.
    t_band: np.ndarray = field(repr=False)
    band: np.ndarray = field(repr=False)
    error: str | None = None


@functools.lru_cache(maxsize=64)
def bound(case: core.Case, duration_s: float | None = None) -> np.ndarray | None:
    """The position CRLB (T,) of ``case``; None without bearing noise."""
    if case.bearing_deg <= 0.0:
        return None
    data = core.generate(case, 1, duration_s=duration_s)
    q_x = case.velocity_mps**2 * data.dt
    return core.crlb(data.t, data.x, data.sigma_rad, q_x)


def run_estimator(est: estimators.Estimator, data: core.Data) -> core.Recorder:
    """Drive ``est`` over ``data`` and record its errors."""
    rec = core.Recorder(data.t, data.x, data.a, data.runs)
    t = data.t
    est.start(float(t[0]), data.y[:, 0], data.v[:, 0], data.r0)
    x, a, p = est.estimate()
    rec.record(0, x, a, p)
    for k in range(1, len(t)):
        est.step(float(t[k]), float(t[k] - t[k - 1]), data.dx(k), data.v[:, k], data.y[:, k])
        x, a, p = est.estimate()
        rec.record(k, x, a, p)
    return rec


def run_task(task: Task) -> Result:
    """Generate the task's data, run its estimator, summarise."""
    t0 = time.perf_counter()
    data = core.generate(
        task.case,
        task.runs,
        seed=task.seed,
        range_factor=task.range_factor,
        random_init=task.random_init,
        duration_s=task.duration_s,
    )
    try:
        est = estimators.make(
            task.estimator,
            data.sigma_rad,
            task.case.velocity_mps,
            data.n,
            data.dt,
            per_sample=task.per_sample,
        )
    except estimators.NotReadyError as exc:
        empty = np.zeros((3, 0))
        return Result(task, {}, 0.0, np.zeros(0), empty, error=str(exc))
    with np.errstate(all="ignore"):
        rec = run_estimator(est, data)
    b = bound(task.case, task.duration_s)
    metrics = core.summarise(rec, b)
    step = max(1, round(1.0 / data.dt))
    rel = rec.rel[:, ::step]
    rel = np.where(np.isfinite(rel), rel, np.inf)
    band = np.quantile(rel, [0.5, 0.1, 0.9], axis=0, method="higher")
    return Result(task, metrics, time.perf_counter() - t0, data.t[::step], band)


def run_all(tasks: list[Task], jobs: int = 1, progress: bool = True) -> list[Result]:
    """Run ``tasks`` (in ``jobs`` processes if > 1); results in the tasks' order."""
    order = sorted(range(len(tasks)), key=lambda i: -tasks[i].cost)
    results: list[Result | None] = [None] * len(tasks)
    done = 0

    def note(i: int, r: Result) -> None:
        nonlocal done
        done += 1
        results[i] = r
        if progress:
            msg = r.error or f"{r.wall_s:.1f} s"
            print(
                f"[{done}/{len(tasks)}] {r.task.case.label} {r.task.estimator}: {msg}",
                file=sys.stderr,
                flush=True,
            )

    if jobs <= 1 or len(tasks) <= 1:
        for i in order:
            note(i, run_task(tasks[i]))
    else:
        # one compiled thread per process: the processes share the cores out already
        with ProcessPoolExecutor(max_workers=jobs, initializer=_one_thread) as pool:
            futs = {pool.submit(run_task, tasks[i]): i for i in order}
            for fut in as_completed(futs):
                note(futs[fut], fut.result())
    return [r for r in results if r is not None]


def _one_thread() -> None:
    import numba

    numba.set_num_threads(1)


def default_jobs() -> int:
    return max(1, min(len(os.sched_getaffinity(0)), 8))


def fmt(v: float, digits: int = 3) -> str:
    """A metric for a table: '-' for NaN, 'inf' for infinity."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if math.isinf(v):
        return "inf"
    return f"{v:.{digits}g}"
