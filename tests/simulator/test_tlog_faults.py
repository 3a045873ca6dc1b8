"""Faults of a recorded link applied to a tlog's records (sim.tlog_faults)."""

from __future__ import annotations

import itertools

import pytest
from pymavlink.dialects.v20 import ardupilotmega as apm

from sim import tlog_faults
from sim.inject import LPN_ID, split_records

T0_US = 1_700_000_000_000_000


def _log(n: int = 100, dt_s: float = 0.1) -> list[bytes]:
    """``n`` LOCAL_POSITION_NED and as many HEARTBEAT records, ``dt_s`` apart in both the
    tlog's stamps and time_boot_ms."""
    mav = apm.MAVLink(None, srcSystem=1, srcComponent=1)
    out = []
    for i in range(n):
        t_us = T0_US + round(i * dt_s * 1e6)
        lpn = apm.MAVLink_local_position_ned_message(round(i * dt_s * 1000), i, 0, 0, 1, 0, 0)
        hb = apm.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)
        out.append(t_us.to_bytes(8, "big") + lpn.pack(mav))
        out.append((t_us + 10).to_bytes(8, "big") + hb.pack(mav))
    return out


def _stamps(records: list[bytes], msgid: int | None = None) -> list[int]:
    return [r.t_us for r in split_records(b"".join(records)) if msgid is None or r.msgid == msgid]


def test_a_gap_drops_one_message_or_every_one_for_its_span() -> None:
    log = _log()
    only = tlog_faults.telemetry_gap(log, 0.5, 2.0, LPN_ID)
    every = tlog_faults.telemetry_gap(log, 0.5, 2.0)
    assert len(_stamps(only, LPN_ID)) == 80 and len(_stamps(only)) == 180  # heartbeats kept
    assert len(_stamps(every)) == 160
    gaps = [b - a for a, b in zip(_stamps(every), _stamps(every)[1:], strict=False)]
    assert max(gaps) == pytest.approx(2.1e6, abs=20)


def test_speed_up_and_a_stall_move_the_stamps_not_the_frames() -> None:
    log = _log()
    fast = tlog_faults.speed_up(log, 4.0)
    assert [r[8:] for r in fast] == [r[8:] for r in log]
    assert _stamps(fast)[-2] - T0_US == pytest.approx(9.9e6 / 4.0, abs=1)
    stall = tlog_faults.recorder_stall(log, 4.0, 0.5, 0.5)
    s = _stamps(stall, LPN_ID)
    assert len(s) == 80  # 0.5 s of tlog time at 4x: 2 s of the clock lost
    assert max(b - a for a, b in itertools.pairwise(s)) <= 0.025e6 + 1  # no gap in stamps


def test_bursty_stamps_bunch_in_order() -> None:
    s = _stamps(tlog_faults.bursty(_log(), 0.25))
    assert s == sorted(s)
    assert len({t // 1000 for t in s}) < len(s) / 4


def test_a_fault_from_its_text() -> None:
    log = _log()
    assert tlog_faults.parse("none")(log) == log
    assert tlog_faults.parse("speed:2")(log) == tlog_faults.speed_up(log, 2.0)
    for bad in ("gap:1", "warp:2", "speed:x"):
        with pytest.raises(ValueError, match="unknown fault"):
            tlog_faults.parse(bad)
