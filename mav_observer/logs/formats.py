"""Which kind of flight log a file is, from its content, and the reader for it.

``tlog`` (8-byte big-endian Unix microseconds, then a MAVLink frame), ``dataflash``
(ArduPilot ``.bin``: ``A3 95`` record headers, the first an FMT record), ``ulog`` (PX4: the
``ULog`` magic), ``raw`` (MAVLink frames without stamps: Mission Planner ``.rlog``, MAVProxy
``.tlog.raw``). A damaged start (the first bytes neither) is read by what the rest of the
first 64 KiB holds, then by the name's suffix.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from struct import unpack_from
from typing import Any

ULOG_MAGIC = b"ULog\x01\x12\x35"
DF_HEAD = b"\xa3\x95\x80"
SNIFF_BYTES = 1 << 16
TS_MIN_US, TS_MAX_US = 946_684_800_000_000, 4_102_444_800_000_000
KINDS = ("tlog", "dataflash", "ulog", "raw")


class LogFormatError(Exception):
    """A file that is no flight log this reads; the message says what its bytes look like."""


@dataclass
class LogStats:
    """What a read of a DataFlash, ULog or raw file found (the tlog reader has its own)."""

    format: str
    records: int = 0
    bytes_total: int = 0
    resyncs: int = 0
    skipped_bytes: int = 0
    truncated_tail: bool = False
    by_name: Counter[str] = field(default_factory=Counter)
    decode_errors: Counter[str] = field(default_factory=Counter)
    other_damage: dict[str, int] = field(default_factory=dict)
    #: what the log lacks, or how it was read ("no MNT record: ...")
    notes: list[str] = field(default_factory=list)
    first_t_unix_s: float | None = None
    last_t_unix_s: float | None = None

    def count_damage(self, kind: str) -> None:
        self.other_damage[kind] = self.other_damage.get(kind, 0) + 1

    def damage(self) -> dict[str, int]:
        out = {
            "resyncs": self.resyncs,
            "skipped_bytes": self.skipped_bytes,
            "truncated_tail": int(self.truncated_tail),
            **self.other_damage,
        }
        out.update({f"decode_{k}": v for k, v in self.decode_errors.items()})
        return {k: v for k, v in out.items() if v}


def _is_tlog_at(b: bytes, i: int) -> bool:
    if i + 9 > len(b):
        return False
    ts = unpack_from(">Q", b, i)[0]
    return TS_MIN_US <= ts <= TS_MAX_US and b[i + 8] in (0xFD, 0xFE)


def _raw_frames(b: bytes) -> int:
    """How many MAVLink 2 frames follow one another from the first 0xFD found (a cheap
    test, no CRC)."""
    i = b.find(b"\xfd")
    n = 0
    while i >= 0 and i + 12 <= len(b) and b[i] == 0xFD and n < 8:
        i += 12 + b[i + 1] + (13 if b[i + 2] & 1 else 0)
        n += 1
    return n


def sniff(path: str | os.PathLike[str]) -> str:
    """The log's kind (one of :data:`KINDS`); :class:`LogFormatError` if it is none."""
    p = Path(path)
    with open(p, "rb") as fh:
        head = fh.read(SNIFF_BYTES)
    if not head:
        raise LogFormatError("the file is empty")
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DF_HEAD):
        return "dataflash"
    if _is_tlog_at(head, 0) and _is_tlog_at(head, 8 + _frame_len(head, 8)):
        return "tlog"
    if head[0] in (0xFD, 0xFE):
        return "raw"
    # a damaged start: what the rest holds
    if head.count(DF_HEAD) >= 2:
        return "dataflash"
    if head.find(ULOG_MAGIC) > 0:
        return "ulog"
    for i in range(min(len(head) - 9, 4096)):
        if _is_tlog_at(head, i) and _is_tlog_at(head, i + 8 + _frame_len(head, i + 8)):
            return "tlog"
    if _raw_frames(head) >= 4:
        return "raw"
    if p.name.lower().endswith(".tlog"):  # damaged from the start: the reader resyncs
        return "tlog"
    shown = head[:16].hex(" ")
    raise LogFormatError(
        f"neither a tlog, a DataFlash .bin, a ULog nor raw MAVLink (it starts {shown})"
    )


def _frame_len(b: bytes, i: int) -> int:
    if i + 3 > len(b):
        return 0
    if b[i] == 0xFD:
        return 12 + b[i + 1] + (13 if b[i + 2] & 1 else 0)
    if b[i] == 0xFE:
        return 8 + b[i + 1]
    return 0


class LogReader:
    """A DataFlash or ULog file read at once, then iterated as ``(t_boot_s, message)`` (the
    tracker's messages), with :attr:`stats`."""

    def __init__(self, path: str | os.PathLike[str], kind: str) -> None:
        from mav_observer.logs.messages import merged

        self.path = Path(path)
        self.kind = kind
        self.position = 0
        if kind == "dataflash":
            from mav_observer.logs import ardupilot
            from mav_observer.logs.dataflash import DataFlashError, DataFlashLog

            try:
                log = DataFlashLog(self.path)
            except DataFlashError as exc:
                raise LogFormatError(str(exc)) from exc
            self.stats = log.stats
            streams = ardupilot.streams(log, self.stats.notes)
        elif kind == "ulog":
            from mav_observer.logs import px4

            try:
                ulog = px4.load(self.path)
            except px4.ULogError as exc:
                raise LogFormatError(str(exc)) from exc
            self.stats = LogStats(format="ULog", bytes_total=self.path.stat().st_size)
            for d in ulog.data_list:
                self.stats.by_name[d.name] += len(d.data["timestamp"])
            self.stats.records = sum(self.stats.by_name.values())
            dropouts = getattr(ulog, "dropouts", [])
            if dropouts:
                self.stats.other_damage["dropouts"] = len(dropouts)
            if getattr(ulog, "file_corruption", False):
                self.stats.other_damage["corrupt"] = 1
            streams = px4.streams(ulog, self.stats.notes)
        else:
            raise ValueError(kind)
        self._messages: Iterator[tuple[float, Any]] = merged(streams)

    def drop(self, msgids: Iterable[int]) -> None:
        """(Everything is read at once: nothing to stop decoding.)"""

    def __iter__(self) -> Iterator[tuple[float, Any]]:
        return self._messages


def open_log(path: str | os.PathLike[str], wanted_ids: Iterable[int] | None) -> Any:
    """The reader for the log at ``path``: the tlog reader, :class:`LogReader`, or the raw
    reader; :class:`LogFormatError` naming why when the file is none of them."""
    kind = sniff(path)
    if kind == "tlog":
        from mav_observer.mavlink.tlog import TlogReader

        return TlogReader(path, wanted_ids)
    if kind == "raw":
        from mav_observer.logs.rawlink import RawLinkReader

        return RawLinkReader(path, wanted_ids)
    return LogReader(path, kind)
