"""Reproduce the figures of the paper's Section 4 (needs matplotlib; writes PNG files).

Six figures as in the paper, for the noise-free case and the paper's noisy case (uniform
+-0.5 m on x before y is formed), gains k = 0.5, k* = 5, start xh1 = 0, M = I, zs = 0:

1. ``fig1_trajectory``, ``fig4_trajectory_noisy``: x and xhat in 3-D;
2. ``fig2_error``, ``fig5_error_noisy``: the components of x - xhat against time (and its
   norm, log scale);
3. ``fig3_ahat``, ``fig6_ahat_noisy``: ahat against time, the true a dashed.

Plus ``fig7_gains_noise``: the error norm under noise for the paper's gains and two
gentler settings, which is where our reproduction departs from the paper's claim.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from mav_observer.core.observer import BiasObserver, ObserverConfig
from sim import scenarios
from sim.runner import RunResult, run
from sim.stream import PAPER_NOISE, Noise, generate

LAST_S = 100.0  # the "steady" part: the last 100 s of the run


def _steady(res: RunResult) -> dict[str, float]:
    sel = res.t_s >= res.t_s[-1] - LAST_S
    rng_est = np.linalg.norm(res.xhat_m[sel], axis=1)
    return {
        "final_pos_err_m": float(res.pos_err_m[-1]),
        "final_bias_err_mps": float(res.bias_err_mps[-1]),
        "steady_pos_err_rms_m": float(np.sqrt(np.mean(res.pos_err_m[sel] ** 2))),
        "steady_range_ratio": float(np.mean(rng_est / res.range_m[sel])),
        "final_cond_m": float(res.cond_m[-1]),
        "time_below_10pct_s": res.time_to_stay_below(0.1),
        "max_pos_err_m": float(res.pos_err_m.max()),
    }


def _trajectory(res: RunResult, title: str, path: Path) -> None:
    fig = plt.figure(figsize=(6.0, 5.0))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*res.x_true_m.T, "k-", lw=1.5, label="x (truth)")
    ax.plot(*res.xhat_m.T, "C1-", lw=0.8, label="xhat (estimate)")
    ax.scatter(*res.xhat_m[0], color="C1", marker="o", s=20, label="xhat(0)")
    ax.set_xlabel("x1 (m)")
    ax.set_ylabel("x2 (m)")
    ax.set_zlabel("x3 (m)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _error(res: RunResult, title: str, path: Path) -> None:
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7.0, 5.5), sharex=True)
    err = res.x_true_m - res.xhat_m
    for i in range(err.shape[1]):
        ax1.plot(res.t_s, err[:, i], lw=0.8, label=f"x{i + 1} - xhat{i + 1}")
    ax1.set_ylabel("error (m)")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ax1.set_title(title, fontsize=9)
    ax2.semilogy(res.t_s, res.pos_err_m, "k-", lw=0.8, label="|x - xhat|")
    ax2.semilogy(res.t_s, 0.1 * res.range_m, "r--", lw=0.8, label="10 % of range")
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("|x - xhat| (m)")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _ahat(res: RunResult, title: str, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(7.0, 4.0))
    for i in range(res.ahat_mps.shape[1]):
        ax.plot(res.t_s, res.ahat_mps[:, i], lw=0.8, color=f"C{i}", label=f"ahat{i + 1}")
        ax.axhline(res.a_true_mps[0, i], color=f"C{i}", ls="--", lw=0.8)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("ahat (m/s)")
    ax.set_title(title + " (dashed: true a)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def paper_figures(
    out_dir: str | Path, *, duration_s: float = 300.0, seed: int = 0
) -> dict[str, Any]:
    """Write the figures into ``out_dir`` and return the measured figures of merit."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sc = scenarios.paper(duration_s=duration_s)
    cfg = ObserverConfig.paper()
    summary: dict[str, Any] = {}
    cases = (("noise-free", Noise(), ""), ("noisy +-0.5 m", PAPER_NOISE, "_noisy"))
    for n_fig, (label, noise, suffix) in enumerate(cases):
        res = run(BiasObserver(cfg), generate(sc, seed=seed, noise=noise))
        title = f"paper scenario, {label}, k=0.5, k*=5"
        _trajectory(res, title, out / f"fig{1 + 3 * n_fig}_trajectory{suffix}.png")
        _error(res, title, out / f"fig{2 + 3 * n_fig}_error{suffix}.png")
        _ahat(res, title, out / f"fig{3 + 3 * n_fig}_ahat{suffix}.png")
        summary[label] = _steady(res)
    # gains under noise
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 4.0), sharey=True)
    for ax, noise in zip(axes, (Noise(position_noise_m=0.05), PAPER_NOISE), strict=True):
        for k, ks in ((0.5, 5.0), (0.5, 0.5), (0.2, 0.2)):
            res = run(
                BiasObserver(ObserverConfig.paper(k_per_s=k, k_star_per_s=ks)),
                generate(sc, seed=seed, noise=noise),
            )
            summary[f"+-{noise.position_noise_m} m, k={k}, k*={ks}"] = _steady(res)
            ax.semilogy(res.t_s, res.pos_err_m, lw=0.7, label=f"k={k}, k*={ks}")
        ax.semilogy(res.t_s, res.range_m, "k--", lw=0.8, label="range |x|")
        ax.set_title(f"paper scenario, uniform +-{noise.position_noise_m} m on x", fontsize=9)
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("|x - xhat| (m)")
    fig.tight_layout()
    fig.savefig(out / "fig7_gains_noise.png", dpi=110)
    plt.close(fig)
    return summary


def _seconds(t: float | None) -> str:
    return "never" if t is None else f"{t:.1f} s"


def summary_lines(summary: dict[str, Any]) -> list[str]:
    lines = []
    for case, m in summary.items():
        lines.append(
            f"{case}: final |x-xhat| {m['final_pos_err_m']:.3g} m, |a-ahat| "
            f"{m['final_bias_err_mps']:.3g} m/s, last-{LAST_S:g}-s RMS error "
            f"{m['steady_pos_err_rms_m']:.3g} m, mean |xhat|/|x| {m['steady_range_ratio']:.3f}, "
            f"below 10 % of range from {_seconds(m['time_below_10pct_s'])}, peak error "
            f"{m['max_pos_err_m']:.3g} m, cond(M) {m['final_cond_m']:.1f}"
        )
    return lines
