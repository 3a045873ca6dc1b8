"""``python -m sim live`` (``mav-observer demo``): the whole chain on loopback, live.

The emitter flies a scenario (accelerated) and sends it as MAVLink over UDP to the service,
which runs as its own process (``python -m mav_observer run``) with its embedded Zenoh peer;
a subscriber here prints a table of estimate against truth until the estimate has been
converged, and within tolerance, for ``hold_s`` of scenario time, then a one-line verdict.
Everything is on 127.0.0.1 with free ports; every process started here is ended here.

Exit status: 0 converged, 2 not converged by the end of the scenario, 1 on a failure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from mav_observer.core import compiled
from mav_observer.outputs import zenoh_io
from sim import emitter, scenarios

#: Convergence tolerances (those of the MAVLink issue's acceptance): position error within
#: 5 % of the range, bias error within 0.1 m/s.
POS_TOL_REL = 0.05
BIAS_TOL_MPS = 0.1


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A port on 127.0.0.1 that is free now (for TCP or UDP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def service_command(mavlink_port: int, zenoh_port: int, *extra: str) -> list[str]:
    """The service's command line on loopback ports."""
    return [
        sys.executable,
        "-m",
        "mav_observer",
        "run",
        "--mavlink",
        f"udpin:127.0.0.1:{mavlink_port}",
        "--zenoh-listen",
        f"tcp/127.0.0.1:{zenoh_port}",
        *extra,
    ]


def wait_for_peer(session: Any, timeout_s: float) -> bool:
    """Wait until ``session`` is connected to some peer or router."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if list(session.info.peers_zid()) or list(session.info.routers_zid()):
            return True
        time.sleep(0.02)
    return False


def stop_process(proc: subprocess.Popen[Any], timeout_s: float = 5.0) -> tuple[int, float]:
    """SIGTERM ``proc`` (ours) and wait; SIGKILL if it does not end. Returns ``(exit code,
    seconds it took)``."""
    t0 = time.monotonic()
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return int(proc.returncode), time.monotonic() - t0


@dataclass
class Errors:
    t_s: float
    range_m: float
    range_est_m: float
    pos_err_m: float
    bias_err_mps: float
    status: str

    @property
    def rel(self) -> float:
        return self.pos_err_m / self.range_m

    @property
    def within(self) -> bool:
        return (
            self.status == "converged"
            and self.rel <= POS_TOL_REL
            and self.bias_err_mps <= BIAS_TOL_MPS
        )


def compare(est: dict[str, Any], truth: dict[str, Any], t0_boot_s: float) -> Errors:
    """Errors of an estimate record against the truth record of the same bearing."""
    x = est["rel_pos_ned_m"]
    xt = truth["rel_pos_ned_m"]
    a = est["bias_ned_mps"]
    at = truth["bias_ned_mps"]
    return Errors(
        t_s=est["t_boot_s"] - t0_boot_s,
        range_m=math.dist(xt, (0.0, 0.0, 0.0)),
        range_est_m=est["range_m"],
        pos_err_m=math.dist(x, xt),
        bias_err_mps=math.dist(a, at),
        status=est["status"],
    )


HEADER = (
    f"{'t_s':>6} {'range_m':>8} {'range_est':>9} {'pos_err_m':>9} {'err_%':>6} "
    f"{'bias_err':>8}  status"
)


def row(e: Errors) -> str:
    return (
        f"{e.t_s:6.1f} {e.range_m:8.2f} {e.range_est_m:9.2f} {e.pos_err_m:9.3f} "
        f"{100 * e.rel:6.2f} {e.bias_err_mps:8.4f}  {e.status}"
    )


def main(args: argparse.Namespace) -> int:
    sc = scenarios.make(args.scenario, duration_s=args.duration)
    cfg = emitter.EmitterConfig(
        bearing=args.bearing,
        duration_s=args.duration,
        bearing_noise_deg=args.bearing_noise_deg,
        seed=args.seed,
    )
    em = emitter.Emitter(sc, cfg)
    t0_boot_s = em.boot_ms(0.0) / 1000.0
    mav_port = args.mavlink_port or free_port(socket.SOCK_DGRAM)
    z_port = args.zenoh_port or free_port()
    target = emitter.TARGET_OF[args.bearing]
    print(f"scenario {sc.name}: {sc.description}")
    print(
        f"emitter: {args.bearing} bearings at {cfg.bearing_hz:g} Hz, noise "
        f"{args.bearing_noise_deg:g} deg, {args.speed:g}x real time -> udp 127.0.0.1:{mav_port}; "
        f"service -> zenoh tcp/127.0.0.1:{z_port}, key mav_observer/{cfg.sysid}/{target}/estimate"
    )
    # the estimator compiled (a machine's first run) or loaded here first, so that the service
    # starts on numba's cache instead of compiling while the scenario already plays
    compiled.kernels()
    extra = ["--log-level", args.service_log_level, "--estimate-rate-hz", "0"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    svc = subprocess.Popen(service_command(mav_port, z_port, *extra), env=env)
    session = None
    stop = threading.Event()
    truths: OrderedDict[int, dict[str, Any]] = OrderedDict()
    lock = threading.Lock()

    def keep_truth(t: dict[str, Any]) -> None:
        with lock:
            truths[round(t["t_boot_s"] * 1000)] = t
            while len(truths) > 5000:  # bounded: only recent bearings can still be matched
                truths.popitem(last=False)

    estimates: queue.Queue[dict[str, Any]] = queue.Queue(maxsize=100_000)
    result = 1
    em_thread = None
    try:
        conf = zenoh_io.session_config(listen=[], connect=[f"tcp/127.0.0.1:{z_port}"])
        session = zenoh_io.open_session(conf)
        if not wait_for_peer(session, 15.0):
            print("demo: the service did not come up on its Zenoh port", file=sys.stderr)
            return 1
        key = f"mav_observer/{cfg.sysid}/{target}/estimate"
        sub = session.declare_subscriber(
            key, lambda s: estimates.put_nowait(json.loads(s.payload.to_string()))
        )
        time.sleep(0.3)  # the service's UDP port is bound before its Zenoh session is up
        em_thread = threading.Thread(
            target=emitter.run,
            args=(em,),
            kwargs={
                "to": f"udpout:127.0.0.1:{mav_port}",
                "speed": args.speed,
                "stop": stop,
                "on_truth": keep_truth,
            },
            daemon=True,
        )
        em_thread.start()
        print(HEADER)
        next_row = 0.0
        within_since: float | None = None
        last: Errors | None = None
        while True:
            try:
                est = estimates.get(timeout=0.2)
            except queue.Empty:
                if not em_thread.is_alive() and estimates.empty():
                    break
                if svc.poll() is not None:
                    print(f"demo: the service exited ({svc.returncode})", file=sys.stderr)
                    return 1
                continue
            with lock:
                truth = truths.get(round(est["t_boot_s"] * 1000))
            if truth is None:
                continue
            e = compare(est, truth, t0_boot_s)
            last = e
            if e.t_s >= next_row:
                print(row(e), flush=True)
                next_row = math.floor(e.t_s / args.every) * args.every + args.every
            if e.within:
                within_since = e.t_s if within_since is None else within_since
                if e.t_s - within_since >= args.hold_s:
                    break
            else:
                within_since = None
        sub.undeclare()
        converged = within_since is not None and last is not None
        if last is None:
            print("verdict: NO ESTIMATE received", flush=True)
            result = 2
        else:
            if last.t_s >= next_row - args.every + 1e-9:
                print(row(last))
            verdict = (
                f"CONVERGED at {within_since:.1f} s of scenario time"
                if converged
                else f"NOT CONVERGED ({last.status})"
            )
            print(
                f"verdict: {verdict}: final position error {last.pos_err_m:.3f} m "
                f"({100 * last.rel:.2f} % of range {last.range_m:.1f} m), bias error "
                f"{last.bias_err_mps:.4f} m/s (tolerances {100 * POS_TOL_REL:g} % and "
                f"{BIAS_TOL_MPS:g} m/s, held {args.hold_s:g} s)",
                flush=True,
            )
            result = 0 if converged else 2
    finally:
        stop.set()
        if em_thread is not None:
            em_thread.join(5.0)
        if session is not None:
            session.close()
        code, took = stop_process(svc)
        print(f"service stopped: exit {code} in {took:.2f} s")
        if code != 0 and result == 0:
            result = 1
    return result


def add_parser(sub: Any) -> None:
    live = sub.add_parser(
        "live",
        help="emitter -> UDP -> the service -> Zenoh -> a table of estimate against truth",
    )
    live.add_argument(
        "--scenario",
        default="orbit",
        choices=sorted(s for s in scenarios.SCENARIOS if s != "planar"),
    )
    live.add_argument("--bearing", default="gimbal", choices=emitter.BEARINGS)
    live.add_argument("--speed", type=float, default=20.0, help="times real time")
    live.add_argument("--duration", type=float, default=300.0, help="scenario seconds at most")
    live.add_argument("--bearing-noise-deg", type=float, default=0.5)
    live.add_argument("--seed", type=int, default=0)
    live.add_argument("--every", type=float, default=10.0, help="a table row every N s")
    live.add_argument(
        "--hold-s", type=float, default=20.0, help="converged and within tolerance this long"
    )
    live.add_argument("--mavlink-port", type=int, default=0, help="UDP port (0: a free one)")
    live.add_argument("--zenoh-port", type=int, default=0, help="TCP port (0: a free one)")
    live.add_argument("--service-log-level", default="WARNING")
    live.set_defaults(func=main)
