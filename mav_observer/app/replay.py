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
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from mav_observer.app.replay_summary import ReplaySummary, Series, TargetSummary
from mav_observer.core.config import BEARING_NOISE_PRIOR_DEG
from mav_observer.errors import MavObserverError
from mav_observer.logs.formats import LogFormatError, LogReader, open_log
from mav_observer.logs.rawlink import RawLinkReader
from mav_observer.mavlink.dialect import MSG_ID
from mav_observer.mavlink.sources import is_file_source
from mav_observer.mavlink.tlog import TlogReader
from mav_observer.outputs.records import CSV_COLUMNS, EstimateRecord
from mav_observer.tracking.tracker import Tracker, TrackerConfig

if TYPE_CHECKING:  # imported where used: a replay without --smooth or a map does not load them
    pass

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
        try:
            reader: Any = open_log(source, _wanted(tracker))
        except (LogFormatError, OSError) as exc:
            raise ReplayError(f"{source}: {exc}", exit_code=3) from exc
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


def _wanted(tracker: Tracker) -> frozenset[int]:
    """The message ids to decode; with rays, SYSTEM_TIME too (their Unix time)."""
    ids = tracker.config.wanted_message_ids()
    return ids if tracker.rays is None else ids | {MSG_ID["SYSTEM_TIME"]}


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
    keep_report: bool = False,
    live: bool = False,
    rays_jsonl: Path | None = None,
) -> ReplaySummary:
    """Run a replay; raises :class:`ReplayError` (with an exit code) when it cannot, or when
    the source has no usable velocity or bearing stream. ``link``: how a live source is read
    (a file ignores it). ``smooth`` (or ``smooth_jsonl``): afterwards, every target's
    estimate from the whole log (:mod:`mav_observer.core.smoother`), in the summary and, one
    record per bearing, in ``smooth_jsonl`` (``docs/schema.md``). ``keep_report``: the
    summary's ``report`` for ``--html``. ``keep_map``: the
    summary's ``map_tracks`` for ``--geojson`` and ``--kml`` (:mod:`mav_observer.outputs.maps`).
    ``live``: each bearing's estimate at its arrival, as the service publishes it; by default
    (``TrackerConfig.publish = "auto"``) once the velocity after it is known
    (``docs/cli.md``). ``rays_jsonl``: every bearing used, as a geodetic ray
    (``docs/fleet.md``), one per line: what ``mav-observer fuse --rays`` fuses."""
    tc = tracker_config if tracker_config is not None else TrackerConfig()
    publish = "live" if live else "committed" if tc.publish == "auto" else tc.publish
    tracker = Tracker(replace(tc, publish=publish))
    if rays_jsonl is not None:
        tracker.rays = []
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
    report = None
    if keep_report:
        from mav_observer.outputs.html_report import ReportData

        report = summary.report = ReportData()
    attitude = tracker.vehicle_attitude
    if is_file_source(source):
        summary.bytes_total = Path(source).stat().st_size
    t0 = time.perf_counter()
    messages, reader = _messages(source, tracker, duration_s, link or LinkOptions())
    bar = _progress(progress and isinstance(reader, TlogReader), summary.bytes_total or None)
    try:
        with ExitStack() as stack:
            jsonl: TextIO | None = None
            writer: Any = None
            rays_fh: TextIO | None = None
            try:
                if rays_jsonl is not None:
                    rays_fh = stack.enter_context(open(rays_jsonl, "w", encoding="utf-8"))
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
                    if report is not None:
                        rpy = attitude(r.sysid, r.t_boot_s)
                        report.add(r, None if rpy is None else rpy[2])
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
                if rays_fh is not None and tracker.rays:
                    rays_fh.writelines(r.to_json() + "\n" for r in tracker.rays)
                    tracker.rays.clear()
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
    elif isinstance(reader, (LogReader, RawLinkReader)):
        st2 = reader.stats
        summary.log_format = st2.format
        summary.messages_read = st2.records
        summary.by_type = dict(st2.by_name.most_common())
        summary.damage = st2.damage()
        summary.log_notes = list(st2.notes)
        for reason, count in st2.decode_errors.items():
            summary.skipped[reason] = summary.skipped.get(reason, 0) + count
    else:
        summary.log_format = "link"
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
            f"{summary.source}: no messages found ({summary.log_format}: "
            + (", ".join(summary.log_notes) or "empty, or nothing readable")
            + ")",
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
