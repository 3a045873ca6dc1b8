"""The ``mav-observer`` command.

Sub-commands:

* ``demo``: run a simulated scenario through the observer and print the estimate
  converging to the truth (the simulator lives in the separate ``sim`` package and runs as
  its own process, ``python -m sim demo``; ``mav_observer`` never imports it).
* ``version``: print the version.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from collections.abc import Sequence

from mav_observer import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mav-observer",
        description="Estimate a target's relative position and the velocity bias from "
        "bearings and the vehicle's velocity.",
    )
    parser.add_argument("--version", action="version", version=f"mav-observer {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser(
        "demo",
        help="run a simulated scenario and show the estimate converging "
        "(options: mav-observer demo --help)",
    )
    sub.add_parser("version", help="print the version")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "demo":
        # the simulator is a separate program: run it as a child process, options passed on
        try:
            return subprocess.call([sys.executable, "-m", "sim", "demo", *argv[1:]])
        except KeyboardInterrupt:
            return 130
    args = build_parser().parse_args(argv)
    if args.command == "version":
        print(f"mav-observer {__version__}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
