"""Which log a file is (mav_observer/logs/formats.py), from its content."""

from __future__ import annotations

from pathlib import Path

import pytest
from flightlogs import LOGS

from mav_observer.logs.formats import LogFormatError, sniff


def test_each_kind_is_found_from_its_content_not_its_name(
    flight: dict[str, Path], tmp_path: Path
) -> None:
    for kind, key in (("tlog", "tlog"), ("dataflash", "bin"), ("ulog", "ulg")):
        renamed = tmp_path / f"{key}.log"  # a name that says nothing
        renamed.write_bytes(flight[key].read_bytes())
        assert sniff(renamed) == kind
    assert sniff(LOGS / "ardusub46_sitl_gimbal_first384k.tlog.raw") == "raw"
    assert sniff(LOGS / "copter_sitl_textprefix_first256k.tlog.raw") == "raw"  # text first
    assert sniff(LOGS / "pyulog_sample_px4_events.ulg") == "ulog"


def test_a_damaged_start_is_read_by_what_follows(flight: dict[str, Path], tmp_path: Path) -> None:
    bad = tmp_path / "x.bin"
    bad.write_bytes(b"\x00" * 37 + flight["bin"].read_bytes())
    assert sniff(bad) == "dataflash"


@pytest.mark.parametrize(
    ("content", "why"),
    [(b"", "empty"), (b"%PDF-1.7 hello\n" * 100, "neither a tlog")],
)
def test_a_foreign_file_is_refused_saying_what_it_starts_with(
    tmp_path: Path, content: bytes, why: str
) -> None:
    p = tmp_path / "x.bin"
    p.write_bytes(content)
    with pytest.raises(LogFormatError, match=why):
        sniff(p)
