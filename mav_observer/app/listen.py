"""``mav-observer listen``: print what a running service publishes, as a table or JSON lines.

The Zenoh callbacks only queue what arrives (bounded: a slow terminal drops rows and says
how many); the caller's thread prints. Liveliness changes (``.../alive``) are printed too.
"""

from __future__ import annotations

import json
import queue
import time
from collections.abc import Callable
from typing import Any, TextIO

import zenoh

HEADER = (
    f"{'time':>12} {'key':<34} {'status':<14} {'range_m':>9} "
    f"{'rel_pos_ned_m':>26} {'bias_ned_mps':>22} {'pe':>6}"
)


def _vec(v: Any, fmt: str) -> str:
    if not isinstance(v, list):
        return "-"
    return " ".join("-" if c is None else format(c, fmt) for c in v)


def format_row(key: str, payload: str, t_unix_s: float) -> str:
    """One table row for a sample of ``key`` (an estimate, a status, or anything else)."""
    clock = time.strftime("%H:%M:%S", time.localtime(t_unix_s)) + f".{int(t_unix_s * 10) % 10}"
    try:
        doc = json.loads(payload)
    except ValueError:
        return f"{clock:>12} {key:<34} {payload[:80]}"
    if not isinstance(doc, dict):
        return f"{clock:>12} {key:<34} {payload[:80]}"
    if key.endswith("/estimate"):
        rng = doc.get("range_m")
        return (
            f"{clock:>12} {key:<34} {doc.get('status', '?'):<14} "
            f"{'-' if rng is None else format(rng, '9.2f'):>9} "
            f"{_vec(doc.get('rel_pos_ned_m'), '8.2f'):>26} "
            f"{_vec(doc.get('bias_ned_mps'), '6.2f'):>22} "
            f"{'-' if doc.get('pe') is None else format(doc['pe'], '6.3f'):>6}"
        )
    if key.endswith("/status"):
        link = doc.get("link", {})
        obs = doc.get("observers", {})
        targets = ", ".join(f"{n}: {o.get('status')}" for n, o in obs.items()) or "no target"
        rate = sum(doc.get("rates_hz", {}).values())
        skipped = sum(doc.get("skipped", {}).values()) + sum(doc.get("link_skipped", {}).values())
        return (
            f"{clock:>12} {key:<34} link {link.get('state', '?')}, {rate:.0f} msg/s, "
            f"{skipped} skipped; {targets}"
        )
    return f"{clock:>12} {key:<34} {payload[:80]}"


def listen(
    session: zenoh.Session,
    key_expr: str,
    *,
    out: TextIO,
    json_lines: bool = False,
    count: int | None = None,
    duration_s: float | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.time,
    max_queue: int = 10_000,
) -> int:
    """Print samples on ``key_expr`` until ``count`` samples, ``duration_s`` seconds, or
    ``should_stop()``. Returns the number of samples printed."""
    q: queue.Queue[tuple[str, str, str]] = queue.Queue(maxsize=max_queue)
    dropped = [0]

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            q.put_nowait(("put", str(sample.key_expr), sample.payload.to_string()))
        except queue.Full:
            dropped[0] += 1

    def on_alive(sample: zenoh.Sample) -> None:
        kind = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
        try:
            q.put_nowait((kind, str(sample.key_expr), ""))
        except queue.Full:
            dropped[0] += 1

    sub = session.declare_subscriber(key_expr, on_sample)
    alive_sub = session.liveliness().declare_subscriber(key_expr, on_alive, history=True)
    printed = 0
    end = None if duration_s is None else time.monotonic() + duration_s
    if not json_lines:
        print(HEADER, file=out, flush=True)
    try:
        while (count is None or printed < count) and not should_stop():
            timeout = 0.1
            if end is not None:
                timeout = min(timeout, end - time.monotonic())
                if timeout <= 0:
                    break
            try:
                kind, key, payload = q.get(timeout=timeout)
            except queue.Empty:
                continue
            now = clock()
            if json_lines:
                if kind == "put":
                    try:
                        value: Any = json.loads(payload)
                    except ValueError:
                        value = payload
                    line = json.dumps({"key": key, "t_rx_unix_s": now, "value": value})
                else:
                    line = json.dumps({"key": key, "t_rx_unix_s": now, "liveliness": kind})
            elif kind == "put":
                line = format_row(key, payload, now)
            else:
                line = f"{'':>12} {key:<34} liveliness: {kind}"
            print(line, file=out, flush=True)
            printed += 1
    finally:
        sub.undeclare()
        alive_sub.undeclare()
    if dropped[0]:
        print(f"(dropped {dropped[0]} samples: the terminal was too slow)", file=out)
    return printed


__all__ = ["HEADER", "format_row", "listen"]
