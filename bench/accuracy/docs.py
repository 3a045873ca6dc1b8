"""``python -m bench.accuracy --write-docs``: run the documented set and regenerate
``docs/accuracy.md`` with its figures ``docs/figures/accuracy_*.png``."""

from __future__ import annotations

import platform
import subprocess
import time
from pathlib import Path

import numpy as np

from . import blocks, core, estimators, report
from .run import Result, Task, fmt, run_all

#: Runs per case: batched estimators; the per-sample ones on the headline cases and elsewhere.
RUNS = 100
RUNS_SLOW_HEADLINE = 20
RUNS_SLOW = 10
#: Runs per headline case of the product's riccati through BiasObserver (about 3 s a run).
RUNS_SERVICE = 10
TIMING_RUNS = 1000
#: runs per case of the large random-initialisation set (riccati and the EKF)
RUNS_RANDOM_BIG = 1000
RANDOM_BIG_SCENARIOS = ("paper", "orbit", "moving_target", "planar")
TIMING_CASE = core.Case("orbit", 0.5, 0.0)

ESTIMATOR_TEXT = {
    "riccati": (
        "**riccati (ours)**, the product's default (the compiled kernels of "
        "`mav_observer/core/kernels/bank.py`, run over the runs by "
        "`bench/accuracy/bankruns.py`): per run a "
        "bank of 7 extended Kalman filters on `[x, a]` whose initial ranges span `r0 / 16` to "
        "`16 r0`, weighted by their bearing likelihoods and pruned, plus one Riccati observer "
        "(the pseudo-linear form, which converges from any initial state under persistent "
        "excitation) that re-seeds the bank when its innovations stop being consistent. Told "
        "`sigma = max(true sigma, 0.05 deg)` and `q_x = sv^2 dt`. Its estimate is the mixture's "
        "mean and covariance."
    ),
    "ekf": (
        "**EKF** (baseline, `bench/accuracy/estimators.py` only): one extended Kalman filter on "
        "`[x, a]` per run, the tracking form of the bank's filter update "
        "(`kalman.update_filter`; innovation: the sines of the angle between the measured and "
        "the estimated bearing), started at `r0 y0` with a "
        "range standard deviation of `1.0 r0` along the bearing and 5 m/s on each bias "
        "component; no process noise but the velocity's. Efficient once near the truth, "
        "local only."
    ),
    "plkf": (
        "**PLKF** (baseline): the pseudo-linear Kalman filter, the acquisition form of "
        "the bank's filter update with the constant weight range `r0`, prior "
        "range std `3 r0`. Its output `E^T x = 0` is linear in the state, so it converges "
        "globally, but the measured bearing's tangent basis is correlated with the noise: "
        "its range is biased short by a few `sigma^2` and it is not efficient."
    ),
    "paper": (
        "**paper's gains (0.5, 5)**: the observer of Le Bras et al. (2015) as the product's "
        "`BiasObserver(ObserverConfig.paper(initial_range_m=r0))`, one per run through "
        "`update_velocity` / `update_bearing`. The gains were chosen for the paper's 3 m scene "
        "with exact bearings; with bearing noise the large `k*` passes the noise into `a` and "
        "the range estimate is biased short, increasingly with the noise and at drone scale "
        "(see the range errors and divergences below)."
    ),
    "observer02": (
        "**observer (0.2, 0.2)**: the same observer with `k = k* = 0.2` "
        "(`ObserverConfig.paper(k_per_s=0.2, k_star_per_s=0.2, initial_range_m=r0)`), the "
        "`paper` estimator's default gains: stable at drone scale, but a fixed-gain observer, "
        "several times above the bound and slow to converge."
    ),
}


def _grid_tasks(seed: int) -> list[Task]:
    out = []
    for s in core.SCENARIOS:
        for b in (0.0, 0.5, 2.0):
            for v in (0.0, 0.05):
                c = core.Case(s, b, v)
                for e in estimators.ALL:
                    slow = RUNS_SLOW_HEADLINE if c in report.HEADLINE else RUNS_SLOW
                    runs = slow if e in estimators.PER_RUN else RUNS
                    out.append(Task(c, e, runs, seed=seed))
    return out


def _random_tasks(seed: int) -> list[Task]:
    return [
        Task(
            c,
            e,
            RUNS_SLOW_HEADLINE if e in estimators.PER_RUN else RUNS,
            seed=seed,
            random_init=True,
        )
        for c in report.HEADLINE
        for e in estimators.ALL
    ]


def _random_big_tasks(seed: int) -> list[Task]:
    return [
        Task(core.Case(s, b, v), e, RUNS_RANDOM_BIG, seed=seed, random_init=True)
        for s in RANDOM_BIG_SCENARIOS
        for b in (0.5, 2.0)
        for v in (0.0, 0.05)
        for e in ("riccati", "ekf")
    ]


def _service_tasks(seed: int) -> list[Task]:
    return [Task(c, "riccati", RUNS_SERVICE, seed=seed, per_sample=True) for c in report.HEADLINE]


def _product_version(root: Path) -> str:
    """The commit of the code measured, and whether mav_observer/ differs from it."""

    def git(*args: str) -> str:
        proc = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, check=False)
        return proc.stdout.strip() if proc.returncode == 0 else ""

    rev = git("rev-parse", "--short", "HEAD")
    if not rev:
        return "an unknown commit"
    dirty = git("status", "--porcelain", "--", "mav_observer")
    return f"commit {rev}" + (" with uncommitted changes in mav_observer/" if dirty else "")


def write_docs(root: Path, *, jobs: int, seed: int = 0) -> int:
    version = _product_version(root)
    t_start = time.perf_counter()
    grid = run_all(_grid_tasks(seed), jobs=jobs)
    random = run_all(_random_tasks(seed), jobs=jobs)
    service = run_all(_service_tasks(seed), jobs=jobs)
    random_big = run_all(_random_big_tasks(seed), jobs=jobs)
    timing = run_all([Task(TIMING_CASE, "riccati", TIMING_RUNS, seed=seed)], jobs=1)[0]
    total = time.perf_counter() - t_start

    figs = root / "docs" / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    made = []
    orbit2 = core.Case("orbit", 2.0, 0.0)
    if report.figure_error(
        grid,
        orbit2,
        figs / "accuracy_error_orbit.png",
        "orbit, 2 deg bearing noise, range guess = true range",
    ):
        made.append("accuracy_error_orbit.png")
    if report.figure_ratio(grid, figs / "accuracy_crlb_ratio.png"):
        made.append("accuracy_crlb_ratio.png")
    if report.figure_error(
        random,
        orbit2,
        figs / "accuracy_random_init.png",
        "orbit, 2 deg, range guess = true range * 10**U(-1, 1)",
    ):
        made.append("accuracy_random_init.png")

    text = _markdown(grid, random, random_big, service, timing, total, jobs, made, version)
    page = root / "docs" / "accuracy.md"
    kept = blocks.blocks_of(page.read_text()) if page.exists() else {}
    page.write_text(blocks.with_blocks(text, kept))  # the end-to-end blocks stay
    print(f"wrote docs/accuracy.md and {len(made)} figures in {total:.0f} s")
    return 0


def _markdown(
    grid: list[Result],
    random: list[Result],
    random_big: list[Result],
    service: list[Result],
    timing: Result,
    total_s: float,
    jobs: int,
    figures: list[str],
    version: str,
) -> str:
    service_ok = [r for r in service if not r.error]
    service_err = sorted({r.error for r in service if r.error})
    m = timing.metrics
    lines = [
        "# Accuracy of the estimators (Monte Carlo)",
        "",
        "<!-- Generated by `python -m bench.accuracy --write-docs`; do not edit by hand. -->",
        "",
        "How close each estimator of the relative position `x` and the velocity bias `a` gets "
        "to the best achievable accuracy, the Cramér-Rao lower bound (CRLB), and how reliably "
        "it converges. The first sections measure the product the way a user runs it: MAVLink "
        "frames through `mav-observer replay`, on emitter streams with realistic timing and on "
        'real flight logs with injected bearings. The Monte Carlo sections after them ("What '
        "is measured\" onwards) feed the estimators' maths directly and tell them the true "
        "noise: they show what the maths can do, not what a user gets.",
        "",
        "## What is measured",
        "",
        "Data: the scenarios of `sim/scenarios.py` (`paper`, `orbit`, `moving_target`, "
        "`straight_pass`, `planar`; 300 s, `straight_pass` 120 s), bearings and velocity both "
        "sampled at 20 Hz. Bearing noise is the simulator's model (`sim.stream.perturb_bearings`: "
        "isotropic Gaussian angular noise of sigma per tangent direction) at 0, 0.5 and 2 deg; "
        "velocity noise is Gaussian on each component at 0 and 0.05 m/s. Every run has its own "
        "seeded random stream (seed, case, run index), so run `i` is the same data for every "
        "estimator and any number of runs. The initial range guess `r0` is the true initial "
        "range (`--range-factor 1`), or with `--random-init` the true range times "
        "`10**U(-1, 1)`, a guess up to 10 times off either way.",
        "",
        "Metrics per (scenario, noise, estimator), position error `e = x̂ - x`, range `r = |x|`:",
        "",
        "* **t10**: the time after which `|e| / r` stays below 10 % to the end (median and "
        "90th percentile over runs; `inf` if it never does).",
        "* **RMS**: root mean square of `|e|` over the last 100 s and all runs whose estimates "
        "stayed finite; **bias RMS** likewise for `|â - a|`.",
        "* **range error**: mean over the last 100 s of `(|x̂| - r) / r` in %, averaged over "
        "runs, with its standard error over runs.",
        "* **CRLB**: the posterior Cramér-Rao bound of the position along the true trajectory, "
        "`sqrt(trace(J^-1)_xx)`, from the information recursion `J_k = (F J_{k-1}^-1 F^T + "
        "Q)^-1 + H_k^T H_k / sigma^2` with `H_k = [E_k^T / r_k, 0]` (`E_k` the tangent basis of "
        "the true bearing) and `Q = q_x dt` on the position block, `q_x = sv^2 dt` (the "
        "velocity's noise as process noise); reported as the RMS of the bound over the last "
        "100 s. Not defined without bearing noise (`-`). **RMS/CRLB** is the efficiency: 1 is "
        "the best any unbiased estimator can do. The bound has no prior information (a "
        "negligible `1e-9` on every component), the estimators do (a range guess, 5 m/s on "
        "the bias): where the bearings alone hardly determine the state, the bound is far "
        "above what they reach and the ratio means nothing. That is `straight_pass`: its last "
        "100 s start during the 32 s pass, when the bound is about 10 km; after the pass "
        "(the vehicle decelerates, then hovers) it is about 1 m.",
        "* **diverged**: share of runs whose final position error exceeds 50 % of the range "
        "(or is not finite).",
        "* **NEES/dof**: for estimators with a covariance, the mean over runs and the last "
        "100 s of `e^T P_xx^-1 e / n`; 1 when the covariance is consistent.",
        "",
        "## How to run",
        "",
        "From the repository root:",
        "",
        "```sh",
        "python -m bench.accuracy                      # the whole grid, 100 runs per case",
        "python -m bench.accuracy --scenarios orbit --bearing-noise 2 --velocity-noise 0 \\",
        "    --estimators riccati ekf --runs 200",
        "python -m bench.accuracy --random-init --scenarios paper orbit   # 10x-off range guesses",
        "python -m bench.accuracy --per-sample --estimators riccati       # through BiasObserver",
        "python -m bench.accuracy --runs 1000 --scenarios orbit --bearing-noise 0.5 \\",
        "    --velocity-noise 0 --estimators riccati                      # batch timing",
        "python -m bench.accuracy --write-docs          # regenerate this page and its figures",
        "```",
        "",
        "`--runs` is the number of runs of the batched estimators (`riccati`, `ekf`, `plkf`: "
        "numpy over all runs at once); `--runs-per-sample` (default 20) that of the estimators "
        "driven one `BiasObserver` per run (`paper`, `observer02`, and `riccati` with "
        "`--per-sample`), about 0.5 s a run. `--jobs` spreads the (case, estimator) tasks over "
        "processes. The output is a markdown table per (case, estimator) and, when the "
        "headline cases are included, the headline tables below.",
        "",
        f"This page: {RUNS} runs per case for the batched estimators, {RUNS_SLOW_HEADLINE} for "
        f"the per-sample ones on the headline cases and {RUNS_SLOW} elsewhere; generated in "
        f"{total_s:.0f} s with {jobs} processes on {platform.machine()} from {version} "
        f"({platform.python_implementation()} {platform.python_version()}, numpy "
        f"{np.__version__}).",
        "",
        "## Headline",
        "",
        "The maths fed directly, the noise told (not the product's path: see \"End to end, "
        'through replay" above). Paper and orbit scenarios, 0.5 and 2 deg bearing noise, '
        "exact velocity, range guess = true range.",
        "",
        report.headline_tables(grid),
        "",
    ]
    if "accuracy_crlb_ratio.png" in figures:
        lines += ["![RMS over CRLB](figures/accuracy_crlb_ratio.png)", ""]
    if "accuracy_error_orbit.png" in figures:
        lines += [
            "Relative position error over time, orbit 2 deg (median and 10-90 % band over "
            "runs; dashed: the CRLB relative to the range):",
            "",
            "![error over time, orbit 2 deg](figures/accuracy_error_orbit.png)",
            "",
        ]
    lines += [
        "## Random initial range",
        "",
        "Range guess `r0` = true range times `10**U(-1, 1)` per run (the same draws for every "
        "estimator): share of runs diverged, t10 (median / 90th percentile) and steady RMS "
        "(over all runs, and over the runs that did not diverge).",
        "",
        report.random_init_table(random),
        "",
    ]
    if "accuracy_random_init.png" in figures:
        lines += ["![random initial range, orbit 2 deg](figures/accuracy_random_init.png)", ""]
    lines += [
        f"### {RUNS_RANDOM_BIG:,} random initial ranges per case",
        "",
        f"The default estimator and the EKF, {RUNS_RANDOM_BIG:,} runs per case, each with its "
        "own noise and range guess `r0` = true range times `10**U(-1, 1)` (so up to 10 times "
        "off either way); the bias starts at zero. RMS over all runs whose estimates stayed "
        "finite.",
        "",
        report.grid_table(random_big),
        "",
    ]
    lines += [
        "## Through the service's interface",
        "",
        "The product's default estimator driven per sample through "
        "`BiasObserver(ObserverConfig()).update_velocity` / `update_bearing` "
        "(`--per-sample`), headline cases:",
        "",
    ]
    if service_ok:
        lines += [report.grid_table(service_ok), ""]
    for e in service_err:
        lines += [f"Not run: {e}.", ""]
    lines += [
        "## Batch timing",
        "",
        f"{TIMING_RUNS} runs of the riccati estimator, {TIMING_CASE.label}, 300 s at 20 Hz "
        f"(6,001 steps), one process: **{timing.wall_s:.1f} s** wall (data generation, the "
        f"estimator and the metrics; goal: under 5 s). RMS {fmt(m['rms'])} m, CRLB "
        f"{fmt(m['crlb'])} m, ratio {fmt(m['ratio'])}, NEES/dof {fmt(m['nees'])}, diverged "
        f"{100 * m['diverged']:.1f} %.",
        "",
        "## The estimators",
        "",
    ]
    for e in estimators.ALL:
        lines += [ESTIMATOR_TEXT[e], ""]
    lines += [
        "## All cases",
        "",
        "Range guess = true range. Columns as above; `wall s` is the task's time (data, "
        "estimator, metrics) in its process.",
        "",
        report.grid_table(grid),
        "",
    ]
    return "\n".join(lines)
