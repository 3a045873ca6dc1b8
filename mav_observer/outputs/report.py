"""The replay report plot (PNG; needs matplotlib: ``pip install 'mav-observer[plots]'``).

One column per target: relative position estimate (N, E, D) and range with its 2-sigma band,
bias estimate, excitation level with the status as a coloured band; with a truth file, the
position error against its 2-sigma band and the bias error. Resets and clock events (the
tracker's event log) are vertical lines on every panel.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mav_observer.errors import MavObserverError

STATUS_COLOURS = {
    "converging": "#f0c040",
    "converged": "#40a040",
    "not observable": "#d04040",
    "stale": "#909090",
}


class PlotError(MavObserverError):
    """The plot cannot be made (matplotlib missing, unwritable file)."""


def plot_replay(
    series: dict[str, Any],
    path: Path,
    *,
    title: str,
    errors: dict[str, dict[str, Any]] | None = None,
    excitation_min: float = 0.01,
    events: list[tuple[float, int, str]] | None = None,
    maps: Any = None,
) -> None:
    """Write the report for ``series`` (``{"sysid/target": Series}``) to ``path``;
    ``events``: ``(t_boot_s, sysid, name)`` marked on the panels of that vehicle; ``maps``
    (:class:`mav_observer.outputs.maps.MapTracks`): a map panel below (the vehicle's track, the
    estimates, the final estimate and its 2-sigma ellipse, longitude and latitude), for the
    targets that have a place on the map."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        import numpy as np
    except ImportError as exc:
        raise PlotError("--plot needs matplotlib: pip install 'mav-observer[plots]'") from exc
    keys = list(series)
    if not keys:
        raise PlotError("nothing to plot: no estimates")
    rows = 4 if errors else 3
    with_map = bool(maps) and any(k in maps.tracks and maps.tracks[k].estimates for k in keys)
    heights = [1.0] * rows + ([2.2] if with_map else [])
    fig, axes = plt.subplots(
        len(heights),
        len(keys),
        figsize=(7.0 * len(keys), 2.6 * sum(heights)),
        squeeze=False,
        gridspec_kw={"height_ratios": heights},
    )
    for col in range(len(keys)):  # the time panels share their time axis (not the map)
        for r in range(1, rows):
            axes[r][col].sharex(axes[0][col])
        if with_map:
            _map_panel(axes[rows][col], maps.tracks.get(keys[col]))
    for col, key in enumerate(keys):
        s = series[key]
        t = np.asarray(s.t_boot_s)
        t0 = t[0] if len(t) else 0.0
        tr = t - t0
        x = np.asarray(s.rel_pos).reshape(-1, 3)
        a = np.asarray(s.bias).reshape(-1, 3)
        ax = axes[0][col]
        for i, lab in enumerate(("north", "east", "down")):
            ax.plot(tr, x[:, i], lw=0.8, label=lab)
        rng = np.asarray(s.range_m)
        ax.plot(tr, rng, "k-", lw=1.0, label="range")
        rsd = np.asarray(s.range_std, dtype=float)
        if np.isfinite(rsd).any():
            lo, hi = rng - 2.0 * rsd, rng + 2.0 * rsd
            ax.fill_between(tr, lo, hi, color="k", alpha=0.15, lw=0, label="range +- 2 sigma")
            top = np.nanmax(np.abs(x)) if len(x) else 1.0
            ax.set_ylim(-1.5 * top, 1.5 * top)  # an early, wide band does not squash the rest
        ax.set_ylabel("target - vehicle (m)")
        ax.set_title(f"{title}: {key}", fontsize=9)
        ax.legend(fontsize=7, ncol=4)
        ax.grid(alpha=0.3)
        ax = axes[1][col]
        for i, lab in enumerate(("north", "east", "down")):
            ax.plot(tr, a[:, i], lw=0.8, label=lab)
        ax.set_ylabel("bias a (m/s)")
        ax.legend(fontsize=7, ncol=3)
        ax.grid(alpha=0.3)
        ax = axes[2][col]
        ax.semilogy(tr, np.maximum(np.asarray(s.pe), 1e-6), "k-", lw=0.8, label="excitation")
        ax.axhline(excitation_min, color="r", ls="--", lw=0.8, label="not observable below")
        start = 0
        for j in range(1, len(tr) + 1):  # one band per run of equal status
            if j == len(tr) or s.status[j] != s.status[start]:
                end = tr[min(j, len(tr) - 1)]
                colour = STATUS_COLOURS.get(s.status[start], "w")
                ax.axvspan(tr[start], end, color=colour, alpha=0.15, lw=0)
                start = j
        ax.set_ylabel("excitation")
        ax.legend(fontsize=7, title="band: status", title_fontsize=7)
        ax.grid(alpha=0.3, which="both")
        if errors:
            ax = axes[3][col]
            err = errors.get(key)
            if err is not None and len(err["t_boot_s"]):
                te = err["t_boot_s"] - t0
                ax.semilogy(te, err["pos_err_m"], lw=0.8, label="|x - xhat| (m)")
                sd = np.asarray(s.pos_std, dtype=float).reshape(-1, 3)
                if np.isfinite(sd).any():
                    band = 2.0 * np.sqrt(np.sum(sd * sd, axis=1))
                    ax.fill_between(
                        tr, 1e-4, band, color="C0", alpha=0.15, lw=0, label="2 sigma (position)"
                    )
                ax.semilogy(te, 0.05 * err["range_true_m"], "r--", lw=0.8, label="5 % of range")
                ax.semilogy(te, err["bias_err_mps"], lw=0.8, label="|a - ahat| (m/s)")
                ax.legend(fontsize=7)
            ax.set_ylabel("error against truth")
            ax.grid(alpha=0.3, which="both")
        sysid = int(key.split("/", 1)[0]) if key.split("/", 1)[0].isdigit() else None
        marks = [(te - t0, name) for te, sid, name in (events or []) if sid == sysid]
        seen: set[str] = set()
        for te, name in marks:
            if not np.isfinite(te) or not (tr[0] <= te <= tr[-1] if len(tr) else False):
                continue
            for r in range(rows):
                axes[r][col].axvline(
                    te, color="m", lw=0.6, ls=":", label=None if name in seen or r else name
                )
            seen.add(name)
        if seen:
            axes[0][col].legend(fontsize=7, ncol=4)
        axes[rows - 1][col].set_xlabel("t (s, autopilot clock, from the first estimate)")
    fig.tight_layout()
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise PlotError(f"cannot write the plot: {exc}") from exc
    finally:
        plt.close(fig)


def _map_panel(ax: Any, track: Any) -> None:
    """The map of one target: the vehicle's track, the estimates, the final estimate and its
    2-sigma ellipse (longitude, latitude; the aspect of the local scale)."""
    import math

    from mav_observer.outputs import maps as mapexport

    if track is None or not track.estimates:
        ax.set_axis_off()
        return
    veh = track.vehicle
    ax.plot([p[0] for p in veh], [p[1] for p in veh], "-", color="0.5", lw=0.8, label="vehicle")
    est = track.estimates
    ax.plot([p[1] for p in est], [p[2] for p in est], ".", ms=2, color="C0", label="estimates")
    fin = mapexport.final_estimate(track)
    if fin is not None:
        props, ring = fin
        if ring is not None:
            ax.plot([p[0] for p in ring], [p[1] for p in ring], "r-", lw=0.8,
                    label="final, 2 sigma")  # fmt: skip
        ax.plot([props["lon_deg"]], [props["lat_deg"]], "r+", ms=10, label="final estimate")
        lat0 = props["lat_deg"]
    else:
        lat0 = est[-1][2]
    ax.set_aspect(1.0 / max(math.cos(math.radians(lat0)), 1e-3))
    ax.set_xlabel("longitude (deg)")
    ax.set_ylabel("latitude (deg)")
    ax.ticklabel_format(useOffset=False)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
