"""Replay: MAVLink from a tlog (or any connection) into estimates, files, a summary and a plot.

``mav-observer replay FLIGHT.tlog --output estimates.jsonl [--csv F] [--plot F] [--truth F]``
(``docs/cli.md``). A tlog is read as fast as the machine allows, decoding only the messages
the tracker uses; a connection string is read live (``--duration``).
"""

from __future__ import annotations

import csv
import json
import logging
import math
import sys
import time
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from mav_observer.core.config import BEARING_NOISE_PRIOR_DEG
from mav_observer.core.samples import NoiseLevels, Status
from mav_observer.errors import MavObserverError
from mav_observer.mavlink.sources import is_file_source
from mav_observer.mavlink.tlog import TlogReader
from mav_observer.outputs.records import CSV_COLUMNS, EstimateRecord
from mav_observer.tracking.tracker import Tracker, TrackerConfig

if TYPE_CHECKING:  # imported where used: a replay without --smooth or a map does not load them
    from mav_observer.core import smoother
    from mav_observer.outputs.maps import MapTracks

log = logging.getLogger(__name__)

BEARING_MESSAGES = (
    "GIMBAL_DEVICE_ATTITUDE_STATUS",
    "CAMERA_TRACKING_IMAGE_STATUS",
    "MOUNT_ORIENTATION",
    "MOUNT_STATUS",
    "LANDING_TARGET",
)


#: Version of the smoothed records (``replay --smooth``, ``docs/schema.md``).
SMOOTHED_SCHEMA = 1


class ReplayError(MavObserverError):
    """Replay could not run or found nothing to estimate from; the message says why."""

    def __init__(
        self, message: str, exit_code: int = 1, summary: ReplaySummary | None = None
    ) -> None:
        super().__init__(message)
        self.exit_code = exit_code
        #: what was read before giving up (counts, damage), when there was anything
        self.summary = summary


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
    #: with ``gimbal_angles = "auto"``: how each gimbal's angles were read in the end, by
    #: ``sysid/device id`` (``"flags"``, ``"body"``, or ``"auto"``: undecided, the flags)
    gimbal_angles: dict[str, str] = field(default_factory=dict)

    @property
    def messages_per_s(self) -> float:
        return self.messages_read / self.wall_s if self.wall_s > 0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "bytes": self.bytes_total,
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
        lines = [f"source: {self.source} ({self.bytes_total} bytes)"]
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


@dataclass(frozen=True)
class LinkOptions:
    """How a live source is read (the ``[mavlink]`` settings of the service): send a
    HEARTBEAT every ``heartbeat_period_s`` (``"auto"``: only on ``udpout:``; ``None``: never),
    and with a 32-byte ``signing_key`` refuse unsigned or wrongly signed frames."""

    heartbeat_period_s: float | str | None = "auto"
    signing_key: bytes | None = None
    signing_link_id: int = 0


def _messages(
    source: str, tracker: Tracker, duration_s: float | None, link: LinkOptions
) -> tuple[Iterator[tuple[float, Any]], Any]:
    if is_file_source(source):
        reader: Any = TlogReader(source, tracker.config.wanted_message_ids())
        return iter(reader), reader
    if Path(source).suffix in (".tlog", ".rlog") and not Path(source).exists():
        raise ReplayError(f"no such file: {source}")
    from mav_observer.mavlink.connection import ConnectionReader  # (a live source's alone)

    reader = ConnectionReader(
        source,
        duration_s=duration_s,
        heartbeat_period_s=link.heartbeat_period_s,
        signing_key=link.signing_key,
        signing_link_id=link.signing_link_id,
    )
    return iter(reader), reader


def _progress(enabled: bool, total: int | None) -> Any:
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # progress is a nicety
        return None
    return tqdm(total=total, unit="B", unit_scale=True, file=sys.stderr, leave=False)


def replay(
    source: str,
    *,
    tracker_config: TrackerConfig | None = None,
    output_jsonl: Path | None = None,
    output_csv: Path | None = None,
    keep_series: bool = False,
    duration_s: float | None = None,
    progress: bool = False,
    link: LinkOptions | None = None,
    smooth: bool = False,
    smooth_jsonl: Path | None = None,
    smooth_window_s: float | None = None,
    keep_map: bool = False,
    live: bool = False,
) -> ReplaySummary:
    """Run a replay; raises :class:`ReplayError` (with an exit code) when it cannot, or when
    the source has no usable velocity or bearing stream. ``link``: how a live source is read
    (a file ignores it). ``smooth`` (or ``smooth_jsonl``): afterwards, every target's
    estimate from the whole log (:mod:`mav_observer.core.smoother`), in the summary and, one
    record per bearing, in ``smooth_jsonl`` (``docs/schema.md``). ``keep_map``: the
    summary's ``map_tracks`` for ``--geojson`` and ``--kml`` (:mod:`mav_observer.outputs.maps`).
    ``live``: each bearing's estimate at its arrival, as the service publishes it; by default
    (``TrackerConfig.publish = "auto"``) once the velocity after it is known
    (``docs/cli.md``)."""
    tc = tracker_config if tracker_config is not None else TrackerConfig()
    publish = "live" if live else "committed" if tc.publish == "auto" else tc.publish
    tracker = Tracker(replace(tc, publish=publish))
    smooth = smooth or smooth_jsonl is not None
    if smooth:
        from mav_observer.core import smoother

        tracker.sample_log = smoother.SampleLog()
    exc_min = tracker.config.observer.excitation_min
    summary = ReplaySummary(source=source)
    if keep_map:
        from mav_observer.outputs.maps import MapTracks

        summary.map_tracks = MapTracks()
    map_tracks = summary.map_tracks
    if is_file_source(source):
        summary.bytes_total = Path(source).stat().st_size
    t0 = time.perf_counter()
    messages, reader = _messages(source, tracker, duration_s, link or LinkOptions())
    bar = _progress(progress and isinstance(reader, TlogReader), summary.bytes_total or None)
    try:
        with ExitStack() as stack:
            jsonl: TextIO | None = None
            writer: Any = None
            try:
                if output_jsonl is not None:
                    jsonl = stack.enter_context(open(output_jsonl, "w", encoding="utf-8"))
                if output_csv is not None:
                    fh = stack.enter_context(open(output_csv, "w", encoding="utf-8", newline=""))
                    writer = csv.writer(fh)
                    writer.writerow(CSV_COLUMNS)
            except OSError as exc:
                raise ReplayError(f"cannot write output: {exc}") from exc
            targets = summary.targets
            handle = tracker.handle
            is_tlog = isinstance(reader, TlogReader)

            def sink(records: list[EstimateRecord]) -> None:
                for r in records:
                    key = f"{r.sysid}/{r.target}"
                    ts = targets.get(key)
                    if ts is None:
                        ts = targets[key] = TargetSummary(r.sysid, r.target, r.source)
                    ts.add(r, exc_min)
                    if jsonl is not None:
                        jsonl.write(r.to_json())
                        jsonl.write("\n")
                    if writer is not None:
                        writer.writerow(r.csv_row())
                    if keep_series:
                        summary.series.setdefault(key, Series()).add(r)
                    if map_tracks is not None:
                        map_tracks.add(r)
                    summary.estimates_written += 1

            for n, (t, msg) in enumerate(messages, 1):
                records = handle(t, msg)
                if n % 4096 == 0:
                    if is_tlog:
                        reader.drop(tracker.redundant_message_ids())
                    if bar is not None:
                        bar.update(reader.position - bar.n)
                if records:
                    sink(records)
            sink(tracker.flush())  # bearings still waiting for an attitude at the end
    except OSError as exc:  # a full disk, a file system gone read-only, while writing
        raise ReplayError(f"cannot write output: {exc}") from exc
    if bar is not None:
        bar.close()
    summary.wall_s = time.perf_counter() - t0
    summary.used = dict(tracker.used.most_common())
    summary.skipped = dict(tracker.skipped.most_common())
    summary.events = {k: v for k, v in tracker.events.items() if k != "targets"}
    summary.event_log = list(tracker.event_log)
    for ts in summary.targets.values():
        obs = tracker.observer(ts.sysid, ts.target)
        ts.noise = None if obs is None else obs.noise()
    summary.gimbal_angles = {
        f"{sysid}/{dev}": reading
        for sysid in sorted(tracker.vehicles)
        for dev, reading in tracker.gimbal_angles(sysid).items()
    }
    if isinstance(reader, TlogReader):
        st = reader.stats
        summary.messages_read = st.records
        summary.by_type = st.by_name()
        summary.damage = st.damage()
        summary.first_t_unix_s, summary.last_t_unix_s = st.first_t_unix_s, st.last_t_unix_s
        for reason, count in st.decode_errors.items():
            summary.skipped[reason] = summary.skipped.get(reason, 0) + count
    else:
        summary.messages_read = sum(reader.counts.values())
        summary.by_type = dict(reader.counts.most_common())
    _check_usable(summary, tracker)
    if smooth:
        _smooth(summary, tracker, smooth_jsonl, smooth_window_s)
    return summary


def _smooth(
    summary: ReplaySummary, tracker: Tracker, path: Path | None, window_s: float | None
) -> None:
    """The smoother over every target's track (windows of ``window_s``, s; ``None``: the
    smoother's :data:`~mav_observer.core.smoother.WINDOW_S`); its records to ``path``."""
    from mav_observer.core import smoother

    if window_s is None:
        window_s = smoother.WINDOW_S
    log_ = tracker.sample_log
    if log_ is None:
        return
    try:
        with ExitStack() as stack:
            fh: TextIO | None = None
            if path is not None:
                fh = stack.enter_context(open(path, "w", encoding="utf-8"))
            for sysid, target, epoch in log_.tracks():
                data = log_.data(sysid, target, epoch)
                if data is None:
                    continue
                tb, y, tv, pos, vel = data
                obs = tracker.observer(sysid, target)
                nz = None if obs is None else obs.noise()
                sigma = math.radians(
                    nz.bearing_noise_deg if nz is not None else BEARING_NOISE_PRIOR_DEG
                )
                res = smoother.smooth(tb, y, tv, vel, pos, sigma_rad=sigma, window_s=window_s)
                key = f"{sysid}/{target}"
                if epoch:
                    key += f"#{epoch}"
                summary.smoothed[key] = res
                std = res.rel_pos_std_ned_m
                vpos = np.column_stack([np.interp(tb, tv, pos[:, i]) for i in range(3)])
                ok = np.flatnonzero(res.window >= 0)
                if len(ok):
                    k = int(ok[-1])
                    summary.smoothed_final[key] = (
                        float(tb[k]),
                        (vpos[k] + res.rel_pos_ned_m[k]).tolist(),
                        std[k].tolist(),
                        sum(f[2] is not None for f in res.fits),
                        len(res.fits),
                    )
                if fh is None:
                    continue
                bstd = np.sqrt(np.diagonal(res.bias_cov_m2ps2, axis1=1, axis2=2))
                for k in range(len(tb)):
                    if res.window[k] < 0:
                        continue
                    x = res.rel_pos_ned_m[k]
                    s, e, _, _ = res.fits[res.window[k]]
                    rec = {
                        "schema": SMOOTHED_SCHEMA,
                        "t_boot_s": float(tb[k]),
                        "sysid": sysid,
                        "target": target,
                        "epoch": epoch,
                        "rel_pos_ned_m": x.tolist(),
                        "range_m": float(np.linalg.norm(x)),
                        "rel_pos_std_ned_m": std[k].tolist(),
                        "bias_ned_mps": res.bias_ned_mps[k].tolist(),
                        "bias_std_ned_mps": bstd[k].tolist(),
                        "target_pos_ned_m": (vpos[k] + x).tolist(),
                        "vehicle_pos_ned_m": vpos[k].tolist(),
                        "window_s": [s, e],
                    }
                    fh.write(json.dumps(rec, separators=(",", ":")))
                    fh.write("\n")

    except OSError as exc:
        raise ReplayError(f"cannot write output: {exc}") from exc


def _check_usable(summary: ReplaySummary, tracker: Tracker) -> None:
    found = (
        ", ".join(f"{k} {v}" for k, v in summary.by_type.items()) or "no MAVLink messages at all"
    )
    if summary.messages_read == 0:
        raise ReplayError(
            f"{summary.source}: no MAVLink messages found (not a tlog, or empty)",
            exit_code=3,
            summary=summary,
        )
    problems = []
    if not tracker.used.get("LOCAL_POSITION_NED"):
        problems.append("no usable velocity stream (LOCAL_POSITION_NED)")
    if not summary.targets:
        wanted = sorted(tracker.enabled)
        problems.append(
            f"no usable bearing stream for the sources {wanted} "
            f"({', '.join(BEARING_MESSAGES)}, or HOME_POSITION for 'home')"
        )
    if problems:
        skipped = ", ".join(f"{k} {v}" for k, v in summary.skipped.items()) or "none"
        raise ReplayError(
            f"{summary.source}: " + "; ".join(problems) + f".\nThe log has: {found}.\n"
            f"Skipped messages by reason: {skipped}.",
            exit_code=3,
            summary=summary,
        )


def _whiteness_lines(nz: NoiseLevels) -> list[str]:
    """The summary's line on the innovations' lag-1 correlation (``NoiseLevels.innovation_corr``)
    with its warning, or none before it is known."""
    ic = nz.innovation_corr
    return [] if ic is None else [f"  {ic.describe()}"]
