"""``mav-observer fuse``: one target seen by several vehicles (``docs/fleet.md``).

Live, a Zenoh session (a client of a router, or a peer of the services) subscribes to every
vehicle's rays ``PREFIX/*/*/ray``, gives each to the fused targets it belongs to
(:class:`~mav_observer.fleet.fusion.FusedTarget`), and publishes each fused estimate on
``PREFIX/fused/NAME`` (and, when asked, as FOLLOW_TARGET over MAVLink to the autopilots).
Offline, ``--rays FILE...`` fuses the rays ``replay --rays`` wrote. Which vehicle targets are
one target comes from ``--target NAME=SYSID/TARGET,...`` or a TOML file's ``[targets]`` table.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import threading
import time
import tomllib
from collections import Counter
from pathlib import Path
from typing import Any

from mav_observer.errors import ConfigError
from mav_observer.fleet.fusion import FusedEstimate, FusedTarget
from mav_observer.fleet.rays import InvalidRayError, Ray, ray_from_json

log = logging.getLogger(__name__)

#: FOLLOW_TARGET's est_capabilities bit: the position is valid.
FOLLOW_TARGET_POS = 1
FUSE_KEYS = {"converged_rel": 0.02, "stale_after_s": 2.0, "rate_hz": 50.0, "mavlink_rate_hz": 4.0}


def add_parser(sub: Any) -> None:
    from mav_observer.app.cli import add_zenoh_client_args

    fp = sub.add_parser(
        "fuse",
        help="fuse the bearings of several vehicles on one target (over Zenoh, or ray files)",
        description="Fuse the rays of the vehicle targets that see one target into one "
        "estimate on WGS84 with its covariance (docs/fleet.md).",
    )
    fp.add_argument(
        "--target",
        action="append",
        default=[],
        metavar="NAME=SYSID/TARGET,...",
        help="one shared target and the vehicle targets that see it, e.g. "
        "person_1=1/gimbal,2/gimbal (repeatable)",
    )
    fp.add_argument("--config", type=Path, help="a TOML file: [targets] NAME = [KEYS], [fuse]")
    fp.add_argument("--rays", type=Path, nargs="+", help="fuse these ray files (replay --rays)")
    fp.add_argument("--output", "-o", type=Path, help="the fused estimates, JSON Lines")
    fp.add_argument(
        "--html",
        type=Path,
        help="with --rays: a map report (the vehicles, the fused targets over time with a slider; "
        "one file that opens from disk)",
    )
    fp.add_argument(
        "--mavlink-out",
        action="append",
        default=[],
        metavar="URL",
        help="also send each converging fused target as FOLLOW_TARGET here (repeatable)",
    )
    fp.add_argument("--mavlink-sysid", type=int, default=250, help="our MAVLink system id")
    add_zenoh_client_args(fp, wait_s=30.0)
    fp.add_argument("--prefix", default="mav_observer", help="the services' key prefix")
    fp.add_argument("--duration", type=float, help="stop after this many seconds")


def parse_groups(specs: list[str], table: dict[str, Any] | None = None) -> dict[str, list[str]]:
    """The shared targets: ``NAME -> ["sysid/target", ...]`` from ``--target`` specs and a
    TOML ``[targets]`` table; raises :class:`ConfigError` naming a bad one."""
    groups: dict[str, list[str]] = {}
    items: list[tuple[str, Any]] = list((table or {}).items())
    for spec in specs:
        name, sep, keys = spec.partition("=")
        if not sep:
            raise ConfigError(f"--target {spec!r}: expected NAME=SYSID/TARGET,...")
        items.append((name.strip(), [k.strip() for k in keys.split(",") if k.strip()]))
    for name, keys in items:
        if not name or "/" in name or not isinstance(keys, list) or not keys:
            raise ConfigError(f"target {name!r} = {keys!r}: expected a name and a list of keys")
        for k in keys:
            sysid, sep, tgt = str(k).partition("/")
            if not sep or not sysid.isdigit() or not 1 <= int(sysid) <= 255 or not tgt:
                raise ConfigError(f"target {name}: {k!r} is not SYSID/TARGET (e.g. 1/gimbal)")
        groups[name] = [str(k) for k in keys]
    if not groups:
        raise ConfigError("fuse needs at least one --target NAME=SYSID/TARGET,... (or [targets])")
    return groups


class Fusion:
    """The fused targets and their routing (no I/O): :meth:`add` a ray payload, get the
    estimates it changed."""

    def __init__(self, groups: dict[str, list[str]], **options: float) -> None:
        self.targets = {
            name: FusedTarget(
                name,
                keys,
                converged_rel=options.get("converged_rel", 0.02),
                stale_after_s=options.get("stale_after_s", 2.0),
            )
            for name, keys in groups.items()
        }
        self.routes: dict[str, list[FusedTarget]] = {}
        for ft in self.targets.values():
            for k in ft.keys:
                self.routes.setdefault(k, []).append(ft)
        self.counts: Counter[str] = Counter()

    def parse(self, payload: str | bytes, where: str = "") -> Ray | None:
        """The ray of a payload, or ``None`` for a bad one (counted; the first few logged)."""
        try:
            return ray_from_json(payload)
        except InvalidRayError as exc:
            self.counts["bad_ray"] += 1
            if self.counts["bad_ray"] <= 5:
                log.warning("%sray refused: %s", where, exc)
            return None

    def add(self, ray: Ray, rx_s: float) -> list[FusedTarget]:
        """Fuse ``ray`` into the targets it belongs to; returns them."""
        routes = self.routes.get(ray.key)
        if not routes:
            self.counts["ray_not_fused"] += 1
            return []
        self.counts["rays"] += 1
        for ft in routes:
            ft.add(ray, rx_s)
        return routes


def _options(args: argparse.Namespace) -> tuple[dict[str, list[str]], dict[str, float]]:
    table: dict[str, Any] = {}
    opts = dict(FUSE_KEYS)
    if args.config is not None:
        try:
            doc = tomllib.loads(args.config.read_text(encoding="utf-8"))
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise ConfigError(f"{args.config}: {exc}") from None
        table = doc.get("targets", {})
        for k, v in doc.get("fuse", {}).items():
            if k not in FUSE_KEYS:
                raise ConfigError(f"{args.config}: fuse.{k} is not a setting ({sorted(FUSE_KEYS)})")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ConfigError(f"{args.config}: fuse.{k}={v!r} is not a positive number")
            opts[k] = float(v)
    return parse_groups(args.target, table), opts


def _line(est: FusedEstimate, extra: dict[str, Any]) -> str:
    d = est.to_dict()
    d.update(extra)
    return json.dumps(d, separators=(",", ":"))


def cmd_fuse(args: argparse.Namespace) -> int:
    groups, opts = _options(args)
    fusion = Fusion(groups, **opts)
    if args.rays:
        return _offline(fusion, args)
    if args.html:
        raise ConfigError("--html makes the report of ray files: it needs --rays")
    return _live(fusion, args, opts)


def _offline(fusion: Fusion, args: argparse.Namespace) -> int:
    rays: list[Ray] = []
    for path in args.rays:
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise ConfigError(f"--rays {path}: {exc}") from None
        for line in lines:
            ray = fusion.parse(line, f"{path}: ") if line.strip() else None
            if ray is not None:
                rays.append(ray)
    rays.sort(key=lambda r: r.t_unix_s)
    report = None
    if args.html:
        from mav_observer.outputs.html_report import FusedReportData

        report = FusedReportData()
    out = open(args.output, "w", encoding="utf-8") if args.output else None  # noqa: SIM115
    try:
        for r in rays:
            if report is not None:
                report.add_ray(r)
            for ft in fusion.add(r, r.t_unix_s):
                if out is not None or report is not None:
                    est = ft.estimate(r.t_unix_s)
                    if out is not None:
                        out.write(_line(est, {}) + "\n")
                    if report is not None:
                        report.add_fused(est)
    finally:
        if out is not None:
            out.close()
    t_end = rays[-1].t_unix_s if rays else 0.0
    for ft in fusion.targets.values():
        e = ft.estimate(t_end)
        sd = e.std_ned_m
        where = (
            f"{e.geodetic[0]:.7f}, {e.geodetic[1]:.7f}, {e.geodetic[2]:.2f} m, 1-sigma N/E/D "
            f"{sd[0]:.3f}/{sd[1]:.3f}/{sd[2]:.3f} m"
            if e.geodetic is not None and sd is not None
            else "no position"
        )
        who = ", ".join(f"{v['key']} ({v['rays']} rays)" for v in e.vehicles) or "no rays"
        print(f"{ft.name}: {e.status}, {where}; from {who}")
    if fusion.counts["bad_ray"]:
        print(f"{fusion.counts['bad_ray']} rays refused")
    if report is not None:
        _write_report(args.html, report, [p.name for p in args.rays])
    return 0


def _write_report(path: Path, report: Any, sources: list[str]) -> None:
    """``fuse --rays ... --html``: the map report of the fusion."""
    from mav_observer.errors import MavObserverError
    from mav_observer.outputs.html_report import write_html

    lines = [f"{name}: {rows[-1][5]}, {len(rows)} estimates shown"
             for name, rows in report.targets.items()]  # fmt: skip
    text = "fused from " + ", ".join(sources) + "\n" + ("\n".join(lines) or "no fused estimate")
    try:
        write_html(path, report, "fusion of " + ", ".join(sources), text, None)
    except OSError as exc:
        raise MavObserverError(f"cannot write {path}: {exc}") from exc


class _FollowTargetOut:
    """The fused targets as FOLLOW_TARGET (lat, lon, alt, position variance) to autopilots."""

    def __init__(self, urls: list[str], sysid: int, rate_hz: float) -> None:
        from mav_observer.mavlink.dialect import connect

        if not 1 <= sysid <= 255:
            raise ConfigError(f"--mavlink-sysid {sysid} is not in [1, 255]")
        # links of our own system id: an autopilot's follow mode listens to one sysid
        self.links = [connect(u, source_system=sysid) for u in urls]
        self.errors = 0
        self.min_s = 1.0 / rate_hz
        self.next: dict[str, float] = {}
        self.t0 = time.monotonic()

    def due(self, name: str, now: float) -> bool:
        """Whether target ``name`` may be sent at ``now`` (its rate limit)."""
        return now >= self.next.get(name, 0.0)

    def send(self, est: FusedEstimate, now: float) -> None:
        from mav_observer.mavlink.dialect import mavlink

        if est.geodetic is None or est.cov_ned_m2 is None or not self.due(est.name, now):
            return
        self.next[est.name] = now + self.min_s
        lat, lon, alt = est.geodetic
        c = est.cov_ned_m2
        msg = mavlink.MAVLink_follow_target_message(
            int(max(0.0, now - self.t0) * 1000),  # ms since this node started (uint64)
            FOLLOW_TARGET_POS,
            round(lat * 1e7),
            round(lon * 1e7),
            alt,
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [c[0][0], c[1][1], c[2][2]],
            0,
        )
        for link in self.links:
            try:
                link.mav.send(msg)
            except OSError as exc:  # a link down: counted and logged, never fatal
                self.errors += 1
                if self.errors <= 5:
                    log.warning("FOLLOW_TARGET not sent: %s", exc)

    def close(self) -> None:
        for link in self.links:
            link.close()


def _live(fusion: Fusion, args: argparse.Namespace, opts: dict[str, float]) -> int:
    import queue

    import zenoh

    from mav_observer.app.cli import zenoh_client_session

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    session = zenoh_client_session(args)
    inbox: queue.SimpleQueue[tuple[float, bytes]] = queue.SimpleQueue()
    mav = (
        _FollowTargetOut(args.mavlink_out, args.mavlink_sysid, opts["mavlink_rate_hz"])
        if args.mavlink_out
        else None
    )
    out = open(args.output, "w", encoding="utf-8") if args.output else None  # noqa: SIM115
    pubs: dict[str, Any] = {}
    next_pub: dict[str, float] = {}
    min_s = 0.0 if opts["rate_hz"] <= 0 else 1.0 / opts["rate_hz"]
    try:
        sub = session.declare_subscriber(
            f"{args.prefix}/*/*/ray",
            lambda s: inbox.put((time.monotonic(), s.payload.to_bytes())),
        )
        for name in fusion.targets:
            pubs[name] = session.declare_publisher(
                f"{args.prefix}/fused/{name}", encoding=zenoh.Encoding.APPLICATION_JSON
            )
        shared = ", ".join(f"{n} = {list(t.keys)}" for n, t in fusion.targets.items())
        print(f"fusing {shared} from {args.prefix}/*/*/ray into {args.prefix}/fused/NAME",
              flush=True)  # fmt: skip
        end = None if args.duration is None else time.monotonic() + args.duration
        while not stop.is_set() and (end is None or time.monotonic() < end):
            try:
                rx, payload = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            ray = fusion.parse(payload)
            if ray is None:
                continue
            for ft in fusion.add(ray, rx):
                now = time.monotonic()
                publish = now >= next_pub.get(ft.name, 0.0)
                send = mav is not None and mav.due(ft.name, now)
                if not (publish or send):
                    continue  # rate-limited: the estimate is not even formed
                est = ft.estimate(now)
                if publish:
                    next_pub[ft.name] = now + min_s
                    extra = {"ray_sent_unix_s": ray.sent_unix_s, "fused_unix_s": time.time()}
                    text = _line(est, extra)
                    pubs[ft.name].put(text)
                    if out is not None:
                        out.write(text + "\n")
                if send and est.status in ("converging", "converged"):
                    mav.send(est, now)  # type: ignore[union-attr]
        sub.undeclare()
    finally:
        for p in pubs.values():
            p.undeclare()
        session.close()
        if mav is not None:
            mav.close()
        if out is not None:
            out.close()
    counts = ", ".join(f"{k} {v}" for k, v in sorted(fusion.counts.items())) or "no rays"
    print(f"fuse: {counts}")
    return 0
