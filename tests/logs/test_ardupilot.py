"""DataFlash records as MAVLink messages (mav_observer/logs/ardupilot.py)."""

from __future__ import annotations

import math
from itertools import pairwise
from pathlib import Path

import pytest
from flightlogs import LOGS

from mav_observer.logs.formats import LogReader
from mav_observer.mavlink.tlog import TlogReader


def by_type(messages: list[tuple[float, object]]) -> dict[str, list[object]]:
    out: dict[str, list[object]] = {}
    for _, m in messages:
        out.setdefault(m.get_type(), []).append(m)  # type: ignore[attr-defined]
    return out


def test_the_converted_flight_gives_back_the_tlogs_messages(flight: dict[str, Path]) -> None:
    tl = by_type(list(TlogReader(flight["tlog"])))
    log = LogReader(flight["bin"], "dataflash")
    msgs = list(log)
    assert all(b[0] >= a[0] for a, b in pairwise(msgs))  # time order
    df = by_type(msgs)
    for a, b in zip(tl["LOCAL_POSITION_NED"], df["LOCAL_POSITION_NED"], strict=True):
        assert a.time_boot_ms == b.time_boot_ms
        assert (b.x, b.vx, b.vy) == pytest.approx((a.x, a.vx, a.vy), abs=1e-4)
    for a, b in zip(tl["ATTITUDE"], df["ATTITUDE"], strict=True):
        assert b.yaw == pytest.approx(math.remainder(a.yaw, 2 * math.pi), abs=2e-4)  # cdeg
    assert len(df["MOUNT_ORIENTATION"]) == len(tl["GIMBAL_DEVICE_ATTITUDE_STATUS"])
    assert log.stats.format == "DataFlash" and not log.stats.damage()


def test_mount_angles_by_column_name_across_layouts() -> None:
    """ArduSub 4.8 inserts a Mode column before the angles; the demanded angles are NaN
    (a servo mount), the measured ones are read."""
    log = LogReader(LOGS / "ardusub48_sitl_mnt_mode_first512k.bin", "dataflash")
    mounts = [m for _, m in log if m.get_type() == "MOUNT_ORIENTATION"]
    assert len(mounts) == 99
    assert all(math.isfinite(m.pitch) and math.isfinite(m.yaw_absolute) for m in mounts)
    assert any(m.pitch != 0.0 for m in mounts)


def test_an_old_log_reads_ekf2_and_says_what_it_lacks() -> None:
    log = LogReader(LOGS / "plane_nkf1_truncated64k_pymavlink.bin", "dataflash")
    kinds = by_type(list(log))
    assert len(kinds["LOCAL_POSITION_NED"]) == 24  # NKF1, no core column
    assert kinds["GPS_GLOBAL_ORIGIN"][0].latitude != 0
    assert any("no MNT record" in n for n in log.stats.notes)
    assert log.stats.truncated_tail
