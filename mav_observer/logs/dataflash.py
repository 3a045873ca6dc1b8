"""ArduPilot DataFlash (``.bin``) logs, read with numpy from the log's own FMT records.

A DataFlash log is a sequence of records: ``0xA3 0x95``, a type byte, then a payload whose
layout the FMT record of that type gives (FMT is type 128, its own layout fixed: type, length,
a 4-character name, a 16-character format, 64 characters of column names). pymavlink's
DFReader decodes every record into a Python object; replay needs a few types out of the
hundreds a log holds, so this reader finds the records with numpy, walks them by their
lengths, and decodes only the types asked for, a column array at a time.

Damage is counted, never fatal: bytes that are not a record on the walk from the first one
(``skipped_bytes``, ``resyncs``: the walk resumes at the next record whose next record follows
it as its length says), a record cut by the end of the file (``truncated_tail``), FMT records
that contradict an earlier one (``fmt_conflicts``), records of a type without a format.
"""

from __future__ import annotations

import mmap
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mav_observer.logs.formats import LogStats

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 0x80
FMT_LENGTH = 89
_FMT_STRUCT = struct.Struct("<BB4s16s64s")

#: DataFlash format characters: numpy type, and the multiplier the value is stored with.
FORMAT_CHARS: dict[str, tuple[str, float | None]] = {
    "a": ("(32,)<i2", None), "b": ("i1", None), "B": ("u1", None), "h": ("<i2", None),
    "H": ("<u2", None), "i": ("<i4", None), "I": ("<u4", None), "f": ("<f4", None),
    "d": ("<f8", None), "n": ("S4", None), "N": ("S16", None), "Z": ("S64", None),
    "c": ("<i2", 0.01), "C": ("<u2", 0.01), "e": ("<i4", 0.01), "E": ("<u4", 0.01),
    "L": ("<i4", 1e-7), "M": ("u1", None), "q": ("<i8", None), "Q": ("<u8", None),
    "g": ("<f2", None),
}  # fmt: skip

#: Bytes of the file searched for record headers at once.
SCAN_WINDOW = 1 << 24


class DataFlashError(Exception):
    """A file that is not a DataFlash log at all (no format record anywhere)."""


@dataclass(frozen=True)
class Format:
    """One record type's layout, from its FMT record."""

    type: int
    name: str
    length: int  # the whole record, header included
    format: str
    columns: tuple[str, ...]

    def dtype(self) -> np.dtype[Any]:
        names, formats, offsets, off = [], [], [], 0
        for col, ch in zip(self.columns, self.format, strict=True):
            nt = np.dtype(FORMAT_CHARS[ch][0])
            names.append(col)
            formats.append(nt)
            offsets.append(off)
            off += nt.itemsize
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": off})


def _parse_fmt(a: np.ndarray[Any, Any], pos: int) -> Format | None:
    """The FMT record at ``pos``, or ``None`` if the bytes there are not a sound one."""
    if pos + FMT_LENGTH > len(a):
        return None
    typ, length, name, fmt, cols = _FMT_STRUCT.unpack(a[pos + 3 : pos + FMT_LENGTH].tobytes())
    try:
        name_s = name.rstrip(b"\0").decode("ascii")
        fmt_s = fmt.rstrip(b"\0").decode("ascii")
        cols_s = cols.rstrip(b"\0").decode("ascii")
    except UnicodeDecodeError:
        return None
    if not name_s.isalnum() or any(c not in FORMAT_CHARS for c in fmt_s):
        return None
    columns = tuple(cols_s.split(",")) if cols_s else ()
    if len(columns) != len(fmt_s) or len(set(columns)) != len(columns):
        return None
    size = 3 + sum(np.dtype(FORMAT_CHARS[c][0]).itemsize for c in fmt_s)
    if size != length:
        return None
    return Format(typ, name_s, length, fmt_s, columns)


class DataFlashLog:
    """The records of one DataFlash file: their positions and types, found at construction
    (:class:`DataFlashError` if the file has no sound FMT record); the columns of a type
    decoded on demand by :meth:`columns`."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.stats = LogStats(format="DataFlash")
        self.formats: dict[int, Format] = {}
        with open(self.path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            self.stats.bytes_total = size
            if size == 0:
                raise DataFlashError("the file is empty")
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                # a copy: the map closes here, and the columns are read from it later
                self._a = np.frombuffer(mm, dtype=np.uint8).copy()
        self._scan()

    # -- finding the records -------------------------------------------------------------
    def _candidates(self) -> np.ndarray[Any, Any]:
        a, n = self._a, len(self._a)
        parts = []
        for lo in range(0, max(n - 2, 0), SCAN_WINDOW):
            hi = min(n - 2, lo + SCAN_WINDOW)
            w = a[lo : hi + 1]
            parts.append(np.flatnonzero((w[:-1] == HEAD1) & (w[1:] == HEAD2)) + lo)
        return np.concatenate(parts) if parts else np.zeros(0, np.int64)

    def _scan(self) -> None:
        a, n, st = self._a, len(self._a), self.stats
        cand = self._candidates()
        types = a[cand + 2] if len(cand) else np.zeros(0, np.uint8)
        for p in cand[types == FMT_TYPE].tolist():
            f = _parse_fmt(a, p)
            if f is None:
                continue
            old = self.formats.get(f.type)
            if old is None:
                self.formats[f.type] = f
            elif old != f:
                st.count_damage("fmt_conflicts")
        if not self.formats:
            raise DataFlashError("no DataFlash format (FMT) record in it")
        lengths = np.zeros(256, np.int64)
        for t, f in self.formats.items():
            lengths[t] = f.length
        rec_len = lengths[types]
        known = rec_len > 0
        nxt = cand + np.maximum(rec_len, 1)
        succ = np.searchsorted(cand, nxt)
        in_file = succ < len(cand)
        exact = known & in_file
        exact[in_file] &= cand[succ[in_file]] == nxt[in_file]
        # a record to resume at: its successor is where its length says
        good = np.flatnonzero(known & exact)
        fits = nxt <= n
        walked = self._walk(cand, rec_len, succ, exact, good, fits)
        sel = np.array(walked, dtype=np.int64)
        self.pos = cand[sel]
        self.types = types[sel]
        st.records = len(sel)
        counts = np.bincount(self.types, minlength=256)
        for t in np.flatnonzero(counts).tolist():
            f = self.formats.get(t)
            st.by_name[f.name if f else f"type{t}"] += int(counts[t])

    def _walk(
        self,
        cand: np.ndarray[Any, Any],
        rec_len: np.ndarray[Any, Any],
        succ: np.ndarray[Any, Any],
        exact: np.ndarray[Any, Any],
        good: np.ndarray[Any, Any],
        fits: np.ndarray[Any, Any],
    ) -> list[int]:
        """The candidates that are records: from the first sound one, each record's successor
        by its length; after damage, the next record whose successor is sound."""
        st, n = self.stats, len(self._a)
        out: list[int] = []
        if len(good) == 0:
            st.skipped_bytes = n
            return out
        cand_l, len_l, succ_l, exact_l, fits_l = (
            cand.tolist(),
            rec_len.tolist(),
            succ.tolist(),
            exact.tolist(),
            fits.tolist(),
        )
        good_l = good.tolist()
        i = good_l[0]
        st.skipped_bytes += cand_l[i]
        m = len(cand_l)
        append = out.append
        while True:
            length = len_l[i]
            if length == 0:  # a type without a format: junk, or a format lost
                st.count_damage("records_without_format")
                end = cand_l[i]
            elif not fits_l[i]:  # cut by the end of the file
                st.truncated_tail = True
                st.skipped_bytes += n - cand_l[i]
                return out
            else:
                append(i)
                if exact_l[i]:
                    i = succ_l[i]
                    continue
                end = cand_l[i] + length
            # damage, or the end: resume at the next sound record after ``end``
            s = succ_l[i]
            k = int(np.searchsorted(good, s)) if s < m else len(good_l)
            if k >= len(good_l):
                if end < n:
                    first = s if s < m else None  # the first header after ``end``
                    if first is not None and len_l[first] > 0 and not fits_l[first]:
                        st.truncated_tail = True
                    else:
                        st.resyncs += 1
                    st.skipped_bytes += n - end
                return out
            j = good_l[k]
            st.resyncs += 1
            st.skipped_bytes += cand_l[j] - end
            i = j

    # -- reading columns -----------------------------------------------------------------
    def format(self, name: str) -> Format | None:
        for f in self.formats.values():
            if f.name == name:
                return f
        return None

    def count(self, name: str) -> int:
        return self.stats.by_name.get(name, 0)

    def columns(self, name: str) -> dict[str, np.ndarray[Any, Any]] | None:
        """Every record of type ``name``, as one array per column (scaled values as float64
        for the format characters stored with a multiplier), ``None`` if the log has none."""
        f = self.format(name)
        if f is None:
            return None
        pos = self.pos[self.types == f.type]
        if len(pos) == 0:
            return None
        rows = self._a[pos[:, None] + np.arange(3, f.length)]
        rec = rows.view(f.dtype()).ravel()
        out: dict[str, np.ndarray[Any, Any]] = {}
        for col, ch in zip(f.columns, f.format, strict=True):
            mult = FORMAT_CHARS[ch][1]
            v = rec[col]
            out[col] = v * mult if mult is not None else v
        return out

    def time_us(self, cols: dict[str, np.ndarray[Any, Any]]) -> np.ndarray[Any, Any] | None:
        """A record's time since boot in microseconds: ``TimeUS``, or ``TimeMS`` on old logs."""
        if "TimeUS" in cols:
            return cols["TimeUS"].astype(np.int64)
        if "TimeMS" in cols:
            return cols["TimeMS"].astype(np.int64) * 1000
        return None
