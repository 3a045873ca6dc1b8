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
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from struct import unpack_from
from typing import Any

import numpy as np

from mav_observer.mavlink.dialect import msg_name
from mav_observer.mavlink.fastdecode import DecodeError, FastDecoder

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
TS_MIN_US = 946_684_800_000_000  # 2000-01-01
TS_MAX_US = 4_102_444_800_000_000  # 2100-01-01
TS_JUMP_MAX_US = 7 * 86400 * 1_000_000


def mapped(
    path: Path, stats: Any, scan: Callable[[Any, int], Iterator[tuple[float, Any]]]
) -> Iterator[tuple[float, Any]]:
    """``scan(buffer, size)`` over the file mapped read-only (nothing for an empty file), the
    file's size in ``stats.bytes_total``: the readers of MAVLink byte streams
    (:class:`TlogReader`, :class:`~mav_observer.logs.rawlink.RawLinkReader`)."""
    size = path.stat().st_size
    stats.bytes_total = size
    if size == 0:
        return
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        yield from scan(buf, size)


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
        return mapped(self.path, self.stats, self._records)

    def _records(self, buf: Any, n: int) -> Iterator[tuple[float, Any]]:
        st = self.stats
        by_id = st.by_id
        decoder = FastDecoder(self.wanted)
        decode = decoder.decode_at
        scan = _Scan(buf, n)
        last_ts: int | None = None
        i = 0
        records = time_back = 0
        try:
            while i < n:
                clean = scan.clean_from(i, last_ts)
                if clean is not None:
                    # a run of records whose headers and timestamps are sound: counted by
                    # their headers at once, only the wanted ones decoded, one by one
                    pos, ends, stamps, ids = clean
                    records += len(pos)
                    for msgid, count in _first_seen_counts(ids):
                        by_id[msgid] += count
                    if last_ts is None:
                        st.first_t_unix_s = int(stamps[0]) * 1e-6
                    elif stamps[0] < last_ts:
                        time_back += 1
                    time_back += int(np.count_nonzero(stamps[1:] < stamps[:-1]))
                    last_ts = int(stamps[-1])
                    i = int(ends[-1])
                    wanted = self.wanted
                    if wanted is not None:
                        sel = np.flatnonzero(np.isin(ids, np.fromiter(wanted, np.int64)))
                        pos, ends, stamps, ids = pos[sel], ends[sel], stamps[sel], ids[sel]
                    for start, end, ts, msgid in zip(
                        pos.tolist(), ends.tolist(), stamps.tolist(), ids.tolist(), strict=True
                    ):
                        wanted = self.wanted  # (:meth:`drop` may have been called meanwhile)
                        if wanted is not None and msgid not in wanted:
                            continue
                        try:
                            msg = decode(buf, start + 8, end, msgid)
                        except DecodeError as exc:
                            st.decode_errors[exc.reason] += 1
                        else:
                            self.position = end
                            yield ts * 1e-6, msg
                    continue
                # one record the fast path does not take: the end of the file, or damage
                hdr = _frame_at(buf, i, n)
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
                        msg = decode(buf, i + 8, end, msgid)
                    except DecodeError as exc:
                        st.decode_errors[exc.reason] += 1
                    else:
                        self.position = end
                        yield ts * 1e-6, msg
                i = end
        finally:
            scan.close()
            st.records += records
            st.time_backwards += time_back
            self.position = max(self.position, i)
            if last_ts is not None:
                st.last_t_unix_s = last_ts * 1e-6


def _first_seen_counts(ids: Any) -> list[tuple[int, int]]:
    """``(msgid, count)`` of the ids in ``ids``, in the order of their first occurrence (the
    order in which counting them one by one would have met them)."""
    uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
    order = np.argsort(first, kind="stable")
    return list(zip(uniq[order].tolist(), counts[order].tolist(), strict=True))


#: Bytes of the file whose candidate record starts :class:`_Scan` finds at once.
SCAN_WINDOW = 1 << 22


class _Scan:
    """The reader's fast path: runs of sound records found with numpy, a window of the file at
    a time.

    A candidate is a position whose byte 8 is a MAVLink magic byte and whose header lies in
    the file; each is linked to the candidate right after its frame when that one's timestamp
    is within the plausible range and within a week of its own. From a sound record, the
    links give the records that the byte-by-byte reading of :meth:`TlogReader._records` would
    accept as they are, up to the first one it would look at more closely (damage, the end of
    the file, or the end of the window), which is left to it.
    """

    def __init__(self, buf: Any, n: int) -> None:
        self.buf: Any = np.frombuffer(buf, dtype=np.uint8) if n else None
        self.n = n
        self.lo = self.hi = 0  # the window: candidates at positions in [lo, hi)
        self.pos: Any = None
        self.links: list[int] = []

    def close(self) -> None:
        """Let go of the file's memory (the map cannot close while a view of it exists)."""
        self.buf = None

    def _window(self, lo: int) -> None:
        a, n = self.buf, self.n
        hi = min(n - 17, lo + SCAN_WINDOW)  # a candidate's header ends within the file
        self.lo, self.hi = lo, max(hi, lo)
        pos = np.flatnonzero(np.subtract(a[lo + 8 : hi + 8], MAGIC_V2, dtype=np.uint8) < 2)
        pos += lo
        v2 = a[pos + 8] == MAGIC_V2
        plen = a[pos + 9].astype(np.int64)
        flen = np.where(v2, 12 + plen + 13 * (a[pos + 10] & 1), 8 + plen)
        ids = np.where(
            v2,
            a[pos + 15]
            | (a[pos + 16].astype(np.int64) << 8)
            | (a[pos + 17].astype(np.int64) << 16),
            a[pos + 13],
        ).astype(np.int64)
        stamps = a[pos[:, None] + np.arange(8)].view(">u8").ravel()
        sane = (stamps >= TS_MIN_US) & (stamps <= TS_MAX_US)
        stamps = np.where(sane, stamps, 0).astype(np.int64)
        nxt = pos + 8 + flen
        k = np.searchsorted(pos, nxt)
        kk = np.minimum(k, len(pos) - 1)
        ok = (k < len(pos)) & (pos[kk] == nxt)
        ok &= sane[kk] & (np.abs(stamps[kk] - stamps) <= TS_JUMP_MAX_US)
        self.pos, self.ends, self.stamps, self.ids, self.sane = pos, nxt, stamps, ids, sane
        self.links = np.where(ok, k, -1).tolist()

    def clean_from(self, i: int, last_ts: int | None) -> tuple[Any, Any, Any, Any] | None:
        """``(starts, ends, timestamps, ids)`` (arrays) of the sound records from ``i`` on,
        ``None`` if the record at ``i`` is not one (or ``i`` is too close to the end)."""
        if self.buf is None:
            return None
        if not self.lo <= i < self.hi:
            if i >= self.n - 17:
                return None
            self._window(i)
        pos = self.pos
        j = int(np.searchsorted(pos, i))
        if j >= len(pos) or pos[j] != i or not self.sane[j]:
            return None
        ts = int(self.stamps[j])
        if last_ts is not None and abs(ts - last_ts) > TS_JUMP_MAX_US:
            return None
        links = self.links
        path = []
        append = path.append
        while j >= 0:
            append(j)
            j = links[j]
        if self.ends[path[-1]] > self.n:  # a frame cut by the end of the file
            path.pop()
            if not path:
                return None
        sel = np.array(path, dtype=np.int64)
        return pos[sel], self.ends[sel], self.stamps[sel], self.ids[sel]
