"""Raw MAVLink captures (mav_observer/logs/rawlink.py): pymavlink's messages, on the
autopilot's clock."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
from flightlogs import LOGS
from mavmsg import frame

from mav_observer.logs.rawlink import RawLinkReader
from mav_observer.mavlink.dialect import MSG_ID, connect


def test_the_same_frames_as_pymavlink_text_skipped() -> None:
    path = LOGS / "copter_sitl_textprefix_first256k.tlog.raw"
    conn = connect(str(path), notimestamps=True)
    theirs: Counter[str] = Counter()
    while (m := conn.recv_match()) is not None:
        if m.get_type() != "BAD_DATA":
            theirs[m.get_type()] += 1
    r = RawLinkReader(path, None)
    ours = Counter(m.get_type() for _, m in r)
    assert ours == theirs
    assert r.stats.resyncs >= 1 and r.stats.skipped_bytes >= 30  # the text at its start


def test_the_time_axis_is_the_autopilots_clock_across_a_reboot(tmp_path: Path) -> None:
    frames = [frame("ATTITUDE", ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0) for ms in (5000, 5100, 300)]
    frames.insert(2, frame("MOUNT_STATUS", 1, 1, 0, 0, 0))
    p = tmp_path / "x.rlog"
    p.write_bytes(b"".join(frames))
    ids = {MSG_ID["ATTITUDE"], MSG_ID["MOUNT_STATUS"]}
    got = [(t, m.get_type()) for t, m in RawLinkReader(p, ids)]
    assert [t for t, _ in got][:3] == pytest.approx([5.0, 5.1, 5.1])  # untimed: the latest
    assert got[3][0] > 5.1  # after the reboot the arrival goes on
