"""Faults of a recorded link, applied to a tlog's records (8-byte big-endian Unix
microseconds, then a MAVLink frame): what real logs do to a replay's time axis and data.

* :func:`telemetry_gap`: the link drops out for a while (every record, or one message's);
* :func:`speed_up`: a simulator run faster than real time, recorded on the wall clock (the
  autopilot's ``time_boot_ms`` advances ``factor`` s per tlog second);
* :func:`recorder_stall`: a sped-up log whose recorder stalls: records lost, and the stamps
  after the loss do not advance across it (a gap in the autopilot's clock, none in the tlog's);
* :func:`bursty`: the recorder flushes in bursts, every record of a burst stamped alike.

Each takes and returns the records as bytes (``sim.inject.InjectResult.records``); damage
chunks (no stamp) are kept as they are.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from sim.inject import TlogRecord, split_records

Records = list[bytes]


def _stamped(records: Sequence[bytes]) -> list[TlogRecord]:
    return split_records(b"".join(records))


def _restamp(recs: Sequence[TlogRecord], new_us: Callable[[int], int]) -> Records:
    return [r.data if r.t_us is None else new_us(r.t_us).to_bytes(8, "big") + r.data[8:]
            for r in recs]  # fmt: skip


def _span(recs: Sequence[TlogRecord]) -> tuple[int, int]:
    ts = [r.t_us for r in recs if r.t_us is not None]
    return ts[0], ts[-1]


def telemetry_gap(
    records: Sequence[bytes], at: float, gap_s: float, msgid: int | None = None
) -> Records:
    """Drop every record (or those of message ``msgid``) in ``gap_s`` s of tlog time from
    ``at`` (a fraction of the log's span)."""
    recs = _stamped(records)
    t0, t1 = _span(recs)
    a = t0 + at * (t1 - t0)
    b = a + gap_s * 1e6
    kept = []
    for r in recs:
        inside = r.t_us is not None and a <= r.t_us < b
        if not inside or (msgid is not None and r.msgid != msgid):
            kept.append(r.data)
    return kept


def speed_up(records: Sequence[bytes], factor: float) -> Records:
    """The tlog's stamps run ``factor`` times slower than its autopilot's clock."""
    recs = _stamped(records)
    t0, _ = _span(recs)
    return _restamp(recs, lambda t: t0 + round((t - t0) / factor))


def recorder_stall(records: Sequence[bytes], factor: float, at: float, lost_s: float) -> Records:
    """:func:`speed_up` by ``factor``, then from ``at`` (a fraction of the span) ``lost_s`` s
    of tlog time lost, the stamps after the loss moved back by as much."""
    recs = _stamped(speed_up(records, factor))
    t0, t1 = _span(recs)
    a = t0 + at * (t1 - t0)
    lost = round(lost_s * 1e6)
    kept = [r for r in recs if r.t_us is None or not a <= r.t_us < a + lost]
    return _restamp(kept, lambda t: t - lost if t >= a + lost else t)


def bursty(records: Sequence[bytes], period_s: float) -> Records:
    """Every record stamped at the end of its ``period_s`` burst, 50 us apart within it."""
    recs = _stamped(records)
    t0, _ = _span(recs)
    p = round(period_s * 1e6)
    state = {"burst": -1, "k": 0}

    def stamp(t: int) -> int:
        burst = (t - t0) // p
        state["k"] = state["k"] + 1 if burst == state["burst"] else 0
        state["burst"] = burst
        return t0 + (burst + 1) * p + 50 * state["k"]

    return _restamp(recs, stamp)


def parse(spec: str) -> Callable[[Sequence[bytes]], Records]:
    """A fault from its text: ``gap:AT:SECONDS[:MSGID]``, ``speed:FACTOR``,
    ``stall:FACTOR:AT:SECONDS``, ``burst:SECONDS`` or ``none``."""
    kind, *args = spec.split(":")
    try:
        a = [float(x) for x in args]
        if kind == "none" and not a:
            return list
        if kind == "gap" and len(a) in (2, 3):
            msgid = int(a[2]) if len(a) == 3 else None
            return lambda r: telemetry_gap(r, a[0], a[1], msgid)
        if kind == "speed" and len(a) == 1:
            return lambda r: speed_up(r, a[0])
        if kind == "stall" and len(a) == 3:
            return lambda r: recorder_stall(r, a[0], a[1], a[2])
        if kind == "burst" and len(a) == 1:
            return lambda r: bursty(r, a[0])
    except ValueError:
        pass
    raise ValueError(f"unknown fault {spec!r}")
