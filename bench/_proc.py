"""What the service benchmarks share: reaching the service, reading ``/proc``."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from typing import Any

from mav_observer.mavlink.connection import udp_socket_stats
from mav_observer.outputs.zenoh_io import open_session, session_config
from sim.live import free_port, service_command, stop_process, wait_for_peer


def cpu_ticks(pid: int, tid: int | None = None) -> int:
    """utime + stime (clock ticks) of process ``pid`` (or of its thread ``tid``)."""
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    with open(path, encoding="ascii") as fh:
        fields = fh.read().rpartition(")")[2].split()
    return int(fields[11]) + int(fields[12])


def proc_status_kb(pid: int, field: str) -> int:
    """A ``kB`` field (VmRSS, VmHWM) of ``/proc/PID/status``."""
    with open(f"/proc/{pid}/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise KeyError(field)


def connect_to_service(svc: subprocess.Popen[Any], mav_port: int, z_port: int) -> Any:
    """A Zenoh session connected to the service's peer, once its MAVLink port is bound."""
    session = open_session(session_config(listen=[], connect=[f"tcp/127.0.0.1:{z_port}"]))
    if not wait_for_peer(session, 20.0):
        raise RuntimeError("the service did not come up on its Zenoh port")
    end = time.monotonic() + 20.0
    while udp_socket_stats(mav_port) is None:
        if time.monotonic() > end or svc.poll() is not None:
            raise RuntimeError("the service did not bind its MAVLink port")
        time.sleep(0.02)
    return session


def start_service(
    extra: list[str], *, prefix: list[str] | None = None
) -> tuple[subprocess.Popen[Any], int, int, Any]:
    """The service on free loopback ports, its output to a temporary file: ``(process,
    MAVLink UDP port, Zenoh TCP port, log file)``. Stop it with ``sim.live.stop_process``.
    ``prefix``: run it as ``python PREFIX... run ...`` instead of ``python -m mav_observer
    run ...`` (a wrapper script that ends in ``mav_observer.app.cli.main``)."""
    mav_port = free_port(socket.SOCK_DGRAM)
    z_port = free_port(socket.SOCK_STREAM)
    log = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 - the caller closes it
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    command = service_command(mav_port, z_port, *extra)
    if prefix is not None:  # [python, -m, mav_observer, run, ...] -> [python, *prefix, run, ...]
        command = [command[0], *prefix, *command[3:]]
    svc = subprocess.Popen(command, stdout=log, stderr=log, env=env)
    return svc, mav_port, z_port, log


def print_log_tail(service_log: str, lines: int = 10) -> None:
    if service_log.strip():
        print("service log (last lines):", *service_log.splitlines()[-lines:], sep="\n  ")
        sys.stdout.flush()


def finish(svc: subprocess.Popen[Any], log: Any, *closables: Any) -> tuple[int, str]:
    """Close the sockets and sessions given (``None`` skipped), stop the service (SIGTERM; a
    no-op if it already ended) and read its log: ``(exit code, log text)``."""
    for obj in closables:
        if obj is not None:
            obj.close()
    code, _ = stop_process(svc)
    log.seek(0)
    text = log.read()
    log.close()
    return code, text
