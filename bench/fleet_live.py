"""A fleet live on loopback, every process its own Zenoh session joined through a router.

Run: ``python bench/fleet_live.py [--runs N] [--duration S] [--fleet fleet_hover] [--json
FILE]`` (20 runs of 10 s by default, about six minutes).

``mav-observer router``; one ``mav-observer run`` per vehicle (a Zenoh client of the router,
reading its own UDP port); ``mav-observer fuse`` (a client too); and this process's own
client subscribed to the fused estimate; ``python -m sim fleet --to ...`` flies two vehicles
in real time. Measured: the delay from a service publishing a ray to the fused estimate it
made reaching this third process, pooled over the runs (goal: under 20 ms at the median),
and each run's last fused estimate against the truth.
"""

from __future__ import annotations

import argparse
import json
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pymap3d  # noqa: E402

from mav_observer.mavlink.connection import udp_socket_stats  # noqa: E402
from mav_observer.outputs.zenoh_io import open_session, session_config  # noqa: E402
from sim.fleet import make_fleet  # noqa: E402
from sim.live import free_port, stop_process  # noqa: E402

PY = [sys.executable, "-m", "mav_observer"]


def _wait(cond: Any, timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            raise RuntimeError(f"{what} did not come up in {timeout_s:g} s")
        time.sleep(0.05)


def run(duration_s: float = 20.0, fleet: str = "fleet_hover", seed: int = 0) -> dict[str, Any]:
    """One live run (see the module docstring); every process started here is stopped here."""
    router_ep = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    client = ["--zenoh-mode", "client", "--zenoh-connect", router_ep]
    ports = [free_port(socket.SOCK_DGRAM) for _ in range(2)]
    procs: list[subprocess.Popen[Any]] = []
    got: list[tuple[float, dict[str, Any]]] = []
    lock = threading.Lock()
    logs = tempfile.TemporaryDirectory()
    session = None

    def start(args: list[str], name: str) -> subprocess.Popen[Any]:
        fh = open(Path(logs.name) / f"{name}.log", "w")  # noqa: SIM115 - closed with the dir
        p = subprocess.Popen(args, cwd=ROOT, stdout=fh, stderr=subprocess.STDOUT)
        procs.append(p)
        return p

    def on_fused(sample: Any) -> None:
        t = time.time()
        with lock:
            got.append((t, json.loads(sample.payload.to_bytes())))

    try:
        start([*PY, "router", "--listen", router_ep], "router")
        for k, port in enumerate(ports, 1):
            start([*PY, "run", "--mavlink", f"udpin:127.0.0.1:{port}", *client], f"service{k}")
        fuse_log = Path(logs.name) / "fuse.log"
        start([*PY, "fuse", "--target", "target=1/gimbal,2/gimbal", "--mode", "client",
               "--connect", router_ep], "fuse")  # fmt: skip
        conf = session_config(mode="client", listen=[], connect=[router_ep])
        session = open_session(conf, retry_s=20.0)
        sub = session.declare_subscriber("mav_observer/fused/target", on_fused)
        for port in ports:
            _wait(lambda p=port: udp_socket_stats(p) is not None, 30.0, f"the service on {port}")
        _wait(lambda: "fusing" in fuse_log.read_text(), 30.0, "fuse")
        time.sleep(0.5)  # the subscriptions reach the router
        fl = make_fleet(fleet, vehicles=2, seed=seed, duration_s=duration_s)
        to = ",".join(f"udpout:127.0.0.1:{p}" for p in ports)
        subprocess.run([sys.executable, "-m", "sim", "fleet", "--fleet", fleet, "--vehicles", "2",
                        "--duration", str(duration_s), "--seed", str(seed), "--to", to,
                        "--speed", "1"], cwd=ROOT, check=True, capture_output=True)  # fmt: skip
        time.sleep(1.0)
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        for p in reversed(procs):
            stop_process(p)
        texts = {f.stem: f.read_text() for f in Path(logs.name).glob("*.log")}
        logs.cleanup()
    with lock:
        rows = list(got)
    lat = [1000.0 * (t - d["ray_sent_unix_s"]) for t, d in rows if d.get("ray_sent_unix_s")]
    last = rows[-1][1] if rows else {}
    err = None
    if last.get("lat_deg") is not None:
        lat0, lon0, alt0 = fl.target_geodetic
        n, e, d = pymap3d.geodetic2ned(last["lat_deg"], last["lon_deg"], last["alt_m"],
                                       lat0, lon0, alt0)  # fmt: skip
        err = [float(n), float(e), float(d)]
    return {
        "fused_messages": len(rows),
        "latencies_ms": lat,
        "latency_ms_p50": statistics.median(lat) if lat else None,
        "latency_ms_p90": sorted(lat)[int(0.9 * len(lat))] if lat else None,
        "last": last,
        "last_error_ned_m": err,
        "logs": texts,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--runs", type=int, default=20, help="live runs pooled (seeds 0..N-1)")
    p.add_argument("--fleet", default="fleet_hover")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    runs = [run(args.duration, args.fleet, seed) for seed in range(args.runs)]
    lat = sorted(x for r in runs for x in r["latencies_ms"])
    z = [
        abs(e) / sd
        for r in runs
        if r["last_error_ned_m"] is not None
        for e, sd in zip(r["last_error_ned_m"], r["last"]["pos_std_ned_m"], strict=True)
    ]
    res = {
        "runs": len(runs),
        "fused_messages": sum(r["fused_messages"] for r in runs),
        "latency_ms_p50": statistics.median(lat),
        "latency_ms_p90": lat[int(0.9 * len(lat))],
        "converged_runs": sum(r["last"].get("status") == "converged" for r in runs),
        "last_error_sigmas_max": max(z),
        "last_error_over_3_sigma": sum(v > 3.0 for v in z) / len(z),
    }
    print(f"{res['runs']} live runs of {args.duration:g} s, {res['fused_messages']} fused "
          f"estimates; ray published to fused estimate received: p50 "
          f"{res['latency_ms_p50']:.1f} ms, p90 {res['latency_ms_p90']:.1f} ms; last estimate "
          f"converged in {res['converged_runs']} runs, its error at most "
          f"{res['last_error_sigmas_max']:.1f} sigma on an axis")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
