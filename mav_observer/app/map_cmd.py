"""``mav-observer map``: the live map on any machine that reaches the service over Zenoh.

A Zenoh session (a peer connecting to the service's endpoint, no scouting) subscribes to the
estimates ``PREFIX/*/*/estimate``, the statuses ``PREFIX/*/status`` (each vehicle's origin)
and the fused targets ``PREFIX/fused/*`` (``mav-observer fuse``), and feeds the page of
:mod:`mav_observer.outputs.web`, served on ``--web HOST:PORT`` (loopback by default); the
service itself then serves no page and spends nothing on one. What the page shows is what the
service (and ``fuse``) published.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time
from typing import Any

from mav_observer.errors import ConfigError


def add_parser(sub: Any) -> None:
    from mav_observer.app.cli import add_zenoh_client_args

    mp = sub.add_parser(
        "map",
        help="a live map in the browser of what a running service publishes (over Zenoh)",
        description="Subscribe to a service's estimates over Zenoh and serve the live map at "
        "http://HOST:PORT/ (docs/service.md, 'The live map').",
    )
    mp.add_argument("--web", default="127.0.0.1:8765", metavar="HOST:PORT")
    mp.add_argument("--web-tiles", metavar="URL", help="a {z}/{x}/{y} tile layer (default none)")
    add_zenoh_client_args(mp, wait_s=30.0)
    mp.add_argument("--prefix", default="mav_observer", help="the service's key prefix")
    mp.add_argument("--duration", type=float, help="stop after this many seconds")


def cmd_map(args: argparse.Namespace) -> int:
    from mav_observer.app.cli import follow_fused, web_server, zenoh_client_session

    web = web_server(args.web, args.web_tiles)
    if web is None:  # (--web has a default)
        raise ConfigError("map needs --web HOST:PORT")
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    session = zenoh_client_session(args)
    try:
        feed = web.feed
        sub = session.declare_subscriber(
            f"{args.prefix}/*/*/estimate",
            lambda s: feed.add_published(s.payload.to_bytes().decode("utf-8", "replace")),
        )
        fused = follow_fused(session, args.prefix, feed)
        status = session.declare_subscriber(  # each vehicle's origin
            f"{args.prefix}/*/status",
            lambda s: feed.add_status(s.payload.to_bytes().decode("utf-8", "replace")),
        )
        print(f"live map on {web.url} (estimates of {args.prefix}/*/*/estimate, fused targets "
              f"of {args.prefix}/fused/*)", flush=True)  # fmt: skip
        end = None if args.duration is None else time.monotonic() + args.duration
        while not stop.is_set() and (end is None or time.monotonic() < end):
            stop.wait(0.2)
        sub.undeclare()
        fused.undeclare()
        status.undeclare()
    finally:
        session.close()
        web.close()
    return 0
