"""PX4 ULog topics as MAVLink messages (mav_observer/logs/px4.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from flightlogs import LOGS

from mav_observer.logs.formats import LogFormatError, LogReader
from mav_observer.logs.px4 import GIMBAL_TOPIC_LINE
from mav_observer.mavlink.tlog import TlogReader


def test_the_converted_flight_gives_back_the_tlogs_messages(flight: dict[str, Path]) -> None:
    tl = [m for _, m in TlogReader(flight["tlog"])]
    log = list(LogReader(flight["ulg"], "ulog"))
    gim_t = [m for m in tl if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    gim_u = [m for _, m in log if m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"]
    assert len(gim_u) == len(gim_t)
    for a, b in zip(gim_t, gim_u, strict=True):
        assert b.flags == a.flags and b.q == pytest.approx(a.q, abs=1e-6)
    lpn = [m for _, m in log if m.get_type() == "LOCAL_POSITION_NED"]
    assert len(lpn) == sum(m.get_type() == "LOCAL_POSITION_NED" for m in tl)
    assert any(m.get_type() == "ATTITUDE_QUATERNION" for _, m in log)


def test_a_px4_log_without_the_gimbal_topic_says_which_line_adds_it() -> None:
    log = LogReader(LOGS / "pyulog_sample_px4_events.ulg", "ulog")
    kinds = {m.get_type() for _, m in log}
    assert "LOCAL_POSITION_NED" in kinds and "GPS_GLOBAL_ORIGIN" in kinds
    assert any(GIMBAL_TOPIC_LINE in n for n in log.stats.notes)
    # PX4's SITL start: positions not yet valid, counted and left out
    assert any("without xy_valid and v_xy_valid, not used" in n for n in log.stats.notes)


def test_a_cut_header_is_a_clear_refusal(flight: dict[str, Path], tmp_path: Path) -> None:
    p = tmp_path / "cut.ulg"
    p.write_bytes(flight["ulg"].read_bytes()[:10])
    with pytest.raises(LogFormatError, match="not a readable ULog"):
        LogReader(p, "ulog")
