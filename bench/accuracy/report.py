"""Markdown tables, figures and ``docs/accuracy.md`` from the harness's results."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from . import core, estimators
from .run import Result, bound, fmt

HEADLINE = (
    core.Case("paper", 0.5, 0.0),
    core.Case("paper", 2.0, 0.0),
    core.Case("orbit", 0.5, 0.0),
    core.Case("orbit", 2.0, 0.0),
)
LABELS = {
    "paper": "paper's gains (0.5, 5)",
    "observer02": "observer (0.2, 0.2)",
    "ekf": "EKF",
    "plkf": "PLKF",
    "riccati": "riccati (ours)",
    "riccati_auto": "riccati, noise learnt",
}
COLOURS = {
    "paper": "tab:red",
    "observer02": "tab:orange",
    "ekf": "tab:green",
    "plkf": "tab:purple",
    "riccati": "tab:blue",
    "riccati_auto": "tab:cyan",
}


def markdown_table(columns: Iterable[str], rows: Iterable[str]) -> str:
    """A markdown table: a header of ``columns``, its separator, and ``rows`` (each already
    formatted as ``| a | b | ... |``)."""
    cols = list(columns)
    head = "| " + " | ".join(cols) + " |"
    return "\n".join([head, "|" + "---|" * len(cols), *rows])


def _name(r: Result) -> str:
    return r.task.estimator + (
        " (service)" if r.task.per_sample and r.task.estimator == "riccati" else ""
    )


def _range(m: dict[str, float]) -> str:
    if math.isnan(m["range_pct"]):
        return "-"
    return f"{m['range_pct']:+.2f} ± {fmt(m['range_pct_se'], 2)}"


def grid_table(results: Iterable[Result]) -> str:
    """One row per (case, estimator)."""
    head = (
        "| scenario | bearing deg | velocity m/s | estimator | runs | t10 median s | t10 p90 s "
        "| RMS m | bias RMS m/s | range error % (± s.e.) | CRLB m | RMS/CRLB | diverged % "
        "| NEES/dof | wall s |"
    )
    lines = [head, "|" + "---|" * 15]
    for r in results:
        c = r.task.case
        if r.error:
            lines.append(
                f"| {c.scenario} | {c.bearing_deg:g} | {c.velocity_mps:g} | {_name(r)} | - "
                f"| {r.error} |" + " |" * 9
            )
            continue
        m = r.metrics
        lines.append(
            f"| {c.scenario} | {c.bearing_deg:g} | {c.velocity_mps:g} | {_name(r)} "
            f"| {int(m['runs'])} | {fmt(m['t10_med'])} | {fmt(m['t10_p90'])} | {fmt(m['rms'])} "
            f"| {fmt(m['bias_rms'])} | {_range(m)} | {fmt(m['crlb'])} | {fmt(m['ratio'])} "
            f"| {100 * m['diverged']:.0f} | {fmt(m['nees'])} | {r.wall_s:.1f} |"
        )
    return "\n".join(lines)


def _lookup(results: Iterable[Result]) -> dict[tuple[core.Case, str], Result]:
    return {(r.task.case, r.task.estimator): r for r in results if not r.error}


def _case_rows(
    cases: Iterable[core.Case],
    names: list[str],
    look: dict[tuple[core.Case, str], Result],
    cell: Callable[[dict[str, float]], str],
    label: Callable[[core.Case], str],
) -> list[str]:
    """One markdown row per case, one ``cell(metrics)`` per estimator (empty if not run)."""
    rows = []
    for c in cases:
        cells = [cell(look[(c, e)].metrics) if (c, e) in look else "" for e in names]
        rows.append(f"| {label(c)} | " + " | ".join(cells) + " |")
    return rows


def headline_tables(results: list[Result]) -> str:
    """The headline cases (paper and orbit scenarios, 0.5 and 2 deg, exact velocity): RMS
    and its ratio to the CRLB per estimator; then t10 and the mean range error. Empty if
    none of the headline cases was run."""
    look = _lookup(results)
    cases = [c for c in HEADLINE if any((c, e) in look for e in estimators.KNOWN)]
    names = [e for e in estimators.KNOWN if any((c, e) in look for c in cases)]
    if not cases:
        return ""
    out = [
        "RMS position error over the last 100 s (m), and its ratio to the CRLB in brackets:",
        "",
        "| case | CRLB m | " + " | ".join(LABELS[e] for e in names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for c in cases:
        cr = next((look[(c, e)].metrics["crlb"] for e in names if (c, e) in look), math.nan)
        cells = []
        for e in names:
            r = look.get((c, e))
            if r is None:
                cells.append("")
            else:
                m = r.metrics
                cells.append(f"{fmt(m['rms'])} ({fmt(m['ratio'])})")
        out.append(
            f"| {c.scenario} {c.bearing_deg:g} deg | {fmt(cr)} | " + " | ".join(cells) + " |"
        )
    out += [
        "",
        "Time to stay within 10 % of the range (median / 90th percentile over runs, s), mean "
        "range error over the last 100 s (% of the range, ± standard error over runs) and "
        "share of runs diverged:",
        "",
        "| case | " + " | ".join(LABELS[e] for e in names) + " |",
        "|---|" + "---|" * len(names),
    ]

    def t10_cell(m: dict[str, float]) -> str:
        div = f", {100 * m['diverged']:.0f} % div." if m["diverged"] > 0 else ""
        return f"{fmt(m['t10_med'])} / {fmt(m['t10_p90'])} s; {_range(m)} %{div}"

    out += _case_rows(cases, names, look, t10_cell, lambda c: f"{c.scenario} {c.bearing_deg:g} deg")
    return "\n".join(out)


def random_init_table(results: list[Result]) -> str:
    look = _lookup(results)
    names = [e for e in estimators.KNOWN if any(k[1] == e for k in look)]
    rank = {c: i for i, c in enumerate(HEADLINE)}
    cases = sorted(
        {k[0] for k in look},
        key=lambda c: (rank.get(c, len(rank)), c.scenario, c.bearing_deg, c.velocity_mps),
    )
    out = [
        "| case | " + " | ".join(LABELS[e] for e in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    out += _case_rows(
        cases,
        names,
        look,
        lambda m: (
            f"{100 * m['diverged']:.0f} % div.; "
            f"t10 {fmt(m['t10_med'])} / {fmt(m['t10_p90'])} s; RMS {fmt(m['rms'])} m "
            f"({fmt(m['rms_converged'])} m without the diverged)"
        ),
        lambda c: c.label,
    )
    return "\n".join(out)


def figure_error(results: list[Result], case: core.Case, path: Path, title: str) -> bool:
    """Relative position error over time (median and 10-90 % band over runs) per estimator,
    with the CRLB relative to the range."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rs = [r for r in results if r.task.case == case and not r.error]
    if not rs:
        return False
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in rs:
        e = r.task.estimator
        col = COLOURS.get(e, "k")
        med, lo, hi = (np.clip(b, 1e-5, 1e3) for b in r.band)
        ax.fill_between(r.t_band, lo, hi, color=col, alpha=0.15, lw=0)
        ax.plot(r.t_band, med, color=col, label=f"{LABELS.get(e, e)} ({r.task.runs} runs)")
    b = bound(case)
    if b is not None:
        data = core.generate(case, 1)
        rel = b / np.linalg.norm(data.x, axis=1)
        ax.plot(data.t, rel, "k--", lw=1, label="CRLB")
    ax.axhline(core.CONVERGED_REL, color="grey", lw=0.5)
    ax.set_yscale("log")
    ax.set_ylim(1e-4, 3)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("|x̂ - x| / |x|")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def figure_ratio(results: list[Result], path: Path) -> bool:
    """Ratio of the steady RMS to the CRLB, headline cases, one bar per estimator."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    look = _lookup(results)
    cases = [c for c in HEADLINE if any((c, e) in look for e in estimators.KNOWN)]
    names = [e for e in estimators.KNOWN if any((c, e) in look for c in cases)]
    if not cases:
        return False
    fig, ax = plt.subplots(figsize=(8, 4.5))
    width = 0.8 / max(len(names), 1)
    for j, e in enumerate(names):
        vals = [look[(c, e)].metrics["ratio"] if (c, e) in look else np.nan for c in cases]
        xs = np.arange(len(cases)) + (j - (len(names) - 1) / 2) * width
        ax.bar(xs, vals, width, color=COLOURS[e], label=LABELS[e])
    ax.axhline(1.0, color="k", lw=1)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(cases)), [f"{c.scenario} {c.bearing_deg:g} deg" for c in cases])
    ax.set_ylabel("RMS position error / CRLB (last 100 s)")
    ax.set_title("Steady accuracy against the Cramér-Rao bound")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
