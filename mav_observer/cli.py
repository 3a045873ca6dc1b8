"""The ``mav-observer`` command.

Sub-commands:

* ``demo``: run a simulated scenario through the observer and print the estimate
  converging to the truth (the simulator lives in the separate ``sim`` package and runs as
  its own process, ``python -m sim demo``; ``mav_observer`` never imports it).
* ``replay SOURCE``: replay a tlog (or read a live connection) into estimates, files, a
  summary and a plot (``docs/cli.md``).
* ``version``: print the version.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from mav_observer import __version__
from mav_observer.errors import MavObserverError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mav-observer",
        description="Estimate a target's relative position and the velocity bias from "
        "bearings and the vehicle's velocity.",
    )
    parser.add_argument("--version", action="version", version=f"mav-observer {__version__}")
    parser.add_argument(
        "--log-level", default="WARNING", choices=("DEBUG", "INFO", "WARNING", "ERROR")
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser(
        "demo",
        help="run a simulated scenario and show the estimate converging "
        "(options: mav-observer demo --help)",
    )
    rp = sub.add_parser(
        "replay",
        help="replay a tlog (or a live connection) into estimates, files and a report",
        description="Replay FLIGHT.tlog (or any pymavlink connection string) into estimate "
        "records; prints a summary. Exit status 3 when the source has no usable velocity or "
        "bearing stream.",
    )
    rp.add_argument("source", help="a .tlog file, or udpin:127.0.0.1:14550, tcp:..., DEVICE,BAUD")
    rp.add_argument("--output", "-o", type=Path, help="estimate records, JSON Lines")
    rp.add_argument("--csv", type=Path, help="estimate records, CSV")
    rp.add_argument("--plot", type=Path, help="report figure (PNG; needs matplotlib)")
    rp.add_argument("--truth", type=Path, help="the emitter's truth file (JSON Lines): errors too")
    rp.add_argument("--summary-json", type=Path, help="write the summary as JSON")
    rp.add_argument(
        "--sources",
        default="auto",
        help="bearing sources, comma separated: auto, gimbal, camera, mount, mount_status, "
        "landing_target, home (synthetic, for validation)",
    )
    rp.add_argument(
        "--gimbal-angles",
        choices=("flags", "body"),
        default="flags",
        help="gimbal quaternion: as its flags say, or relative to the body (servo mounts)",
    )
    rp.add_argument("--mount-status-yaw", choices=("vehicle", "earth"), default="vehicle")
    rp.add_argument("--landing-target-orientation", choices=("down", "forward"), default="down")
    rp.add_argument("--landing-target-yaw-align-deg", type=float, default=0.0)
    rp.add_argument("--camera-fov-deg", type=float, nargs=2, metavar=("H", "V"))
    rp.add_argument("--sysid", type=int, action="append", help="only this vehicle (repeatable)")
    rp.add_argument("--k", type=float, help="observer gain k (1/s)")
    rp.add_argument("--k-star", type=float, help="observer gain k* (1/s)")
    rp.add_argument(
        "--initial-range-m", type=float, help="start on the first bearing at this range"
    )
    rp.add_argument("--duration", type=float, help="seconds to read a live connection")
    rp.add_argument("--quiet", "-q", action="store_true", help="no progress bar, no summary")
    sub.add_parser("version", help="print the version")
    return parser


def _tracker_config(args: argparse.Namespace):
    from mav_observer.mavlink.tracker import TrackerConfig
    from mav_observer.observer import ObserverConfig

    obs: dict[str, object] = {}
    if args.k is not None:
        obs["k_per_s"] = args.k
    if args.k_star is not None:
        obs["k_star_per_s"] = args.k_star
    if args.initial_range_m is not None:
        obs["initial_range_m"] = args.initial_range_m
    fov = args.camera_fov_deg or (None, None)
    return TrackerConfig(
        sources=tuple(s.strip() for s in args.sources.split(",") if s.strip()),
        gimbal_angles=args.gimbal_angles,
        mount_status_yaw=args.mount_status_yaw,
        landing_target_orientation=args.landing_target_orientation,
        landing_target_yaw_align_deg=args.landing_target_yaw_align_deg,
        camera_hfov_deg=fov[0],
        camera_vfov_deg=fov[1],
        sysids=tuple(args.sysid) if args.sysid else None,
        observer=ObserverConfig(**obs),  # type: ignore[arg-type]
    )


def cmd_replay(args: argparse.Namespace) -> int:
    import json

    from mav_observer import replay as rp
    from mav_observer.report import plot_replay

    cfg = _tracker_config(args)
    summary = rp.replay(
        args.source,
        tracker_config=cfg,
        output_jsonl=args.output,
        output_csv=args.csv,
        keep_series=bool(args.plot or args.truth),
        duration_s=args.duration,
        progress=not args.quiet and sys.stderr.isatty(),
    )
    errors = None
    if args.truth:
        truth = rp.read_truth(args.truth)
        errors = {k: rp.truth_errors(s, truth[k]) for k, s in summary.series.items() if k in truth}
    if args.plot:
        plot_replay(
            summary.series,
            args.plot,
            title=Path(args.source).name,
            errors=errors,
            excitation_min=cfg.observer.excitation_min,
        )
    if not args.quiet:
        print(summary.text())
        if errors:
            for key, err in errors.items():
                last = rp.last_third_errors(err)
                print(
                    f"against truth, {key}, last third: worst position error "
                    f"{100 * last['max_rel_pos_err']:.2f} % of range, worst bias error "
                    f"{last['max_bias_err_mps']:.4f} m/s"
                )
    if args.summary_json:
        doc = summary.to_dict()
        if errors:
            doc["truth_last_third"] = {k: rp.last_third_errors(e) for k, e in errors.items()}
        args.summary_json.write_text(json.dumps(doc, indent=1))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "demo":
        # the simulator is a separate program: run it as a child process, options passed on
        try:
            return subprocess.call([sys.executable, "-m", "sim", "demo", *argv[1:]])
        except KeyboardInterrupt:
            return 130
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(levelname)s %(name)s: %(message)s")
    if args.command == "version":
        print(f"mav-observer {__version__}")
        return 0
    try:
        if args.command == "replay":
            return cmd_replay(args)
    except MavObserverError as exc:
        summary = getattr(exc, "summary", None)
        if summary is not None and not getattr(args, "quiet", False):
            print(summary.text())
        print(f"mav-observer: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", 1)
    except FileNotFoundError as exc:
        print(f"mav-observer: no such file: {exc.filename}", file=sys.stderr)
        return 1
    except PermissionError as exc:
        print(f"mav-observer: permission denied: {exc.filename}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
