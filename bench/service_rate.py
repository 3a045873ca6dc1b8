"""Sustained input rate of the service: the highest multiple of a typical mix it keeps up with.

Run: ``python bench/service_rate.py`` (a few minutes; ``--duration-s 3 --k 1,2,5,10`` for a
quick check).

The typical mix (k = 1), from the emitter's orbit scenario with gimbal bearings, per second:

* 50 LOCAL_POSITION_NED and 50 GLOBAL_POSITION_INT (``position_hz`` 50);
* 30 GIMBAL_DEVICE_ATTITUDE_STATUS (the bearing, ``bearing_hz`` 30, 0.5 deg noise);
* 20 ATTITUDE and 20 ATTITUDE_QUATERNION (``attitude_hz`` 20);
* 1 each of HEARTBEAT, SYSTEM_TIME, SYS_STATUS;
* 100 of other telemetry (``background_hz`` 100: VFR_HUD, RAW_IMU, SERVO_OUTPUT_RAW,
  RC_CHANNELS, SCALED_PRESSURE, MEMINFO, POWER_STATUS, NAV_CONTROLLER_OUTPUT, AHRS2,
  VIBRATION, 10 each);

that is 273 messages/s. For each factor k the same stream is sent k times faster (every rate
times k) for ``--duration-s`` of wall time, one frame per datagram from a plain UDP socket to
the service's ``udpin:127.0.0.1:PORT``, paced on the real clock (each frame waits for its due
time; a sender running late catches up without sleeping). Each k gets a fresh service process
(``--estimate-rate-hz 0``: every estimate is published) and a Zenoh subscriber in this process
for its estimates and its status.

Per k, compared with what was sent:

* messages the service counted: the largest ``messages`` of its status (cumulative per
  vehicle), read once it stops changing after the last send (and the final status on stop);
* estimates: ``observers.gimbal.estimates`` of the status against the bearings sent, and the
  estimates this process received;
* datagrams the kernel dropped on the service's socket (``/proc/net/udp``, its receive buffer
  full: the service did not read fast enough);
* lag: delay from a bearing's ``sendto()`` to its estimate's arrival (``perf_counter`` of this
  process, matched by ``time_boot_ms``), p50 and max over the run and p50 over the last second
  of sending; behind when that last-second p50 exceeds ``--behind-s`` (0.5 s);
* CPU share of the service process (utime + stime from ``/proc/PID/stat`` over the sending
  window, per clock tick) and of its main thread alone (the one that reads and estimates).

A k keeps up when message and estimate losses are each at most 0.1 % and it is not behind.
The run stops after the first k that does not (``--all`` runs every k). Goal: keep up with
k = 10 on one core.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _proc import connect_to_service, cpu_ticks, finish, start_service  # noqa: E402

from mav_observer.mavlink.connection import udp_socket_stats  # noqa: E402
from mav_observer.mavlink.dialect import msg_name  # noqa: E402
from sim import emitter, scenarios  # noqa: E402
from sim.live import stop_process  # noqa: E402

MIX_HZ = {"position_hz": 50.0, "bearing_hz": 30.0, "attitude_hz": 20.0, "background_hz": 100.0}
MAX_LOSS = 0.001
GOAL_K = 10.0


class Stream:
    """The typical mix in scenario time, generated lazily and kept (every k replays a prefix)."""

    def __init__(self, sim_duration_s: float, seed: int) -> None:
        d = sim_duration_s + 1.0
        self.em = emitter.Emitter(
            scenarios.orbit(duration_s=d),
            emitter.EmitterConfig(
                duration_s=d, bearing="gimbal", bearing_noise_deg=0.5, seed=seed, **MIX_HZ
            ),
        )
        self._it = self.em.emissions()
        self.items: list[tuple[float, bytes, int | None, str]] = []

    def upto(self, t_sim_s: float) -> list[tuple[float, bytes, int | None, str]]:
        """Every ``(t_emit_s, frame, bearing key or None, type)`` with ``t_emit_s < t_sim_s``."""
        while not self.items or self.items[-1][0] < t_sim_s:
            e = next(self._it, None)
            if e is None:
                break
            key = None if e.truth is None else round(e.truth["t_boot_s"] * 1000)
            self.items.append((e.t_emit_s, e.frame, key, _type_of(e.frame)))
        n = len(self.items)
        while n and self.items[n - 1][0] >= t_sim_s:
            n -= 1
        return self.items[:n]


def _type_of(frame: bytes) -> str:
    msgid = frame[7] | frame[8] << 8 | frame[9] << 16 if frame[0] == 0xFD else frame[5]
    return msg_name(msgid)


def one_k(k: float, stream: Stream, args: argparse.Namespace) -> dict[str, Any]:
    plan = stream.upto(args.duration_s * k)
    extra = ["--estimate-rate-hz", "0", "--log-level", args.service_log_level]
    svc, mav_port, z_port, log = start_service(extra)
    session = None
    sock = None
    received: list[tuple[float, bytes]] = []
    statuses: list[bytes] = []
    sent_at: dict[int, float] = {}
    try:
        session = connect_to_service(svc, mav_port, z_port)
        subs = [
            session.declare_subscriber(
                "mav_observer/1/gimbal/estimate",
                lambda s: received.append((time.perf_counter(), s.payload.to_bytes())),
            ),
            session.declare_subscriber(
                "mav_observer/1/status", lambda s: statuses.append(s.payload.to_bytes())
            ),
        ]
        time.sleep(0.5)  # the subscriptions reach the service's peer
        main_tid = svc.pid
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        addr = ("127.0.0.1", mav_port)
        perf = time.perf_counter
        sleep = time.sleep
        cpu0, main0, wall0 = cpu_ticks(svc.pid), cpu_ticks(svc.pid, main_tid), perf()
        t0 = wall0 + 0.005
        for t_sim, frame, key, _ in plan:
            d = t0 + t_sim / k - perf()
            if d > 0:
                sleep(d)
            if key is not None:
                sent_at[key] = perf()
            sock.sendto(frame, addr)
        t_end = perf()
        cpu1, main1 = cpu_ticks(svc.pid), cpu_ticks(svc.pid, main_tid)
        # wait for the status count to settle (a status a second)
        last, stable_since = -1, perf()
        deadline = t_end + args.settle_s
        while perf() < deadline:
            m = _max_messages(statuses)
            if m != last:
                last, stable_since = m, perf()
            elif m >= len(plan) or perf() - stable_since > 2.5:
                break
            sleep(0.1)
        drops = (udp_socket_stats(mav_port) or (0, 0))[1]
        alive = svc.poll() is None
        code, _ = stop_process(svc)
        sleep(0.3)  # the final status
        for s in subs:
            s.undeclare()
    finally:
        code, service_log = finish(svc, log, sock, session)
    send_wall = t_end - wall0
    docs = [json.loads(s) for s in statuses]
    messages = max((d.get("messages", 0) for d in docs), default=0)
    # the latest of the statuses that counted every message (a bearing that waited for its
    # attitude is counted a little after the last message)
    last_doc = max(docs, key=lambda d: (d.get("messages", 0), d.get("t_unix_s", 0.0)), default={})
    obs = last_doc.get("observers", {}).get("gimbal", {})
    n_bearings = sum(1 for _, _, key, _ in plan if key is not None)
    delays: list[tuple[float, float]] = []  # (send time, delay)
    for t_recv, payload in received:
        t_sent = sent_at.get(round(json.loads(payload)["t_boot_s"] * 1000))
        if t_sent is not None:
            delays.append((t_sent, t_recv - t_sent))
    dl = np.array([d for _, d in delays])
    tail = np.array([d for t, d in delays if t >= t_end - 1.0])
    tail_p50 = float(np.median(tail)) if tail.size else float("nan")
    msg_loss = 1.0 - messages / len(plan)
    est_loss = 1.0 - int(obs.get("estimates", 0)) / n_bearings
    behind = not tail.size or tail_p50 > args.behind_s
    r = {
        "k": k,
        "msgs_sent": len(plan),
        "bearings_sent": n_bearings,
        "send_wall_s": send_wall,
        "send_rate_hz": len(plan) / send_wall,
        "target_rate_hz": len(plan) / (args.duration_s),
        "messages_counted": messages,
        "msg_loss": msg_loss,
        "udp_drops": drops,
        "estimates": obs.get("estimates"),
        "published": obs.get("published"),
        "estimates_received": len(received),
        "est_loss": est_loss,
        "delay_p50_ms": float(np.median(dl)) * 1000 if dl.size else float("nan"),
        "delay_max_ms": float(dl.max()) * 1000 if dl.size else float("nan"),
        "delay_last_s_p50_ms": tail_p50 * 1000,
        "behind": behind,
        "service_cpu_pct": 100.0 * (cpu1 - cpu0) / os.sysconf("SC_CLK_TCK") / send_wall,
        "main_thread_cpu_pct": 100.0 * (main1 - main0) / os.sysconf("SC_CLK_TCK") / send_wall,
        "skipped": last_doc.get("skipped"),
        "link_skipped": last_doc.get("link_skipped"),
        "service_alive_at_end": alive,
        "service_exit": code,
        "service_log_lines": service_log.count("\n"),
    }
    r["keeps_up"] = bool(
        msg_loss <= MAX_LOSS and est_loss <= MAX_LOSS and not behind and alive and code == 0
    )
    if service_log.strip():
        print(f"service log at k={k:g} (last lines):", *service_log.splitlines()[-5:], sep="\n  ")
    return r


def _max_messages(statuses: list[bytes]) -> int:
    return max((json.loads(s).get("messages", 0) for s in list(statuses)), default=0)


def mix(stream: Stream, sim_s: float) -> dict[str, float]:
    counts: dict[str, int] = {}
    for _, _, _, name in stream.upto(sim_s):
        counts[name] = counts.get(name, 0) + 1
    return {n: round(c / sim_s, 1) for n, c in sorted(counts.items())}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--k", default="1,2,5,10,20,40,80,160", help="rate factors, comma separated"
    )
    parser.add_argument("--duration-s", type=float, default=10.0, help="sending time per k")
    parser.add_argument("--behind-s", type=float, default=0.5, help="lag that means behind")
    parser.add_argument("--settle-s", type=float, default=6.0, help="wait for the last status")
    parser.add_argument("--all", action="store_true", help="do not stop at the first failure")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--service-log-level", default="WARNING")
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    args = parser.parse_args()
    ks = [float(x) for x in args.k.split(",")]
    stream = Stream(max(args.duration_s * max(ks), 100.0), args.seed)
    typical = mix(stream, 100.0)
    print(
        f"typical mix (k=1), messages/s: {sum(typical.values()):.0f} = "
        + ", ".join(f"{n} {v:g}" for n, v in typical.items()),
        flush=True,
    )
    head = (
        f"{'k':>5s} {'sent/s':>7s} {'sent':>7s} {'counted':>7s} {'loss_%':>7s} {'drops':>6s} "
        f"{'bear':>6s} {'est':>6s} {'rcvd':>6s} {'p50_ms':>7s} {'max_ms':>8s} {'last_ms':>8s} "
        f"{'cpu_%':>6s} {'main_%':>6s}  ok"
    )
    print(head, flush=True)
    results = []
    for k in ks:
        r = one_k(k, stream, args)
        results.append(r)
        print(
            f"{k:5g} {r['send_rate_hz']:7.0f} {r['msgs_sent']:7d} {r['messages_counted']:7d} "
            f"{100 * r['msg_loss']:7.3f} {r['udp_drops']:6d} {r['bearings_sent']:6d} "
            f"{r['estimates'] or 0:6d} {r['estimates_received']:6d} {r['delay_p50_ms']:7.2f} "
            f"{r['delay_max_ms']:8.1f} {r['delay_last_s_p50_ms']:8.1f} "
            f"{r['service_cpu_pct']:6.1f} {r['main_thread_cpu_pct']:6.1f}  "
            f"{'yes' if r['keeps_up'] else 'NO'}",
            flush=True,
        )
        if not r["keeps_up"] and not args.all:
            break
    kept = [r["k"] for r in results if r["keeps_up"]]
    ok_prefix = 0.0
    for r in results:
        if not r["keeps_up"]:
            break
        ok_prefix = r["k"]
    summary = {
        "typical_mix_hz": typical,
        "duration_s": args.duration_s,
        "highest_k_kept_up": ok_prefix,
        "highest_k_kept_up_any": max(kept, default=0.0),
        "goal_k": GOAL_K,
        "goal_met": ok_prefix >= GOAL_K,
        "runs": results,
    }
    print(
        f"highest k kept up: {ok_prefix:g} ({ok_prefix * sum(typical.values()):.0f} msg/s); "
        f"goal k >= {GOAL_K:g}: {'met' if summary['goal_met'] else 'NOT met'}"
    )
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
