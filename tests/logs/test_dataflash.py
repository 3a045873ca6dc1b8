"""The DataFlash reader (mav_observer/logs/dataflash.py): the same records as pymavlink's
DFReader on public logs, damaged ones included; columns by the log's own FMT records."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from flightlogs import LOGS
from pymavlink import DFReader

from mav_observer.logs.dataflash import DataFlashError, DataFlashLog

PUBLIC = sorted(LOGS.glob("*.bin"))


def dfreader(path: Path) -> tuple[Counter[str], list[object]]:
    d = DFReader.DFReader_binary(str(path))
    counts: Counter[str] = Counter()
    mnt = []
    while (m := d.recv_msg()) is not None:
        counts[m.get_type()] += 1
        if m.get_type() == "MNT":
            mnt.append(m)
    return counts, mnt


@pytest.mark.parametrize("path", PUBLIC, ids=[p.name for p in PUBLIC])
def test_public_logs_give_dfreaders_records_damage_counted(path: Path) -> None:
    counts, mnt = dfreader(path)
    log = DataFlashLog(path)
    assert Counter(log.stats.by_name) == counts
    if "corrupt" in path.name:  # runs of junk: found and stepped over
        assert log.stats.resyncs >= 40 and log.stats.skipped_bytes > 1000
    if mnt:  # ArduSub 4.8: a Mode column moves the angles; read by name
        cols = log.columns("MNT")
        assert cols is not None and "Mode" in cols
        np.testing.assert_allclose(cols["Pitch"], [m.Pitch for m in mnt], equal_nan=True)
        np.testing.assert_allclose(cols["YawE"], [m.YawE for m in mnt], equal_nan=True)


def test_scaled_columns_and_the_time_axis(flight: dict[str, Path]) -> None:
    log = DataFlashLog(flight["bin"])
    att = log.columns("ATT")
    assert att is not None and att["Roll"].dtype == np.float64  # centidegrees scaled
    t = log.time_us(att)
    assert t is not None and np.all(np.diff(t) > 0)
    assert log.columns("NOPE") is None


def test_damage_is_counted_never_fatal(flight: dict[str, Path], tmp_path: Path) -> None:
    data = flight["bin"].read_bytes()
    clean = DataFlashLog(flight["bin"]).stats
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[: len(data) - 7])
    s = DataFlashLog(cut).stats
    assert s.truncated_tail and s.records == clean.records - 1
    junk = tmp_path / "junk.bin"
    mid = len(data) // 2
    junk.write_bytes(data[:mid] + bytes(range(200)) * 3 + data[mid:])
    s = DataFlashLog(junk).stats
    assert s.resyncs >= 1 and clean.records - 3 <= s.records <= clean.records
    foreign = tmp_path / "foreign.bin"
    prefix = b"PK\x03\x04 not a log"
    foreign.write_bytes(prefix + data)
    s = DataFlashLog(foreign).stats
    assert s.records == clean.records and s.skipped_bytes == len(prefix)
    with pytest.raises(DataFlashError, match="no DataFlash format"):
        (tmp_path / "none.bin").write_bytes(b"\xa3\x95\x10" + bytes(500))
        DataFlashLog(tmp_path / "none.bin")
