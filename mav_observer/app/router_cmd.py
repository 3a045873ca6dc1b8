"""``mav-observer router``: Zenoh's own router, for services, a fusion node and listeners on
several machines (``docs/fleet.md``).

It opens a Zenoh session in router mode from a standard Zenoh JSON5 configuration file (the
same file Zenoh's ``zenohd`` reads), with the project's safe defaults for what the file
leaves unset: listening on ``tcp/127.0.0.1:7447`` only, multicast scouting off.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time
from typing import Any


def add_parser(sub: Any) -> None:
    rp = sub.add_parser(
        "router",
        help="a Zenoh router joining services, `fuse` and listeners across machines",
        description="Run Zenoh's router (docs/fleet.md): every other process connects to it as "
        "a client.",
    )
    rp.add_argument("--zenoh-config", help="a standard Zenoh JSON5 configuration file")
    rp.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="where to listen (default tcp/127.0.0.1:7447, or the file's)",
    )
    rp.add_argument("--duration", type=float, help="stop after this many seconds")


def cmd_router(args: argparse.Namespace) -> int:
    from mav_observer.outputs import zenoh_io

    conf = zenoh_io.session_config(config_file=args.zenoh_config, mode="router", listen=args.listen)
    session = zenoh_io.open_session(conf)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    print(f"zenoh router {session.zid()} listening on {conf.get_json('listen/endpoints')}",
          flush=True)  # fmt: skip
    end = None if args.duration is None else time.monotonic() + args.duration
    try:
        while not stop.is_set() and (end is None or time.monotonic() < end):
            stop.wait(0.2)
    finally:
        session.close()
    return 0
