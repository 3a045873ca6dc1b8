"""``mav-observer replay``: the command around :func:`mav_observer.app.replay.replay` (its
outputs: the summary, the truth's comparison, the plot, the maps and the HTML report)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from mav_observer.app.cli import SETTING_FLAGS, estimation_overrides
from mav_observer.errors import ConfigError, MavObserverError


def _write_maps(args: argparse.Namespace, summary: Any, name: str) -> int:
    """Write ``--geojson`` and ``--kml``; 3 (nothing written) when no estimate had a place
    on the map (the log never gave the local frame's origin)."""
    if not (args.geojson or args.kml):
        return 0
    import json

    from mav_observer.outputs import maps as mapexport

    tracks = summary.map_tracks
    if not tracks:
        print(
            "mav-observer: no map written: no estimate has a place on the map (the log gives "
            "no GPS_GLOBAL_ORIGIN, HOME_POSITION, or GLOBAL_POSITION_INT at the time of a "
            "LOCAL_POSITION_NED; docs/geolocation.md)",
            file=sys.stderr,
        )
        return 3
    try:
        if args.geojson:
            args.geojson.write_text(json.dumps(mapexport.geojson(tracks)), encoding="utf-8")
        if args.kml:
            args.kml.write_text(mapexport.kml(tracks, name=name), encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot write the map: {exc}") from exc
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from mav_observer.app import reference
    from mav_observer.app import replay as rp
    from mav_observer.app import settings as st
    from mav_observer.mavlink import signing
    from mav_observer.outputs.report import plot_replay

    settings = st.resolve(args.config, estimation_overrides(args), SETTING_FLAGS)
    cfg = settings.tracker_config()
    m = settings.values["mavlink"]
    if args.source is None and args.config is None:
        raise ConfigError(
            "replay needs a SOURCE (a .tlog file or a connection string), or --config FILE "
            "whose [mavlink] url it reads"
        )
    source = args.source if args.source is not None else m["url"]
    key_file = m["signing_key_file"]
    link = rp.LinkOptions(
        heartbeat_period_s=m["heartbeat_period_s"],
        signing_key=None if key_file is None else signing.load_key(key_file),
        signing_link_id=m["signing_link_id"],
    )
    summary = rp.replay(
        source,
        link=link,
        tracker_config=cfg,
        output_jsonl=args.output,
        output_csv=args.csv,
        keep_series=bool(args.plot or args.truth or args.html),
        duration_s=args.duration,
        progress=not args.quiet and sys.stderr.isatty(),
        smooth=args.smooth is not None,
        smooth_jsonl=args.smooth if isinstance(args.smooth, Path) else None,
        keep_map=bool(args.geojson or args.kml or args.plot or args.html),
        keep_report=args.html is not None,
        live=args.live,
        rays_jsonl=args.rays,
    )
    map_status = _write_maps(args, summary, Path(source).name)
    errors = None
    if args.truth:
        track = reference.read(args.truth)
        errors = {k: reference.errors(s, track[k]) for k, s in summary.series.items() if k in track}
    if args.plot:
        plot_replay(
            summary.series,
            args.plot,
            title=Path(source).name,
            errors=errors,
            excitation_min=cfg.observer.excitation_min,
            events=summary.event_log,
            maps=summary.map_tracks,
        )
    if not args.quiet:
        print(summary.text())
        if errors:
            for key, err in errors.items():
                last = reference.last_third(err)
                print(
                    f"against truth, {key}, last third: worst position error "
                    f"{100 * last['max_rel_pos_err']:.2f} % of range, worst bias error "
                    f"{last['max_bias_err_mps']:.4f} m/s"
                )
                h = reference.honesty(err)
                if h["after_convergence"]:
                    n, u = h["after_convergence"], h["uncovered"]
                    print(
                        f"  after the first convergence: {u} of {n} estimates "
                        f"({100 * u / n:.1f} %) outside twice their sigma, worst error "
                        f"{h['worst_sigma_ratio']:.1f} sigma; error above 5 % of range for "
                        f"{h['time_above_s']:.1f} s ({100 * h['time_above_share']:.1f} % "
                        "of the span)"
                    )
    if args.html:
        _write_html(args, summary, Path(source).name, errors, cfg.observer.excitation_min)
    if args.summary_json:
        doc = summary.to_dict()
        if errors:
            doc["truth_last_third"] = {k: reference.last_third(e) for k, e in errors.items()}
            doc["truth_honesty"] = {k: reference.honesty(e) for k, e in errors.items()}
        args.summary_json.write_text(json.dumps(doc, indent=1))
    return map_status


def _write_html(
    args: argparse.Namespace, summary: Any, title: str, errors: Any, excitation_min: float
) -> None:
    """``replay --html``: the map report, with the report plot when matplotlib is there."""
    import tempfile

    from mav_observer.outputs.html_report import write_html
    from mav_observer.outputs.report import plot_replay

    png = None
    with tempfile.TemporaryDirectory() as tmp:
        try:
            plot_replay(summary.series, Path(tmp) / "p.png", title=title, errors=errors,
                        excitation_min=excitation_min, events=summary.event_log,
                        maps=summary.map_tracks)  # fmt: skip
            png = (Path(tmp) / "p.png").read_bytes()
        except ImportError:  # (matplotlib is optional: the report without its plot)
            png = None
    try:
        write_html(args.html, summary.report, title, summary.text(), png)
    except OSError as exc:
        raise MavObserverError(f"cannot write {args.html}: {exc}") from exc
