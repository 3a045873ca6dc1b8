"""Optional peer check: MAVProxy as a router between the emitter and the reader.

emitter --udpout--> MAVProxy (udpin master) --udpout--> ConnectionReader (udpin) -> Tracker

then MAVProxy's own telemetry log (``mav.tlog``) is replayed. Everything is on 127.0.0.1.
MAVProxy is not a dependency; install it beside the project without its dependencies (its full
install pulls in over a gigabyte) and keep its ``terrain`` module out (it looks up an internet
host when it starts)::

    .venv/bin/pip install --no-deps MAVProxy && .venv/bin/pip install defusedxml pynmeagps
    .venv/bin/python bench/mavproxy_router.py

Exits 0 when the estimates came through both ways, 1 otherwise, 2 if MAVProxy is missing.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mav_observer.app.replay import replay  # noqa: E402
from mav_observer.mavlink.connection import ConnectionReader  # noqa: E402
from mav_observer.tracking.tracker import Tracker  # noqa: E402
from sim import scenarios  # noqa: E402
from sim.emitter import Emitter, EmitterConfig, run  # noqa: E402

MODULES = "link,log"  # MAVProxy's defaults without terrain (and the rest we do not need)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    parser.add_argument("--speed", type=float, default=10.0, help="emitter speed factor")
    args = parser.parse_args()
    exe = shutil.which("mavproxy.py") or str(Path(sys.executable).with_name("mavproxy.py"))
    if not Path(exe).exists():
        print("MAVProxy is not installed (see this file's docstring)", file=sys.stderr)
        return 2
    p_in, p_out = free_udp_port(), free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        proxy = subprocess.Popen(
            [
                exe, f"--master=udpin:127.0.0.1:{p_in}", f"--out=udpout:127.0.0.1:{p_out}",
                f"--default-modules={MODULES}", "--daemon", "--non-interactive",
            ],
            cwd=tmp,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            time.sleep(2.0)  # MAVProxy binds its master port
            em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=args.duration))
            wall_s = args.duration / args.speed
            reader = ConnectionReader(
                f"udpin:127.0.0.1:{p_out}", duration_s=wall_s + 5.0, idle_timeout_s=3.0
            )
            reader.open()
            sender = threading.Thread(
                target=run,
                args=(em,),
                kwargs={"to": f"udpout:127.0.0.1:{p_in}", "speed": args.speed},
            )
            sender.start()
            tracker = Tracker()
            live = 0
            for t, msg in reader:
                live += len(tracker.handle(t, msg))
            sender.join()
        finally:
            proxy.terminate()
            try:
                proxy.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proxy.kill()
                proxy.wait()
        print(f"live through MAVProxy: {sum(reader.counts.values())} messages, {live} estimates")
        print(f"  targets {tracker.targets()}, skipped {dict(tracker.skipped) or 'none'}")
        s = replay(str(Path(tmp) / "mav.tlog"))
        print(
            f"MAVProxy's mav.tlog replayed: {s.messages_read} messages, "
            f"{s.estimates_written} estimates, skipped {s.skipped or 'none'}, "
            f"damage {s.damage or 'none'}"
        )
    ok = live > 0 and not tracker.skipped and s.estimates_written > 0 and not s.damage
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
