"""The floor of ``service_latency.py``: a process that does nothing but what any service must.

Run by ``bench/service_latency.py`` (``python bench/_relay.py UDP_PORT ZENOH_PORT KEY_EXPR``):
it receives the same datagrams on ``127.0.0.1:UDP_PORT`` and, for each
GIMBAL_DEVICE_ATTITUDE_STATUS frame, publishes ``{"t_boot_s": ...}`` (its ``time_boot_ms``,
read from the payload's first four bytes) on ``KEY_EXPR`` over a Zenoh peer listening on
``tcp/127.0.0.1:ZENOH_PORT`` (multicast scouting off). No decoding, no estimate: the
operating system's UDP, Python's wake-up and Zenoh's delivery. It stops on SIGTERM or after
``--duration-s``.
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import struct
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mav_observer.outputs.zenoh_io import open_session, session_config

GIMBAL_DEVICE_ATTITUDE_STATUS = 285


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("udp_port", type=int)
    parser.add_argument("zenoh_port", type=int)
    parser.add_argument("key_expr")
    parser.add_argument("--duration-s", type=float, default=600.0)
    args = parser.parse_args()
    stop = False

    def on_term(signum: int, frame: object) -> None:
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_term)
    session = open_session(session_config(listen=[f"tcp/127.0.0.1:{args.zenoh_port}"]))
    pub = session.declare_publisher(args.key_expr)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", args.udp_port))
    sock.settimeout(0.2)
    end = time.monotonic() + args.duration_s
    try:
        while not stop and time.monotonic() < end:
            try:
                data = sock.recv(4096)
            except TimeoutError:
                continue
            if len(data) < 14:
                continue
            if data[0] == 0xFD:
                msgid, hlen = data[7] | (data[8] << 8) | (data[9] << 16), 10
            else:
                msgid, hlen = data[5], 6
            if msgid == GIMBAL_DEVICE_ATTITUDE_STATUS:
                (ms,) = struct.unpack_from("<I", data, hlen)
                pub.put(json.dumps({"t_boot_s": ms / 1000.0}))
    finally:
        sock.close()
        pub.undeclare()
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
