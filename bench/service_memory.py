"""Resident memory of the service over a long accelerated run (a million messages or more).

Run: ``python bench/service_memory.py`` (ten minutes; ``--duration-s 60`` for a check).

What is measured: VmRSS of the service process (``/proc/PID/status``) at the start, 5 s after
the first data, then every ``--sample-s`` (30 s) of sending, and at the end; reported as start,
end, max (and the kernel's VmHWM peak), growth (end minus start) and the slope of a straight
line through the samples from the first minute on, in MB per 10 minutes.

How: the service runs as its own process (``python -m mav_observer run``, its default estimate
rate limit unless ``--estimate-rate-hz`` is given) reading ``udpin:127.0.0.1:PORT``, Zenoh on
``tcp/127.0.0.1:ZPORT``; this process subscribes to its estimates and status (so that they are
delivered, not only published). The emitter's orbit scenario with gimbal bearings (0.5 deg
noise) is generated as it is sent (nothing held in memory here) and sent from a plain UDP
socket, one frame per datagram, paced on the real clock at ``--speed`` times the scenario's
time. The mix in scenario time is the typical one of ``bench/service_rate.py``: per second 50
LOCAL_POSITION_NED and 50 GLOBAL_POSITION_INT, 30 GIMBAL_DEVICE_ATTITUDE_STATUS, 20 ATTITUDE and
20 ATTITUDE_QUATERNION, 1 each of HEARTBEAT, SYSTEM_TIME, SYS_STATUS, 100 of other telemetry:
273 messages/s, times ``--speed`` (default 7: about 1900 messages/s, 1.15 million in 600 s).
The service's own count (its status's ``messages``) and the kernel's drops on its socket are
reported too. Goal: growth under 5 MB.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _proc import connect_to_service, finish, print_log_tail, proc_status_kb, start_service  # noqa: E402

from mav_observer.mavlink.connection import udp_socket_stats  # noqa: E402
from sim import emitter, fuzz, scenarios  # noqa: E402

MIX_HZ = {"position_hz": 50.0, "bearing_hz": 30.0, "attitude_hz": 20.0, "background_hz": 100.0}
GOAL_GROWTH_MB = 5.0


def run(args: argparse.Namespace, *, fuzz_share: float = 0.0) -> dict[str, Any]:
    """The run above; ``fuzz_share``: also send that many ``sim.fuzz`` garbage frames per valid
    frame, interleaved (``bench/soak.py``). The result also holds the data times of the
    estimates received and the last 600 of them (for gaps and accuracy)."""
    rng = np.random.default_rng(args.seed)
    garbage = fuzz.garbage(rng, 10**9) if fuzz_share > 0.0 else None
    fuzz_sent = 0
    est_t: list[float] = []
    last_est: list[dict[str, Any]] = []
    sim_s = args.duration_s * args.speed + 5.0
    em = emitter.Emitter(
        scenarios.orbit(duration_s=sim_s),
        emitter.EmitterConfig(
            duration_s=sim_s, bearing="gimbal", bearing_noise_deg=0.5, seed=args.seed, **MIX_HZ
        ),
    )
    extra = ["--log-level", args.service_log_level]
    if args.estimate_rate_hz is not None:
        extra += ["--estimate-rate-hz", str(args.estimate_rate_hz)]
    svc, mav_port, z_port, log = start_service(extra)
    session = None
    sock = None
    estimates = [0]
    statuses: list[bytes] = []
    samples: list[tuple[float, float]] = []  # (s since the first send, RSS MB)
    sent = 0
    try:
        session = connect_to_service(svc, mav_port, z_port)

        def on_estimate(s: Any) -> None:
            estimates[0] += 1
            d = json.loads(s.payload.to_bytes())
            est_t.append(d["t_boot_s"])
            last_est.append(d)
            if len(last_est) > 1200:
                del last_est[:600]

        subs = [
            session.declare_subscriber("mav_observer/1/gimbal/estimate", on_estimate),
            session.declare_subscriber(
                "mav_observer/1/status", lambda s: statuses.append(s.payload.to_bytes())
            ),
        ]
        time.sleep(0.5)
        idle_mb = proc_status_kb(svc.pid, "VmRSS") / 1024
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        addr = ("127.0.0.1", mav_port)
        perf = time.perf_counter
        sleep = time.sleep
        speed = args.speed
        due_samples = [args.start_s, *np.arange(args.sample_s, args.duration_s, args.sample_s)]
        next_i = 0
        t0 = perf() + 0.005
        t_stop = t0 + args.duration_s
        for e in em.emissions():
            due = t0 + e.t_emit_s / speed
            if due >= t_stop:
                break
            d = due - perf()
            if d > 0:
                sleep(d)
            sock.sendto(e.frame, addr)
            sent += 1
            if garbage is not None and rng.random() < fuzz_share:
                sock.sendto(next(garbage)[1], addr)
                fuzz_sent += 1
            if next_i < len(due_samples) and perf() - t0 >= due_samples[next_i]:
                samples.append((perf() - t0, proc_status_kb(svc.pid, "VmRSS") / 1024))
                next_i += 1
                print(f"  {samples[-1][0]:6.0f} s  RSS {samples[-1][1]:7.2f} MB", flush=True)
        send_wall = perf() - t0
        samples.append((send_wall, proc_status_kb(svc.pid, "VmRSS") / 1024))
        hwm_mb = proc_status_kb(svc.pid, "VmHWM") / 1024
        last, stable_since = -1, perf()
        while perf() < t0 + send_wall + 6.0:
            m = max((json.loads(s).get("messages", 0) for s in list(statuses)), default=0)
            if m != last:
                last, stable_since = m, perf()
            elif m >= sent or perf() - stable_since > 2.5:
                break
            sleep(0.1)
        drops = (udp_socket_stats(mav_port) or (0, 0))[1]
        alive = svc.poll() is None
        for s in subs:
            s.undeclare()
    finally:
        code, service_log = finish(svc, log, sock, session)
    docs = [json.loads(s) for s in statuses]
    counted = max((d.get("messages", 0) for d in docs), default=0)
    rss = np.array([m for _, m in samples])
    late = [(t, m) for t, m in samples if t >= 60.0]
    slope = (
        float(np.polyfit([t for t, _ in late], [m for _, m in late], 1)[0]) * 600.0
        if len(late) >= 3
        else float("nan")
    )
    result = {
        "duration_s": args.duration_s,
        "speed": args.speed,
        "msgs_sent": sent,
        "send_rate_hz": sent / send_wall,
        "messages_counted": counted,
        "udp_drops": drops,
        "estimates_received": estimates[0],
        "idle_rss_mb": idle_mb,
        "start_rss_mb": float(rss[0]),
        "end_rss_mb": float(rss[-1]),
        "max_rss_mb": float(rss.max()),
        "vm_hwm_mb": hwm_mb,
        "growth_mb": float(rss[-1] - rss[0]),
        "slope_mb_per_10min_after_60s": slope,
        "samples": [{"t_s": round(t, 1), "rss_mb": round(m, 3)} for t, m in samples],
        "service_alive_at_end": alive,
        "service_exit": code,
        "service_log_lines": service_log.count("\n"),
        "fuzz_sent": fuzz_sent,
        "estimate_t_boot_s": est_t,
        "last_estimates": last_est[-600:],
        "skipped": (docs[-1].get("skipped", {}) | docs[-1].get("link_skipped", {})) if docs else {},
        "goal_growth_mb": GOAL_GROWTH_MB,
    }
    result["goal_met"] = result["growth_mb"] < GOAL_GROWTH_MB
    print_log_tail(service_log)
    return result


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """The options :func:`run` reads (shared with ``bench/soak.py``)."""
    parser.add_argument("--duration-s", type=float, default=600.0, help="sending time")
    parser.add_argument("--speed", type=float, default=7.0, help="scenario time / wall time")
    parser.add_argument("--start-s", type=float, default=5.0, help="the start sample, after data")
    parser.add_argument("--sample-s", type=float, default=30.0, help="RSS sampling period")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--service-log-level", default="WARNING")
    parser.add_argument("--json", type=Path, help="also write the results as JSON")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_run_arguments(parser)
    parser.add_argument("--estimate-rate-hz", type=float, help="service option (default: its own)")
    args = parser.parse_args()
    print(
        f"sending {args.duration_s:g} s at {args.speed:g} x the typical mix "
        f"(~{273 * args.speed:.0f} messages/s)",
        flush=True,
    )
    r = run(args)
    print(
        f"{'sent':>8s} {'counted':>8s} {'msg/s':>6s} {'drops':>6s} {'idle_MB':>8s} "
        f"{'start_MB':>8s} {'end_MB':>8s} {'max_MB':>8s} {'hwm_MB':>8s} {'growth':>7s} "
        f"{'MB/10min':>8s}"
    )
    print(
        f"{r['msgs_sent']:8d} {r['messages_counted']:8d} {r['send_rate_hz']:6.0f} "
        f"{r['udp_drops']:6d} {r['idle_rss_mb']:8.2f} {r['start_rss_mb']:8.2f} "
        f"{r['end_rss_mb']:8.2f} {r['max_rss_mb']:8.2f} {r['vm_hwm_mb']:8.2f} "
        f"{r['growth_mb']:7.2f} {r['slope_mb_per_10min_after_60s']:8.2f}"
    )
    print(
        f"goal growth < {GOAL_GROWTH_MB:g} MB: {'met' if r['goal_met'] else 'NOT met'}"
        + ("" if r["msgs_sent"] >= 1_000_000 else " (fewer than a million messages: a check)")
    )
    if args.json:
        drop = ("estimate_t_boot_s", "last_estimates")
        args.json.write_text(json.dumps({k: v for k, v in r.items() if k not in drop}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
