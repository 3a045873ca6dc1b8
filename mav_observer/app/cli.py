"""The ``mav-observer`` command.

Sub-commands:

* ``run``: the service: MAVLink in, estimates out over Zenoh, until stopped
  (``docs/service.md``).
* ``listen [KEY_EXPR]``: print what a running service publishes.
* ``map``: the live map of what a running service publishes, over Zenoh
  (:mod:`mav_observer.app.map_cmd`).
* ``demo``: the emitter, the service and a subscriber on loopback, with a live table of
  estimate against truth until converged (the simulator lives in the separate ``sim``
  package and runs as its own process, ``python -m sim live``; ``mav_observer`` never
  imports it).
* ``replay SOURCE``: replay a flight log (or read a live connection) into estimates, files, a
  summary, a plot and maps (``docs/cli.md``; :mod:`mav_observer.app.replay_cmd`).
* ``fuse``: one target seen by several vehicles, from their rays over Zenoh or from ray
  files (:mod:`mav_observer.app.fuse_cmd`, ``docs/fleet.md``).
* ``router``: Zenoh's router joining the processes of several machines
  (:mod:`mav_observer.app.router_cmd`).
* ``version``: print the version.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mav_observer import __version__
from mav_observer.errors import ConfigError, MavObserverError

#: The commands whose module ``mav_observer.app.{name}_cmd`` holds ``cmd_{name}``.
LAZY_COMMANDS = ("replay", "map", "fuse", "router")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mav-observer",
        description="Estimate a target's relative position and the velocity bias from "
        "bearings and the vehicle's velocity.",
    )
    parser.add_argument("--version", action="version", version=f"mav-observer {__version__}")
    parser.add_argument(
        "--log-level",
        default=None,
        choices=("DEBUG", "INFO", "WARNING", "ERROR"),
        help="default: WARNING, or the settings' log.level for run",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser(
        "demo",
        help="the emitter, the service and a subscriber on loopback: a live table of "
        "estimate against truth until converged (options: mav-observer demo --help)",
    )
    rp = sub.add_parser(
        "replay",
        help="replay a tlog (or a live connection) into estimates, files and a report",
        description="Replay FLIGHT.tlog (or any pymavlink connection string) into estimate "
        "records; prints a summary. Exit status 3 when the source has no usable velocity or "
        "bearing stream.",
    )
    rp.add_argument(
        "source",
        nargs="?",
        help="a .tlog file, or udpin:127.0.0.1:14550, tcp:..., DEVICE,BAUD (default: the "
        "settings' [mavlink] url)",
    )
    rp.add_argument("--output", "-o", type=Path, help="estimate records, JSON Lines")
    rp.add_argument("--csv", type=Path, help="estimate records, CSV")
    rp.add_argument("--plot", type=Path, help="report figure (PNG; needs matplotlib)")
    rp.add_argument(
        "--geojson",
        type=Path,
        help="the vehicle's track and the target's estimates with their uncertainty on the map "
        "(GeoJSON, docs/geolocation.md)",
    )
    rp.add_argument("--kml", type=Path, help="the same as KML (Google Earth, QGIS)")
    rp.add_argument(
        "--html",
        type=Path,
        help="a map report: one HTML file that opens from disk (the tracks, the estimates over "
        "time with a slider and their sigma ellipses, the summary, the plot)",
    )
    rp.add_argument(
        "--truth", type=Path, help="a reference track, JSON Lines (docs/schema.md): errors too"
    )
    rp.add_argument(
        "--smooth",
        nargs="?",
        type=Path,
        const=True,
        default=None,
        metavar="FILE",
        help="afterwards, every estimate from the whole log (batch fits on windows): the "
        "post-flight answer, in the summary and, given FILE, one record per bearing (JSON "
        "Lines, docs/schema.md)",
    )
    rp.add_argument(
        "--live",
        action="store_true",
        help="publish what the service would have, each bearing's estimate at its arrival "
        "(the default: once the velocity after it is known, interpolated; docs/cli.md)",
    )
    rp.add_argument(
        "--rays",
        type=Path,
        help="every bearing used as a geodetic ray, JSON Lines (docs/fleet.md): what "
        "`mav-observer fuse --rays` fuses across vehicles after the flight",
    )
    rp.add_argument("--summary-json", type=Path, help="write the summary as JSON")
    rp.add_argument(
        "--config",
        type=Path,
        help="settings file (TOML), the same as run's: its [observer] and [tracker] tables "
        "are used, the service-only ones checked and ignored",
    )
    add_estimation_flags(rp)
    rp.add_argument("--duration", type=float, help="seconds to read a live connection")
    rp.add_argument("--quiet", "-q", action="store_true", help="no progress bar, no summary")
    _add_run_parser(sub)
    _add_listen_parser(sub)
    from mav_observer.app import map_cmd

    map_cmd.add_parser(sub)
    from mav_observer.app import fuse_cmd, router_cmd

    fuse_cmd.add_parser(sub)
    router_cmd.add_parser(sub)
    sub.add_parser("version", help="print the version")
    return parser


def _add_run_parser(sub: Any) -> None:
    run = sub.add_parser(
        "run",
        help="the service: read MAVLink, publish estimates over Zenoh until stopped",
        description="Read MAVLink telemetry, run one observer per vehicle and target and "
        "publish estimates and status over Zenoh until SIGTERM or SIGINT. Settings: defaults, "
        "then --config FILE (TOML), then these flags (docs/service.md).",
    )
    run.add_argument("--config", type=Path, help="settings file (TOML)")
    run.add_argument(
        "--print-config", action="store_true", help="print the effective settings and exit"
    )
    run.add_argument("--mavlink", help="MAVLink source (default udpin:127.0.0.1:14550)")
    run.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file")
    run.add_argument("--zenoh-mode", choices=("peer", "client", "router"))
    run.add_argument(
        "--zenoh-listen",
        action="append",
        metavar="ENDPOINT",
        help="listen on this endpoint (repeatable; default tcp/127.0.0.1:7447)",
    )
    run.add_argument(
        "--zenoh-connect", action="append", metavar="ENDPOINT", help="connect (repeatable)"
    )
    run.add_argument("--prefix", help="key expression prefix (default mav_observer)")
    run.add_argument("--estimate-rate-hz", type=float, help="most estimates/s per target, 0: all")
    run.add_argument("--stale-after-s", type=float, help="no data for this long: stale")
    run.add_argument("--state-file", help="save and restore the observers here")
    run.add_argument(
        "--signing-key-file",
        help="MAVLink 2 signing: a file holding the key (64 hex digits) or a passphrase",
    )
    run.add_argument(
        "--mavlink-out",
        metavar="URL",
        help="send converged estimates back over MAVLink (LANDING_TARGET, STATUSTEXT) to URL; "
        "'input': over the input connection (docs/geolocation.md)",
    )
    run.add_argument(
        "--web",
        metavar="HOST:PORT",
        help="a live map in the browser at http://HOST:PORT/ (127.0.0.1:8765, say; another "
        "address than loopback is your explicit choice) (docs/service.md)",
    )
    run.add_argument(
        "--web-tiles",
        metavar="URL",
        help="a tile layer for the map once the origin is known ({z}/{x}/{y} URL); default: "
        "none, a metric grid in the local frame (offline)",
    )
    add_estimation_flags(run)
    run.add_argument("--duration", type=float, help="stop after this many seconds")
    run.add_argument(
        "--log-level", dest="run_log_level", choices=("DEBUG", "INFO", "WARNING", "ERROR")
    )


def _add_listen_parser(sub: Any) -> None:
    ls = sub.add_parser(
        "listen",
        help="print what a running service publishes",
        description="Subscribe to KEY_EXPR (default mav_observer/**) and print estimates, "
        "status and liveliness changes as a table or JSON lines.",
    )
    ls.add_argument("key_expr", nargs="?", default="mav_observer/**")
    add_zenoh_client_args(ls, wait_s=10.0)
    ls.add_argument("--json", action="store_true", help="JSON lines instead of a table")
    ls.add_argument("--count", type=int, help="stop after this many samples")
    ls.add_argument("--duration", type=float, help="stop after this many seconds")


def add_zenoh_client_args(p: argparse.ArgumentParser, wait_s: float) -> None:
    """How a command that reads a running service reaches it over Zenoh (``listen``, ``map``)."""
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="where the service (or a router) listens (default tcp/127.0.0.1:7447)",
    )
    p.add_argument("--mode", choices=("peer", "client"), default="peer")
    p.add_argument("--zenoh-config", help="a Zenoh JSON5 configuration file")
    p.add_argument(
        "--wait-s",
        type=float,
        default=wait_s,
        help="keep trying to reach the service (or the router) this long",
    )


def zenoh_client_session(args: argparse.Namespace) -> Any:
    """The Zenoh session of :func:`add_zenoh_client_args`' options: no scouting, no listening
    (unless a configuration file says otherwise), connecting to ``--connect``."""
    from mav_observer.outputs import zenoh_io

    connect = args.connect or (None if args.zenoh_config else [zenoh_io.DEFAULT_ENDPOINT])
    conf = zenoh_io.session_config(
        config_file=args.zenoh_config,
        mode=args.mode,
        listen=None if args.zenoh_config else [],
        connect=connect,
    )
    return zenoh_io.open_session(conf, retry_s=args.wait_s)


def _number_or_auto(text: str) -> float | str:
    """``auto`` or a number, for the noise flags (the settings file's own check)."""
    from mav_observer.app.setting_checks import number_or_auto

    try:
        return number_or_auto(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: The observer flags of run and replay: ``(flag, settings key, type, help)``. A flag for
#: the estimator not chosen is an error (:func:`mav_observer.app.settings.check_estimator_keys`).
OBSERVER_FLAGS = (
    ("--estimator", "estimator", str, "riccati (default) or paper"),
    (
        "--bearing-noise-deg",
        "bearing_noise_deg",
        _number_or_auto,
        "bearing noise, 1 sigma (deg), or auto: learnt online (default; riccati)",
    ),
    (
        "--velocity-noise-mps",
        "velocity_noise_mps",
        _number_or_auto,
        "white velocity noise (m/s), or auto: learnt online (default; riccati)",
    ),
    (
        "--bias-walk",
        "bias_walk_mps_per_sqrt_s",
        _number_or_auto,
        "bias random walk (m/s/sqrt s; 0: constant), or auto: learnt online (riccati, default)",
    ),
    (
        "--bearing-latency-s",
        "bearing_latency_s",
        _number_or_auto,
        "how long the bearings trail the line of sight (s), or auto: learnt online (default; "
        "riccati)",
    ),
    ("--initial-range-m", "initial_range_m", float, "first range guess (m)"),
    ("--k", "k_per_s", float, "gain k (1/s; paper)"),
    ("--k-star", "k_star_per_s", float, "gain k* (1/s; paper)"),
)


def add_estimation_flags(p: argparse.ArgumentParser) -> None:
    """The flags of the observer and tracker settings users tune, for run and replay (each
    overrides the settings file's value; unset: the file's, else the default)."""
    for flag, _key, typ, help_ in OBSERVER_FLAGS:
        p.add_argument(flag, type=typ, help=help_)
    p.add_argument(
        "--sources",
        help="bearing sources, comma separated: auto (default), gimbal, camera, mount, "
        "mount_status, landing_target, home (synthetic, for validation)",
    )
    p.add_argument(
        "--gimbal-angles",
        choices=("auto", "flags", "body"),
        help="gimbal quaternion: as its flags say until the data show it body-relative "
        "(auto, the default), as its flags say, or relative to the body (servo mounts)",
    )
    p.add_argument("--mount-status-yaw", choices=("vehicle", "earth"))
    p.add_argument("--landing-target-orientation", choices=("down", "forward"))
    p.add_argument("--landing-target-yaw-align-deg", type=float)
    p.add_argument("--camera-fov-deg", type=float, nargs=2, metavar=("H", "V"))
    p.add_argument("--sysid", type=int, action="append", help="only this vehicle (repeatable)")


def estimation_overrides(args: argparse.Namespace) -> dict[str, dict[str, object]]:
    """The observer and tracker flags given, as a settings layer."""
    o: dict[str, dict[str, object]] = {}

    def put(section: str, key: str, value: object) -> None:
        if value is not None:
            o.setdefault(section, {})[key] = value

    for flag, key, _typ, _help in OBSERVER_FLAGS:
        put("observer", key, getattr(args, flag.lstrip("-").replace("-", "_")))
    if args.sources is not None:
        put("tracker", "sources", [x.strip() for x in args.sources.split(",") if x.strip()])
    put("tracker", "gimbal_angles", args.gimbal_angles)
    put("tracker", "mount_status_yaw", args.mount_status_yaw)
    put("tracker", "landing_target_orientation", args.landing_target_orientation)
    put("tracker", "landing_target_yaw_align_deg", args.landing_target_yaw_align_deg)
    if args.camera_fov_deg:
        put("tracker", "camera_hfov_deg", args.camera_fov_deg[0])
        put("tracker", "camera_vfov_deg", args.camera_fov_deg[1])
    put("tracker", "sysids", args.sysid)
    return o


#: ``"section.key" -> flag`` of every settings flag, so that an error names the flag.
SETTING_FLAGS: dict[str, str] = {
    **{f"observer.{key}": flag for flag, key, _typ, _help in OBSERVER_FLAGS},
    "tracker.sources": "--sources",
    "tracker.gimbal_angles": "--gimbal-angles",
    "tracker.mount_status_yaw": "--mount-status-yaw",
    "tracker.landing_target_orientation": "--landing-target-orientation",
    "tracker.landing_target_yaw_align_deg": "--landing-target-yaw-align-deg",
    "tracker.camera_hfov_deg": "--camera-fov-deg",
    "tracker.camera_vfov_deg": "--camera-fov-deg",
    "tracker.sysids": "--sysid",
    "mavlink.url": "--mavlink",
    "mavlink.stale_after_s": "--stale-after-s",
    "mavlink.signing_key_file": "--signing-key-file",
    "mavlink.out": "--mavlink-out",
    "mavlink.out_url": "--mavlink-out",
    "zenoh.config_file": "--zenoh-config",
    "zenoh.mode": "--zenoh-mode",
    "zenoh.listen": "--zenoh-listen",
    "zenoh.connect": "--zenoh-connect",
    "zenoh.prefix": "--prefix",
    "zenoh.estimate_max_rate_hz": "--estimate-rate-hz",
    "state.file": "--state-file",
    "log.level": "--log-level",
}


def run_overrides(args: argparse.Namespace) -> dict[str, dict[str, object]]:
    """The ``run`` flags as a settings layer (only those given)."""
    o = estimation_overrides(args)

    def put(section: str, key: str, value: object) -> None:
        if value is not None:
            o.setdefault(section, {})[key] = value

    put("mavlink", "url", args.mavlink)
    put("mavlink", "stale_after_s", args.stale_after_s)
    put("mavlink", "signing_key_file", args.signing_key_file)
    if args.mavlink_out is not None:
        put("mavlink", "out", True)
        if args.mavlink_out != "input":
            put("mavlink", "out_url", args.mavlink_out)
    put("zenoh", "config_file", args.zenoh_config)
    put("zenoh", "mode", args.zenoh_mode)
    put("zenoh", "listen", args.zenoh_listen)
    put("zenoh", "connect", args.zenoh_connect)
    put("zenoh", "prefix", args.prefix)
    put("zenoh", "estimate_max_rate_hz", args.estimate_rate_hz)
    put("state", "file", args.state_file)
    put("log", "level", args.run_log_level or args.log_level)
    return o


def cmd_run(args: argparse.Namespace) -> int:
    import signal

    from mav_observer.app import settings as st
    from mav_observer.app.service import Service
    from mav_observer.outputs import zenoh_io

    settings = st.resolve(args.config, run_overrides(args), SETTING_FLAGS)
    if args.print_config:
        print(settings.to_toml(), end="")
        return 0
    logging.getLogger().setLevel(settings["log"]["level"])
    # the estimator loaded (compiled on a machine's first run) before the service shows itself
    # on Zenoh or binds its MAVLink port: nothing waits on it once it is there
    from mav_observer.core import compiled

    compiled.kernels()
    z = settings["zenoh"]
    conf = zenoh_io.session_config(
        config_file=z["config_file"], mode=z["mode"], listen=z["listen"], connect=z["connect"]
    )
    web = web_server(args.web, args.web_tiles)
    session = zenoh_io.open_session(conf)
    try:
        service = Service.from_settings(settings, session)
        if web is not None:
            service.web = web.feed
            follow_fused(session, z["prefix"], web.feed)
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: service.stop())
        logging.getLogger("mav_observer.app.service").info(
            "zenoh %s session, listening on %s, connecting to %s",
            json.loads(conf.get_json("mode")),
            conf.get_json("listen/endpoints"),
            conf.get_json("connect/endpoints"),
        )
        service.run(duration_s=args.duration)
    finally:
        session.close()
        if web is not None:
            web.close()
    return 0


def follow_fused(session: Any, prefix: str, feed: Any) -> Any:
    """Give the live map's ``feed`` every fused target ``mav-observer fuse`` publishes under
    ``prefix`` (the subscriber; it ends with the session)."""

    def on_fused(sample: Any) -> None:
        feed.add_fused(sample.payload.to_bytes().decode("utf-8", "replace"))

    return session.declare_subscriber(f"{prefix}/fused/*", on_fused)


def web_server(listen: str | None, tiles: str | None) -> Any:
    """The live map's server on ``HOST:PORT`` (started), or ``None``; a bad address is a
    :class:`ConfigError` naming it."""
    if listen is None:
        return None
    from mav_observer.outputs.web import MapFeed, MapServer

    host, _, port = listen.rpartition(":")
    if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(f"--web must be HOST:PORT, got {listen!r}")
    if host not in ("127.0.0.1", "localhost", "::1"):
        logging.getLogger("mav_observer.app.service").warning(
            "the live map listens on %s: reachable from other machines", host
        )
    try:
        return MapServer(MapFeed(), host, int(port), tiles).start()
    except OSError as exc:
        raise ConfigError(f"--web {listen}: cannot listen there ({exc})") from exc


def cmd_listen(args: argparse.Namespace) -> int:
    import signal
    import threading

    from mav_observer.app.listen import listen

    session = zenoh_client_session(args)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        listen(
            session,
            args.key_expr,
            out=sys.stdout,
            json_lines=args.json,
            count=args.count,
            duration_s=args.duration,
            should_stop=stop.is_set,
        )
    except BrokenPipeError:
        pass  # the reader of our output went away (listen | head)
    finally:
        session.close()
    return 0


#: Threads of numpy's BLAS (OpenBLAS) unless the environment says otherwise: the estimator's
#: matrices are 3x3 to 8x8, which OpenBLAS does not split, and starting its threads (one a
#: core) slows a replay's start-up. Set before numpy is first imported, which ``import
#: mav_observer`` must therefore not do.
BLAS_THREADS = "1"


def main(argv: Sequence[str] | None = None) -> int:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", BLAS_THREADS)
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "demo":
        # the simulator is a separate program: run it as a child process, options passed on
        try:
            import subprocess  # (the demo's alone: its import is not a replay's start-up)

            return subprocess.call([sys.executable, "-m", "sim", "live", *argv[1:]])
        except KeyboardInterrupt:
            return 130
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=args.log_level or "WARNING",
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    if args.command == "version":
        print(f"mav-observer {__version__}")
        return 0
    try:
        if args.command == "run":
            return cmd_run(args)
        if args.command == "listen":
            return cmd_listen(args)
        if args.command in LAZY_COMMANDS:  # imported when used: each start stays light
            module = importlib.import_module(f"mav_observer.app.{args.command}_cmd")
            return int(getattr(module, f"cmd_{args.command}")(args))
    except ConfigError as exc:  # a setting or flag that cannot be: a usage error
        print(f"mav-observer: {exc}", file=sys.stderr)
        return 2
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
