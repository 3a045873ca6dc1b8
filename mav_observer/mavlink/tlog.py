"""Fast, damage-tolerant reading of ``.tlog`` files.

A tlog is a sequence of records: an 8-byte big-endian timestamp (microseconds since the Unix
epoch, the time the record was logged) followed by one raw MAVLink frame (1 or 2). This
reader splits records itself instead of going through pymavlink's stream parser:

* it looks at each frame's header only, counts every message by id, and decodes (with CRC
  check) only the ids it is asked for: most of a log is never decoded;
* it does not lose alignment after short MAVLink 1 frames or junk, which pymavlink's tlog
  reading does (``../shared/ENGINEERING_NOTES.md``);
* damage is counted, never fatal: a record whose timestamp is not plausible or whose frame
  does not start with a MAVLink magic byte makes the reader scan forward to the next
  plausible record (``resyncs``, ``skipped_bytes``); a frame cut by the end of the file is
  counted (``truncated_tail``); a failed decode is counted by reason; timestamps going
  backwards are counted (``time_backwards``) and passed on as they are.

A record is plausible when its timestamp lies between 2000 and 2100, within a week of the
previous good record, its frame starts with 0xFD or 0xFE and fits in the file; while
resynchronising, the record after it must be plausible too (or the file must end there).
"""

from __future__ import annotations

import mmap
import os
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from struct import Struct, unpack_from
from typing import Any

from mav_observer.mavlink.dialect import msg_name
from mav_observer.mavlink.fastdecode import DecodeError, FastDecoder

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
TS_MIN_US = 946_684_800_000_000  # 2000-01-01
TS_MAX_US = 4_102_444_800_000_000  # 2100-01-01
TS_JUMP_MAX_US = 7 * 86400 * 1_000_000


@dataclass
class TlogStats:
    """What a read found. ``by_id`` counts every frame seen, decoded or not."""

    records: int = 0
    bytes_total: int = 0
    resyncs: int = 0
    skipped_bytes: int = 0
    truncated_tail: bool = False
    time_backwards: int = 0
    first_t_unix_s: float | None = None
    last_t_unix_s: float | None = None
    by_id: Counter[int] = field(default_factory=Counter)
    decode_errors: Counter[str] = field(default_factory=Counter)

    def by_name(self) -> dict[str, int]:
        """Frames per message name, most frequent first."""
        return {msg_name(i): c for i, c in self.by_id.most_common()}

    def damage(self) -> dict[str, int]:
        """The damage found, by kind (empty when the file is clean)."""
        out = {
            "resyncs": self.resyncs,
            "skipped_bytes": self.skipped_bytes,
            "truncated_tail": int(self.truncated_tail),
            "time_backwards": self.time_backwards,
        }
        out.update({f"decode_{k}": v for k, v in self.decode_errors.items()})
        return {k: v for k, v in out.items() if v}


def _frame_at(buf: Any, i: int, n: int) -> tuple[int, int, int] | None:
    """``(timestamp_us, msgid, frame_length)`` of a record starting at ``i``, or ``None`` if
    its header is not a MAVLink frame header (the frame may still run past the end)."""
    if i + 9 > n:
        return None
    magic = buf[i + 8]
    if magic == MAGIC_V2:
        if i + 18 > n:
            return None
        flen = 12 + buf[i + 9] + (13 if buf[i + 10] & 1 else 0)
        msgid = buf[i + 15] | (buf[i + 16] << 8) | (buf[i + 17] << 16)
    elif magic == MAGIC_V1:
        if i + 14 > n:
            return None
        flen = 8 + buf[i + 9]
        msgid = buf[i + 13]
    else:
        return None
    return unpack_from(">Q", buf, i)[0], msgid, flen


class TlogReader:
    """Iterate over ``(t_unix_s, message)`` for the wanted message ids of a tlog.

    ``wanted_ids=None`` decodes everything. Statistics accumulate in :attr:`stats` as the
    iteration proceeds (complete once it is exhausted).
    """

    def __init__(self, path: str | os.PathLike[str], wanted_ids: Iterable[int] | None = None):
        self.path = Path(path)
        self.wanted = None if wanted_ids is None else frozenset(wanted_ids)
        self.stats = TlogStats()
        #: bytes consumed so far (for progress reporting)
        self.position = 0

    def drop(self, msgids: Iterable[int]) -> None:
        """Stop decoding these ids from now on (they are still counted)."""
        if self.wanted is not None:
            self.wanted = self.wanted - frozenset(msgids)

    def _plausible(self, ts: int, last_ts: int | None) -> bool:
        if not TS_MIN_US <= ts <= TS_MAX_US:
            return False
        return last_ts is None or abs(ts - last_ts) <= TS_JUMP_MAX_US

    def _resync(self, buf: Any, start: int, n: int, last_ts: int | None) -> int:
        """Position of the next plausible record at or after ``start``, or ``n``."""
        pos = start
        while True:
            c2 = buf.find(b"\xfd", pos + 8)
            c1 = buf.find(b"\xfe", pos + 8)
            cands = [c for c in (c1, c2) if c >= 0]
            if not cands:
                return n
            m = min(cands)
            i = m - 8
            hdr = _frame_at(buf, i, n)
            if hdr is not None and self._plausible(hdr[0], last_ts):
                end = i + 8 + hdr[2]
                if end == n:
                    return i
                if end < n:
                    nxt = _frame_at(buf, end, n)
                    if nxt is not None and self._plausible(nxt[0], hdr[0]):
                        return i
            pos = m - 7  # next candidate after this magic byte

    def _cut_record(self, buf: Any, i: int, n: int, last_ts: int | None) -> bool:
        """True if the bytes from ``i`` to the end are the start of a plausible record that
        the end of the file cut short."""
        if i + 8 > n:
            return True
        if not self._plausible(unpack_from(">Q", buf, i)[0], last_ts):
            return False
        if i + 8 == n:
            return True
        if buf[i + 8] not in (MAGIC_V1, MAGIC_V2):
            return False
        hdr = _frame_at(buf, i, n)
        return hdr is None or i + 8 + hdr[2] > n

    def __iter__(self) -> Iterator[tuple[float, Any]]:
        st = self.stats
        size = self.path.stat().st_size
        st.bytes_total = size
        if size == 0:
            return
        with open(self.path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            yield from self._records(buf, size)

    def _records(self, buf: Any, n: int) -> Iterator[tuple[float, Any]]:
        st = self.stats
        by_id = st.by_id
        decoder = FastDecoder(self.wanted)
        decode = decoder.decode
        unpack_ts = Struct(">Q").unpack_from
        last_ts: int | None = None
        i = 0
        records = time_back = 0
        try:
            while i < n:
                # header of the record at i, inlined from _frame_at (this loop is the hot path)
                ok = False
                if i + 18 <= n:
                    magic = buf[i + 8]
                    if magic == MAGIC_V2:
                        flen = 12 + buf[i + 9] + (13 if buf[i + 10] & 1 else 0)
                        msgid = buf[i + 15] | (buf[i + 16] << 8) | (buf[i + 17] << 16)
                        ok = True
                    elif magic == MAGIC_V1:
                        flen = 8 + buf[i + 9]
                        msgid = buf[i + 13]
                        ok = True
                if ok:
                    ts = unpack_ts(buf, i)[0]
                    ok = TS_MIN_US <= ts <= TS_MAX_US and (
                        last_ts is None or -TS_JUMP_MAX_US <= ts - last_ts <= TS_JUMP_MAX_US
                    )
                if not ok:
                    hdr = _frame_at(buf, i, n)  # short final record, or damage
                    if hdr is not None and self._plausible(hdr[0], last_ts) and i + 8 + hdr[2] <= n:
                        ts, msgid, flen = hdr
                    else:
                        if self._cut_record(buf, i, n, last_ts):
                            st.truncated_tail = True
                            st.skipped_bytes += n - i
                            break
                        j = self._resync(buf, i, n, last_ts)
                        st.resyncs += 1
                        st.skipped_bytes += j - i
                        i = j
                        continue
                end = i + 8 + flen
                if end > n:
                    st.truncated_tail = True
                    st.skipped_bytes += n - i
                    break
                records += 1
                by_id[msgid] += 1
                if last_ts is None:
                    st.first_t_unix_s = ts * 1e-6
                elif ts < last_ts:
                    time_back += 1
                last_ts = ts
                wanted = self.wanted
                if wanted is None or msgid in wanted:
                    try:
                        msg = decode(buf[i + 8 : end])
                    except DecodeError as exc:
                        st.decode_errors[exc.reason] += 1
                    else:
                        self.position = end
                        yield ts * 1e-6, msg
                i = end
        finally:
            st.records += records
            st.time_backwards += time_back
            self.position = max(self.position, i)
            if last_ts is not None:
                st.last_t_unix_s = last_ts * 1e-6
