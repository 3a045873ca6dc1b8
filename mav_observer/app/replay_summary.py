"""What a replay read, used, skipped and estimated: its summary, as text and as JSON."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from mav_observer.core.samples import NoiseLevels, Status
from mav_observer.outputs.records import EstimateRecord

if TYPE_CHECKING:
    from mav_observer.core import smoother
    from mav_observer.outputs.html_report import ReportData
    from mav_observer.outputs.maps import MapTracks


@dataclass
class Series:
    """Per-target time series kept for the plot and the truth comparison."""

    t_boot_s: list[float] = field(default_factory=list)
    rel_pos: list[tuple[float, float, float]] = field(default_factory=list)
    bias: list[tuple[float, float, float]] = field(default_factory=list)
    range_m: list[float] = field(default_factory=list)
    #: 1-sigma of the range (m) and of each component of the position (m); NaN if unknown
    range_std: list[float] = field(default_factory=list)
    pos_std: list[tuple[float, float, float]] = field(default_factory=list)
    pe: list[float] = field(default_factory=list)
    status: list[str] = field(default_factory=list)

    def add(self, r: EstimateRecord) -> None:
        e = r.estimate
        self.t_boot_s.append(r.t_boot_s)
        self.rel_pos.append((float(e.x_m[0]), float(e.x_m[1]), float(e.x_m[2])))
        self.bias.append((float(e.a_mps[0]), float(e.a_mps[1]), float(e.a_mps[2])))
        self.range_m.append(e.range_m)
        nan = math.nan
        self.range_std.append(nan if e.range_std_m is None else e.range_std_m)
        sd = e.x_std_m
        self.pos_std.append(
            (nan, nan, nan) if sd is None else (float(sd[0]), float(sd[1]), float(sd[2]))
        )
        self.pe.append(e.excitation)
        self.status.append(str(e.status))


@dataclass
class TargetSummary:
    sysid: int
    target: str
    source: str
    estimates: int = 0
    first_t_boot_s: float | None = None
    last_t_boot_s: float | None = None
    excited_s: float = 0.0
    covered_s: float = 0.0
    converged_s: float = 0.0
    nis_sum: float = 0.0
    nis_count: int = 0
    final: EstimateRecord | None = None
    #: the noise levels in use at the end (learnt or told) and the robust update's counts
    noise: NoiseLevels | None = None

    def add(self, r: EstimateRecord, excitation_min: float) -> None:
        if self.final is not None and self.last_t_boot_s is not None:
            dt = r.t_boot_s - self.last_t_boot_s
            if dt > 0:
                self.covered_s += dt
                prev = self.final.estimate
                if prev.excitation >= excitation_min and prev.status not in (
                    Status.NOT_OBSERVABLE,
                    Status.STALE,
                ):
                    self.excited_s += dt
                if prev.status == Status.CONVERGED:
                    self.converged_s += dt
        nis = r.estimate.nis
        if nis is not None and math.isfinite(nis):
            self.nis_sum += nis
            self.nis_count += 1
        if self.first_t_boot_s is None:
            self.first_t_boot_s = r.t_boot_s
        self.last_t_boot_s = r.t_boot_s
        self.estimates += 1
        self.final = r

    @property
    def excited_share(self) -> float:
        return self.excited_s / self.covered_s if self.covered_s > 0 else 0.0

    @property
    def converged_share(self) -> float:
        """Share of the time covered by estimates during which the status was converged."""
        return self.converged_s / self.covered_s if self.covered_s > 0 else 0.0

    @property
    def nis_mean(self) -> float | None:
        """Mean normalised innovation squared per degree of freedom over the estimates
        (about 1 when the bearings are as noisy as the estimator was told); ``None`` for
        an estimator without one."""
        return self.nis_sum / self.nis_count if self.nis_count else None


@dataclass
class ReplaySummary:
    """What a replay read, used, skipped and estimated."""

    source: str
    bytes_total: int = 0
    #: the file's kind: ``tlog``, ``DataFlash``, ``ULog``, ``raw MAVLink``; ``link`` for a live one
    log_format: str = "tlog"
    #: what the log lacks, or how it was read (``no MNT record: ...``)
    log_notes: list[str] = field(default_factory=list)
    messages_read: int = 0
    by_type: dict[str, int] = field(default_factory=dict)
    used: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)
    damage: dict[str, int] = field(default_factory=dict)
    events: dict[str, int] = field(default_factory=dict)
    first_t_unix_s: float | None = None
    last_t_unix_s: float | None = None
    targets: dict[str, TargetSummary] = field(default_factory=dict)
    estimates_written: int = 0
    wall_s: float = 0.0
    series: dict[str, Series] = field(default_factory=dict)
    #: ``(t_boot_s, sysid, event)`` of the resets and clock events, in order
    event_log: list[tuple[float, int, str]] = field(default_factory=list)
    #: ``replay --smooth``: each target's smoothed track, by ``sysid/target``
    smoothed: dict[str, smoother.Smoothed] = field(default_factory=dict)
    #: its last estimate of the target's position: ``(t_boot_s, target_pos_ned_m,
    #: rel_pos_std_ned_m, windows fitted, windows)``
    smoothed_final: dict[str, tuple[float, list[float], list[float], int, int]] = field(
        default_factory=dict
    )
    #: ``keep_map``: what the GeoJSON and KML exports need (:mod:`mav_observer.outputs.maps`)
    map_tracks: MapTracks | None = None
    #: ``keep_report``: what ``replay --html`` shows (:mod:`mav_observer.outputs.html_report`)
    report: ReportData | None = None
    #: with ``gimbal_angles = "auto"``: how each gimbal's angles were read in the end, by
    #: ``sysid/device id`` (``"flags"``, ``"body"``, or ``"auto"``: undecided, the flags)
    gimbal_angles: dict[str, str] = field(default_factory=dict)

    @property
    def messages_per_s(self) -> float:
        return self.messages_read / self.wall_s if self.wall_s > 0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "format": self.log_format,
            "bytes": self.bytes_total,
            "log_notes": self.log_notes,
            "messages_read": self.messages_read,
            "messages_by_type": self.by_type,
            "used": self.used,
            "skipped": self.skipped,
            "damage": self.damage,
            "events": self.events,
            "gimbal_angles": self.gimbal_angles,
            "first_t_unix_s": self.first_t_unix_s,
            "last_t_unix_s": self.last_t_unix_s,
            "estimates_written": self.estimates_written,
            "wall_s": self.wall_s,
            "targets": {
                k: {
                    "sysid": t.sysid,
                    "target": t.target,
                    "source": t.source,
                    "estimates": t.estimates,
                    "excited_share": t.excited_share,
                    "converged_share": t.converged_share,
                    "nis_mean": t.nis_mean,
                    "noise": None if t.noise is None else t.noise.to_dict(),
                    "smoothed": {
                        key: {
                            "t_boot_s": v[0],
                            "target_pos_ned_m": v[1],
                            "rel_pos_std_ned_m": v[2],
                            "windows_fitted": v[3],
                            "windows": v[4],
                        }
                        for key, v in self.smoothed_final.items()
                        if key.split("#")[0] == k
                    },
                    "final": None if t.final is None else t.final.to_dict(),
                }
                for k, t in self.targets.items()
            },
        }

    def text(self) -> str:
        lines = [f"source: {self.source} ({self.log_format}, {self.bytes_total} bytes)"]
        lines.extend(f"log: {note}" for note in self.log_notes)
        top = ", ".join(f"{k} {v}" for k, v in list(self.by_type.items())[:12])
        more = len(self.by_type) - 12
        lines.append(
            f"messages read: {self.messages_read} of {len(self.by_type)} types: {top}"
            + (f", and {more} more types" if more > 0 else "")
        )
        lines.append("used: " + (", ".join(f"{k} {v}" for k, v in self.used.items()) or "nothing"))
        lines.append(
            "skipped: " + (", ".join(f"{k} {v}" for k, v in self.skipped.items()) or "none")
        )
        if self.damage:
            lines.append("damage: " + ", ".join(f"{k} {v}" for k, v in self.damage.items()))
        if self.events:
            lines.append("events: " + ", ".join(f"{k} {v}" for k, v in self.events.items()))
        for key, reading in self.gimbal_angles.items():
            sysid, dev = key.split("/")
            lines.append(
                f"gimbal angles: vehicle {sysid} gimbal {dev} read "
                + {
                    "body": "as body-relative (found from the vehicle's tilt: a servo mount)",
                    "flags": "as its flags say (confirmed by the vehicle's tilt)",
                }.get(reading, "as its flags say (the vehicle did not tilt enough to tell)")
            )
        if self.first_t_unix_s is not None and self.last_t_unix_s is not None:
            a = datetime.fromtimestamp(self.first_t_unix_s, UTC).isoformat(timespec="seconds")
            b = datetime.fromtimestamp(self.last_t_unix_s, UTC).isoformat(timespec="seconds")
            lines.append(
                f"time span: {a} to {b} ({self.last_t_unix_s - self.first_t_unix_s:.1f} s)"
            )
        for t in self.targets.values():
            lines.append(
                f"bearing source: vehicle {t.sysid} target {t.target!r} from {t.source}: "
                f"{t.estimates} estimates, enough excitation "
                f"{100 * t.excited_share:.0f} % of the time, converged "
                f"{100 * t.converged_share:.0f} % of the time"
                + (
                    ""
                    if t.nis_mean is None
                    else f", innovations {t.nis_mean:.2f} times their expected size with the "
                    "noise in use (1 is consistent)"
                )
            )
            if t.noise is not None:
                nz = t.noise
                lines.append(
                    f"  noise: bearing {nz.bearing_noise_deg:.3g} deg "
                    f"({'learnt' if nz.bearing_noise_learnt else 'told'}), velocity "
                    f"{nz.velocity_noise_mps:.3g} m/s "
                    f"({'learnt' if nz.velocity_noise_learnt else 'told'}), bearing latency "
                    f"{1000 * nz.bearing_latency_s:.0f} ms "
                    f"({'learnt' if nz.bearing_latency_learnt else 'told'}), bias walk "
                    f"{nz.bias_walk_mps_per_sqrt_s:.2g} m/s/sqrt(s) "
                    f"({'learnt' if nz.bias_walk_learnt else 'told'}); "
                    f"{nz.outliers} of {nz.bearings} bearings down-weighted as gross errors; "
                    f"re-acquired {nz.reacquisitions} times"
                    + (f" ({nz.reacquiring_s:.1f} s re-acquiring)" if nz.reacquisitions else "")
                )
                lines.extend(_whiteness_lines(nz))
            for key, (t_s, tp, sd, fitted, windows) in self.smoothed_final.items():
                if key.split("#")[0] != f"{t.sysid}/{t.target}":
                    continue
                lines.append(
                    f"  smoothed over the whole log ({fitted} of {windows} windows fitted): "
                    f"target_pos_ned at t_boot {t_s:.2f} s "
                    f"[{', '.join(f'{v:.2f}' for v in tp)}] m, "
                    f"1 sigma [{', '.join(f'{v:.2f}' for v in sd)}] m"
                )
            if t.final is not None:
                e = t.final.estimate
                tp = t.final.target_pos_ned_m
                tp_txt = (
                    "unknown" if tp is None else "[" + ", ".join(f"{v:.2f}" for v in tp) + "] m"
                )
                lines.append(
                    f"  final estimate at t_boot {t.final.t_boot_s:.2f} s: rel_pos_ned "
                    f"[{', '.join(f'{v:.2f}' for v in e.x_m)}] m, range {e.range_m:.2f} m, bias "
                    f"[{', '.join(f'{v:.3f}' for v in e.a_mps)}] m/s, target_pos_ned {tp_txt}, "
                    f"status {e.status}"
                )
                geo = t.final.target_geodetic()
                if geo is not None and t.final.origin is not None:
                    lat, lon, alt, h_sd, v_sd = geo
                    sd_txt = (
                        "" if h_sd is None else f" +-{h_sd:.2f} m (1 sigma), alt +-{v_sd:.2f} m"
                    )
                    lines.append(
                        f"  on the map: {lat:.7f} {lon:.7f} {alt:.1f} m AMSL{sd_txt} "
                        f"(origin from {t.final.origin.source})"
                    )
        lines.append(
            f"estimates written: {self.estimates_written}; {self.messages_read} messages in "
            f"{self.wall_s:.2f} s ({self.messages_per_s:,.0f} messages/s)"
        )
        return "\n".join(lines)


def _whiteness_lines(nz: NoiseLevels) -> list[str]:
    """The summary's line on the innovations' lag-1 correlation (``NoiseLevels.innovation_corr``)
    with its warning, or none before it is known."""
    ic = nz.innovation_corr
    return [] if ic is None else [f"  {ic.describe()}"]
