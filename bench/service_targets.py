"""Many targets on one service: LANDING_TARGET with ``target_num`` 0..N-1, each at 30 Hz.

Run: ``python bench/service_targets.py`` (about a minute; ``--targets 100 --duration-s 20``;
``--vehicles 10``: ten vehicles of 10 targets each, every vehicle's whole stream).

The emitter flies its weaving scenario with a downward camera reporting LANDING_TARGET in
the local frame (``landing_target_local``) at ``--bearing-hz``, LOCAL_POSITION_NED at 50 Hz
and ATTITUDE at 20 Hz; every LANDING_TARGET is sent ``--targets`` times, with ``target_num``
0..N-1 (the same line of sight: the load of N targets, each with its own estimator). Every
frame is re-packed by one MAVLink encoder so the sequence numbers stay continuous. The frames
go in real time, one per datagram, to a fresh service (``--estimate-rate-hz 0``: every
estimate published), and a subscriber in this process counts the estimates of every target
(``mav_observer/1/*/estimate``). Reported: bearings sent per second, estimates received
against bearings sent (all targets and the worst one), the service's CPU share over the
sending window (``/proc``: the process and its main thread), kernel UDP drops, and the delay
from the last bearing sent to the last estimate received. Goal: every estimate published,
on one core (main thread under 100 %).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _proc import connect_to_service, cpu_ticks, finish, free_port, start_service  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from mav_observer.mavlink.connection import udp_socket_stats  # noqa: E402
from sim import emitter, scenarios  # noqa: E402
from sim.live import stop_process  # noqa: E402


def plan(
    targets: int,
    bearing_hz: float,
    duration_s: float,
    seed: int,
    vehicles: int = 1,
    attitude_hz: float = 20.0,
) -> list[tuple[float, bytes]]:
    """``(t_s, frame)`` in scenario time: every message once per vehicle (system ids
    1..``vehicles``), every LANDING_TARGET repeated for each of its ``targets / vehicles``."""
    d = duration_s + 1.0
    em = emitter.Emitter(
        scenarios.weave(duration_s=d),
        emitter.EmitterConfig(
            duration_s=d,
            bearing="landing_target_local",
            bearing_noise_deg=0.5,
            seed=seed,
            bearing_hz=bearing_hz,
            position_hz=50.0,
            attitude_hz=attitude_hz,
            background_hz=0.0,
        ),
    )
    parser = mavlink.MAVLink(None)
    encoders: dict[tuple[int, int], Any] = {}
    out: list[tuple[float, bytes]] = []
    for e in em.emissions():
        if e.t_emit_s >= duration_s:
            break
        msgs = parser.parse_buffer(e.frame) or []
        for msg, sysid in ((m, v) for m in msgs for v in range(1, vehicles + 1)):
            key = (sysid, msg.get_srcComponent())
            enc = encoders.setdefault(
                key, mavlink.MAVLink(None, srcSystem=key[0], srcComponent=key[1])
            )
            each = targets // vehicles
            copies = range(each) if msg.get_type() == "LANDING_TARGET" else [None]
            for k in copies:
                if k is not None:
                    msg.target_num = k
                out.append((e.t_emit_s, bytes(msg.pack(enc, force_mavlink1=False))))
                enc.seq = (enc.seq + 1) % 256  # (MAVLink.send counts it; pack does not)
    return out


def run(args: argparse.Namespace, web_page: bool | str = False) -> dict[str, Any]:
    """One run; ``web_page``: the service with its live map (``--web``) open in a headless
    Chromium all along (``True``), or its events read by ``curl`` (``"reader"``: what the
    service spends on a page, without a browser on its cores) (``bench/web_map.py``)."""
    vehicles = getattr(args, "vehicles", 1)
    frames = plan(args.targets, args.bearing_hz, args.duration_s, args.seed, vehicles,
                  getattr(args, "attitude_hz", 20.0))  # fmt: skip
    keys = [_bearing_key(f) for _, f in frames]
    n_bearings = sum(k is not None for k in keys)
    extra = ["--estimate-rate-hz", "0", "--log-level", "WARNING"]
    web_port = free_port(socket.SOCK_STREAM)
    if web_page:
        extra += ["--web", f"127.0.0.1:{web_port}"]
    svc, mav_port, z_port, log = start_service(extra)
    session = sock = page = reader = None
    page_result: dict[str, float] = {}
    per_target: Counter[str] = Counter()
    last_rx = [0.0]
    received: list[tuple[float, bytes]] = []
    sent_at: dict[tuple[int, str, int], float] = {}
    try:
        session = connect_to_service(svc, mav_port, z_port)
        if web_page == "reader":  # the events read without a browser's rendering
            reader = subprocess.Popen(["curl", "-sN", f"http://127.0.0.1:{web_port}/events"],
                                      stdout=subprocess.DEVNULL)  # fmt: skip
        elif web_page:
            from _browser import open_page

            page = open_page(f"http://127.0.0.1:{web_port}/")

        def on_estimate(s: Any) -> None:
            per_target[str(s.key_expr).rpartition("/")[0]] += 1  # mav_observer/SYSID/TARGET
            last_rx[0] = time.perf_counter()
            received.append((last_rx[0], s.payload.to_bytes()))

        sub = session.declare_subscriber("mav_observer/*/*/estimate", on_estimate)
        time.sleep(0.5)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 22)
        addr = ("127.0.0.1", mav_port)
        perf, sleep = time.perf_counter, time.sleep
        browser0 = _browser_ticks(page)
        cpu0, main0, wall0 = cpu_ticks(svc.pid), cpu_ticks(svc.pid, svc.pid), perf()
        t0 = wall0 + 0.005
        for (t_sim, frame), key in zip(frames, keys, strict=True):
            d = t0 + t_sim - perf()
            if d > 0:
                sleep(d)
            sock.sendto(frame, addr)
            if key is not None:
                sent_at[key] = perf()
        t_end = perf()
        cpu1, main1 = cpu_ticks(svc.pid), cpu_ticks(svc.pid, svc.pid)
        browser1 = _browser_ticks(page)
        deadline = t_end + args.settle_s
        while perf() < deadline and sum(per_target.values()) < n_bearings:
            sleep(0.05)
        drain_s = max(last_rx[0] - t_end, 0.0)
        drops = (udp_socket_stats(mav_port) or (0, 0))[1]
        if page is not None:
            from _browser import page_figures

            page_result = page_figures(page)
        stop_process(svc)
        sub.undeclare()
    finally:
        if page is not None:
            page.quit()
        if reader is not None:
            stop_process(reader)
        code, service_log = finish(svc, log, sock, session)
    send_s = t_end - wall0
    lat_ms = []
    for t_rx, payload in received:
        doc = json.loads(payload)
        t_sent = sent_at.get((doc["sysid"], doc["target"], round(doc["t_boot_s"] * 1000)))
        if t_sent is not None:
            lat_ms.append(1000.0 * (t_rx - t_sent))
    lat_ms.sort()
    tick = os.sysconf("SC_CLK_TCK")
    received = sum(per_target.values())
    expected_each = n_bearings / (args.targets // vehicles * vehicles)
    return {
        "targets": args.targets,
        "vehicles": vehicles,
        "targets_seen": len(per_target),
        "bearings_sent": n_bearings,
        "bearings_per_s": n_bearings / send_s,
        "frames_sent": len(frames),
        "estimates_received": received,
        "received_share": received / n_bearings,
        "worst_target_share": min(per_target.values(), default=0) / expected_each,
        "service_cpu_pct": 100.0 * (cpu1 - cpu0) / tick / send_s,
        "main_thread_cpu_pct": 100.0 * (main1 - main0) / tick / send_s,
        # the page's Chromium over the sending window, all its processes (NaN: no page)
        "browser_cpu_pct": 100.0 * (browser1 - browser0) / tick / send_s,
        "udp_drops": drops,
        "drain_after_last_send_s": drain_s,
        "service_exit": code,
        # a bearing sent to its estimate received (its time_usec names it)
        "latency_matched": len(lat_ms),
        "latency_p50_ms": _quantile(lat_ms, 0.5),
        "latency_p99_ms": _quantile(lat_ms, 0.99),
        "service_log_tail": service_log.splitlines()[-3:],
        **page_result,
    }


def _browser_ticks(page: Any) -> float:
    if page is None:
        return float("nan")
    from _browser import browser_cpu_ticks

    return float(browser_cpu_ticks())


def _quantile(xs: list[float], q: float) -> float:
    return xs[min(int(q * len(xs)), len(xs) - 1)] if xs else float("nan")


_PARSER = mavlink.MAVLink(None)


def _bearing_key(frame: bytes) -> tuple[int, str, int] | None:
    """A LANDING_TARGET's (system id, target, time in ms), as its estimate names it."""
    if _msgid(frame) != mavlink.MAVLINK_MSG_ID_LANDING_TARGET:
        return None
    msg = _PARSER.decode(bytearray(frame))
    return (msg.get_srcSystem(), f"landing_target_{msg.target_num}", round(msg.time_usec / 1000))


def _msgid(frame: bytes) -> int:
    return frame[7] | frame[8] << 8 | frame[9] << 16 if frame[0] == 0xFD else frame[5]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", type=int, default=100, help="in all, shared by the vehicles")
    ap.add_argument("--vehicles", type=int, default=1, help="system ids 1..N, each its stream")
    ap.add_argument("--bearing-hz", type=float, default=30.0, help="per target")
    ap.add_argument("--duration-s", type=float, default=20.0, help="sending time")
    ap.add_argument(
        "--attitude-hz",
        type=float,
        default=20.0,
        help="ATTITUDE per vehicle (a LANDING_TARGET waits for the one after it)",
    )
    ap.add_argument("--settle-s", type=float, default=10.0, help="wait for the last estimates")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="also write the result as JSON")
    args = ap.parse_args()
    r = run(args)
    print(
        f"{r['vehicles']} vehicle(s), {r['targets']} targets ({r['targets_seen']} seen), "
        f"{r['bearings_per_s']:.0f} bearings/s "
        f"for {args.duration_s:g} s: {r['estimates_received']} of {r['bearings_sent']} estimates "
        f"received ({100 * r['received_share']:.2f} %, worst target "
        f"{100 * r['worst_target_share']:.2f} %), service CPU {r['service_cpu_pct']:.0f} % "
        f"(main thread {r['main_thread_cpu_pct']:.0f} %), UDP drops {r['udp_drops']}, last "
        f"estimate {r['drain_after_last_send_s'] * 1000:.0f} ms after the last send; a bearing "
        f"to its estimate p50 {r['latency_p50_ms']:.2f} ms, p99 {r['latency_p99_ms']:.2f} ms "
        f"({r['latency_matched']} matched)"
    )
    ok = r["estimates_received"] == r["bearings_sent"] and r["main_thread_cpu_pct"] < 100.0
    print(f"goal (every estimate, one core): {'met' if ok else 'NOT met'}")
    if args.json:
        Path(args.json).write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
