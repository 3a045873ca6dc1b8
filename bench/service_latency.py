"""Service latency on loopback: a bearing datagram written to the estimate it produced received.

Run: ``python bench/service_latency.py`` (about two minutes; ``--updates 3000`` for a check).

What is measured: the time from ``sendto()`` of a GIMBAL_DEVICE_ATTITUDE_STATUS datagram to
the arrival, in a Zenoh subscriber of this process, of the estimate that bearing produced. Both
ends read ``time.perf_counter()`` in this process (one clock): just before each bearing's
``sendto()`` (keyed by its ``time_boot_ms``) and first thing in the subscriber's callback; an
estimate is matched to its bearing by ``round(t_boot_s * 1000)``.

How: the service runs as its own process (``python -m mav_observer run``, ``--estimate-rate-hz
0`` so that every estimate is published), reading ``udpin:127.0.0.1:PORT`` and listening for
Zenoh on ``tcp/127.0.0.1:ZPORT``; this process connects to it (no multicast scouting). The
emitter's orbit scenario (gimbal bearings, 0.5 deg noise) is generated beforehand and sent from
a plain UDP socket in time order, paced on the real clock, one frame per datagram. Default mix,
in wall-clock rates: bearings at 100 Hz, LOCAL_POSITION_NED and GLOBAL_POSITION_INT at 100 Hz
each, ATTITUDE and ATTITUDE_QUATERNION at 200 Hz each, HEARTBEAT, SYSTEM_TIME, SYS_STATUS at
1 Hz (``--speed S`` generates the scenario at the rates divided by S and sends it S times
faster: the same wall rates, a faster scenario). The first ``--warmup`` bearings (the
observer's start, the first publication) are not measured; then ``--updates`` bearings are.

Output: p50, p90, p99, p99.9, max and mean latency (ms) of the measured bearings, how many
produced no estimate (lost), the sender's own lateness against its schedule, and the service
process's CPU share over the run; and the service's p50 and p99 apart for the bearings whose
estimate was ``converged`` and the others (the estimator's acquisition, the bank's several
hypotheses: most of the default run's 30 s). Goal: p50 within 1.3x and p99 within 1.5x the
relay's (docs/performance.md).

The baseline, measured first in the same run (``--no-baseline`` skips it): the same frames
sent the same way to ``bench/_relay.py``, a process that only receives each datagram and, for
a bearing, publishes its ``time_boot_ms`` over Zenoh: the floor of any Python service on this
machine (the operating system's UDP, the interpreter's wake-up, Zenoh's delivery), against
which the service's figures are given as ratios.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _proc import connect_to_service, cpu_ticks, finish, print_log_tail, start_service  # noqa: E402

from mav_observer.mavlink.connection import udp_socket_stats  # noqa: E402
from sim import emitter, scenarios  # noqa: E402
from sim.live import free_port, stop_process  # noqa: E402

GOAL_P99_MS = 1.0
RELAY = Path(__file__).resolve().parent / "_relay.py"
TIMED_SERVICE = Path(__file__).resolve().parent / "_timed_service.py"


def frames(args: argparse.Namespace) -> tuple[list[tuple[float, bytes, int | None]], int]:
    """Pre-generated ``(wall offset s, frame, bearing key or None)`` up to the last bearing
    needed, and the number of bearings."""
    need = args.warmup + args.updates
    s = args.speed
    duration = need / (args.bearing_hz / s) + 1.0
    em = emitter.Emitter(
        scenarios.orbit(duration_s=duration),
        emitter.EmitterConfig(
            duration_s=duration,
            bearing="gimbal",
            bearing_hz=args.bearing_hz / s,
            position_hz=args.position_hz / s,
            attitude_hz=args.attitude_hz / s,
            background_hz=args.background_hz / s,
            bearing_noise_deg=0.5,
            seed=args.seed,
        ),
    )
    out: list[tuple[float, bytes, int | None]] = []
    n = 0
    for e in em.emissions():
        key = None if e.truth is None else round(e.truth["t_boot_s"] * 1000)
        out.append((e.t_emit_s / s, e.frame, key))
        if key is not None:
            n += 1
            if n == need:
                break
    return out, n


def start_relay(key_expr: str) -> tuple[subprocess.Popen[Any], int, int, Any]:
    """``bench/_relay.py`` on free loopback ports, as :func:`start_service` starts the
    service: ``(process, UDP port, Zenoh TCP port, log file)``."""
    mav_port = free_port(socket.SOCK_DGRAM)
    z_port = free_port(socket.SOCK_STREAM)
    log = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 - finish() closes it
    proc = subprocess.Popen(
        [sys.executable, str(RELAY), str(mav_port), str(z_port), key_expr],
        stdout=log,
        stderr=log,
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    return proc, mav_port, z_port, log


def run(args: argparse.Namespace, *, relay: bool = False, web_page: str = "") -> dict[str, Any]:
    """One run (``relay``: the baseline); ``web_page``: the service with its live map
    (``--web``) open all along, in a headless Chromium (``"browser"``) or read by ``curl``
    (``"reader"``: the events without a page's rendering) (``bench/web_map.py``)."""
    t_gen = time.perf_counter()
    plan, n_bearings = frames(args)
    keys = [k for _, _, k in plan if k is not None]
    if len(set(keys)) != len(keys):
        raise SystemExit("bearing keys (time_boot_ms) are not unique: lower --bearing-hz")
    measured = set(keys[args.warmup :])
    print(
        f"{len(plan)} frames, {n_bearings} bearings generated in "
        f"{time.perf_counter() - t_gen:.1f} s; sending for {plan[-1][0]:.1f} s",
        flush=True,
    )
    key_expr = f"mav_observer/1/{emitter.TARGET_OF['gimbal']}/estimate"
    if relay:
        svc, mav_port, z_port, log = start_relay(key_expr)
    else:
        extra = ["--estimate-rate-hz", "0", "--log-level", args.service_log_level]
        if web_page:
            web_port = free_port(socket.SOCK_STREAM)
            extra += ["--web", f"127.0.0.1:{web_port}"]
        prefix = None
        if args.breakdown:
            timings = tempfile.NamedTemporaryFile(suffix=".json", delete=False)  # noqa: SIM115
            timings.close()
            prefix = [str(TIMED_SERVICE), timings.name]
        svc, mav_port, z_port, log = start_service(extra, prefix=prefix)
    session = None
    sock = None
    page = reader = None
    page_result: dict[str, float] = {}
    received: list[tuple[float, bytes]] = []
    sent_at: dict[int, float] = {}
    lateness: list[float] = []
    try:
        session = connect_to_service(svc, mav_port, z_port)
        if web_page == "browser":
            from _browser import open_page

            page = open_page(f"http://127.0.0.1:{web_port}/")
        elif web_page == "reader":
            reader = subprocess.Popen(["curl", "-sN", f"http://127.0.0.1:{web_port}/events"],
                                      stdout=subprocess.DEVNULL)  # fmt: skip
        sub = session.declare_subscriber(
            key_expr, lambda s: received.append((time.perf_counter(), s.payload.to_bytes()))
        )
        time.sleep(0.5)  # the subscription reaches the service's peer
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        addr = ("127.0.0.1", mav_port)
        perf = time.perf_counter
        sleep = time.sleep
        cpu0, wall0 = cpu_ticks(svc.pid), time.monotonic()
        t0 = perf() + 0.01
        for t_rel, frame, key in plan:
            due = t0 + t_rel
            d = due - perf()
            if d > 0:
                sleep(d)
            if key is not None:
                now = perf()
                sent_at[key] = now
                lateness.append(now - due)
            sock.sendto(frame, addr)
        sleep(args.drain_s)
        cpu1, wall1 = cpu_ticks(svc.pid), time.monotonic()
        drops = (udp_socket_stats(mav_port) or (0, 0))[1]
        sub.undeclare()
        alive = svc.poll() is None
        if page is not None:
            from _browser import page_figures

            page_result = page_figures(page)
    finally:
        if page is not None:
            page.quit()
        if reader is not None:
            stop_process(reader)
        code, service_log = finish(svc, log, sock, session)
    lat_ms: dict[int, float] = {}
    status_of: dict[int, str] = {}
    unmatched = 0
    for t_recv, payload in received:
        doc = json.loads(payload)
        key = round(doc["t_boot_s"] * 1000)
        t_sent = sent_at.get(key)
        if t_sent is None:
            unmatched += 1
            continue
        if key in measured and key not in lat_ms:
            lat_ms[key] = (t_recv - t_sent) * 1000.0
            status_of[key] = doc.get("status", "-")  # (the relay's payload has none)
    lat = np.array(list(lat_ms.values()))
    by_status = {}
    for status in sorted(set(status_of.values())):
        part = np.array([v for k, v in lat_ms.items() if status_of[k] == status])
        by_status[status] = {
            "count": int(part.size),
            "p50_ms": float(np.percentile(part, 50)),
            "p99_ms": float(np.percentile(part, 99)),
        }
    late = np.array(lateness) * 1000.0
    pct = (lambda q: float(np.percentile(lat, q))) if lat.size else (lambda q: float("nan"))
    result = {
        "mix_wall_hz": {
            "GIMBAL_DEVICE_ATTITUDE_STATUS": args.bearing_hz,
            "LOCAL_POSITION_NED": args.position_hz,
            "GLOBAL_POSITION_INT": args.position_hz,
            "ATTITUDE": args.attitude_hz,
            "ATTITUDE_QUATERNION": args.attitude_hz,
            "HEARTBEAT+SYSTEM_TIME+SYS_STATUS": 3 * args.speed,
            "background": args.background_hz,
        },
        "speed": args.speed,
        "frames_sent": len(plan),
        "bearings_sent": n_bearings,
        "warmup": args.warmup,
        "measured": len(measured),
        "matched": int(lat.size),
        "lost": len(measured) - int(lat.size),
        "estimates_received": len(received),
        "estimates_unmatched": unmatched,
        "p50_ms": pct(50),
        "p90_ms": pct(90),
        "p99_ms": pct(99),
        "p999_ms": pct(99.9),
        "max_ms": float(lat.max()) if lat.size else float("nan"),
        "mean_ms": float(lat.mean()) if lat.size else float("nan"),
        "by_status": by_status,
        "sender_late_p99_ms": float(np.percentile(late, 99)) if late.size else float("nan"),
        "sender_late_max_ms": float(late.max()) if late.size else float("nan"),
        "service_cpu_pct": 100.0 * (cpu1 - cpu0) / os.sysconf("SC_CLK_TCK") / (wall1 - wall0),
        "udp_drops": drops,
        "service_alive_at_end": alive,
        "service_exit": code,
        "service_log_lines": service_log.count("\n"),
        **page_result,
    }
    if not relay and args.breakdown:
        result["breakdown"] = _breakdown(Path(timings.name), args.warmup)
    result["goal_p99_ms"] = GOAL_P99_MS
    result["goal_met"] = bool(lat.size) and result["p99_ms"] < GOAL_P99_MS
    print_log_tail(service_log)
    return result


def _breakdown(path: Path, warmup: int) -> dict[str, Any]:
    """The service's own timers (``bench/_timed_service.py``): the wall time of each bearing's
    ``Service.handle`` and of each estimate's ``Publications.estimate``, the first ``warmup``
    left out: p50, p90, p99 and max (ms)."""
    times = json.loads(path.read_text())
    path.unlink()
    out = {}
    for name, values in times.items():
        v = np.array(values[warmup:]) * 1000.0
        if v.size:
            out[name.removesuffix("_s")] = {
                "count": int(v.size),
                **{f"p{q}_ms": float(np.percentile(v, q)) for q in (50, 90, 99)},
                "max_ms": float(v.max()),
            }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--updates", type=int, default=10_000, help="bearings measured")
    parser.add_argument("--warmup", type=int, default=200, help="bearings sent first, unmeasured")
    parser.add_argument("--bearing-hz", type=float, default=100.0, help="wall-clock rate")
    parser.add_argument("--position-hz", type=float, default=100.0, help="wall-clock rate")
    parser.add_argument("--attitude-hz", type=float, default=200.0, help="wall-clock rate")
    parser.add_argument("--background-hz", type=float, default=0.0, help="other messages/s")
    parser.add_argument("--speed", type=float, default=1.0, help="scenario time / wall time")
    parser.add_argument("--drain-s", type=float, default=1.0, help="wait after the last send")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--service-log-level", default="WARNING")
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    parser.add_argument(
        "--no-baseline", action="store_true", help="skip the relay's floor (bench/_relay.py)"
    )
    parser.add_argument(
        "--breakdown",
        action="store_true",
        help="run the service with timers (bench/_timed_service.py): the wall time of each "
        "bearing's handling in the service, and of its estimate's publication over Zenoh",
    )
    args = parser.parse_args()
    base = None if args.no_baseline else run(args, relay=True)
    r = run(args)
    print(
        f"{'':9s} {'measured':>8s} {'lost':>5s} {'p50_ms':>7s} {'p90_ms':>7s} {'p99_ms':>7s} "
        f"{'p99.9_ms':>8s} {'max_ms':>7s} {'mean_ms':>7s} {'cpu_%':>6s} {'udp_drops':>9s}"
    )
    for name, x in (("relay", base), ("service", r)):
        if x is None:
            continue
        print(
            f"{name:9s} {x['measured']:8d} {x['lost']:5d} {x['p50_ms']:7.3f} {x['p90_ms']:7.3f} "
            f"{x['p99_ms']:7.3f} {x['p999_ms']:8.3f} {x['max_ms']:7.3f} {x['mean_ms']:7.3f} "
            f"{x['service_cpu_pct']:6.1f} {x['udp_drops']:9d}"
        )
    parts = [
        f"{st} {v['count']} (p50 {v['p50_ms']:.3f} ms, p99 {v['p99_ms']:.3f} ms)"
        for st, v in r["by_status"].items()
    ]
    print("the service's bearings by the status of their estimate: " + "; ".join(parts))
    for name, v in r.get("breakdown", {}).items():
        what = {
            "handle": "a bearing's handling in the service (tracker, observer, publication)",
            "publish": "of which its estimate's publication over Zenoh",
        }[name]
        print(
            f"{what}: p50 {v['p50_ms']:.3f} ms, p90 {v['p90_ms']:.3f} ms, p99 "
            f"{v['p99_ms']:.3f} ms, max {v['max_ms']:.3f} ms ({v['count']})"
        )
    if base is not None:
        r["baseline"] = base
        r["ratio_to_relay"] = {
            k: r[k] / base[k] for k in ("p50_ms", "p90_ms", "p99_ms", "p999_ms", "mean_ms")
        }
        ratio = r["ratio_to_relay"]
        print(
            f"service / relay: p50 {ratio['p50_ms']:.2f}x, p90 {ratio['p90_ms']:.2f}x, "
            f"p99 {ratio['p99_ms']:.2f}x, mean {ratio['mean_ms']:.2f}x"
        )
    print(
        f"sender lateness p99 {r['sender_late_p99_ms']:.3f} ms, max "
        f"{r['sender_late_max_ms']:.3f} ms; goal p99 < {GOAL_P99_MS:g} ms: "
        f"{'met' if r['goal_met'] else 'NOT met'}"
        + ("" if base is None else f" (the relay's own p99: {base['p99_ms']:.3f} ms)")
    )
    if args.json:
        args.json.write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
