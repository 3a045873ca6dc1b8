"""Raw MAVLink captures without tlog stamps: Mission Planner's ``.rlog``, MAVProxy's
``.tlog.raw``; the bytes of the link as they came, frames and anything else.

Frames are found by their magic byte and kept when their CRC checks (with the message's
extra byte); anything else is skipped and counted (``skipped_bytes``, ``resyncs``). There is
no arrival time, so the autopilot's own clock is the time axis: a message's arrival is the
latest ``time_boot_ms`` seen, kept increasing across a reboot (the clock going back by more
than :data:`REBOOT_BACK_S`), so that the tracker sees the reboot as on a live link.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mav_observer.logs.formats import LogStats
from mav_observer.mavlink import dialect
from mav_observer.mavlink.fastdecode import DecodeError, FastDecoder
from mav_observer.mavlink.tlog import mapped

try:
    from fastcrc.crc16 import mcrf4xx as _crc16
except ImportError:  # pragma: no cover - pymavlink depends on fastcrc
    _crc16 = None

MAGIC_V1, MAGIC_V2 = 0xFE, 0xFD
#: The autopilot's clock going back by more than this (s) is a reboot.
REBOOT_BACK_S = 2.0


class RawLinkReader:
    """Iterate over ``(t_s, message)`` for the wanted message ids of a raw capture; ``t_s`` on
    the autopilot's clock as the module says."""

    def __init__(self, path: str | os.PathLike[str], wanted_ids: Iterable[int] | None) -> None:
        self.path = Path(path)
        self.wanted = None if wanted_ids is None else frozenset(wanted_ids)
        self.stats = LogStats(format="raw MAVLink")
        self.position = 0
        self._extra: dict[int, bytes | None] = {}

    def drop(self, msgids: Iterable[int]) -> None:
        if self.wanted is not None:
            self.wanted = self.wanted - frozenset(msgids)

    def _crc_extra(self, msgid: int) -> bytes | None:
        if msgid not in self._extra:
            w = dialect.wire(msgid)
            self._extra[msgid] = None if w is None else bytes([w[5]])
        return self._extra[msgid]

    def _frame(self, buf: Any, i: int, n: int) -> tuple[int, int] | None:
        """``(msgid, frame length)`` of a frame at ``i`` whose CRC checks, else ``None``."""
        if buf[i] == MAGIC_V2:
            if i + 12 > n:
                return None
            plen = buf[i + 1]
            flen = 12 + plen + (13 if buf[i + 2] & 1 else 0)
            msgid = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
            body = i + 10 + plen
        else:
            if i + 8 > n:
                return None
            plen = buf[i + 1]
            flen = 8 + plen
            msgid = buf[i + 5]
            body = i + 6 + plen
        if i + flen > n:
            return None
        extra = self._crc_extra(msgid)
        if extra is None or _crc16 is None:
            return None
        if _crc16(buf[i + 1 : body] + extra) != buf[body] | (buf[body + 1] << 8):
            return None
        return msgid, flen

    def __iter__(self) -> Iterator[tuple[float, Any]]:
        return mapped(self.path, self.stats, self._frames)

    def _frames(self, buf: Any, n: int) -> Iterator[tuple[float, Any]]:
        st = self.stats
        by_id: Counter[int] = Counter()
        decode = FastDecoder(self.wanted).decode_at
        i = 0
        base_s = 0.0
        latest_s: float | None = None
        in_sync = True
        try:
            while i < n:
                c = buf[i]
                got = self._frame(buf, i, n) if c in (MAGIC_V1, MAGIC_V2) else None
                if got is None:
                    if in_sync:
                        st.resyncs += 1
                        in_sync = False
                    j2, j1 = buf.find(b"\xfd", i + 1), buf.find(b"\xfe", i + 1)
                    cands = [j for j in (j1, j2) if j >= 0]
                    j = min(cands) if cands else n
                    st.skipped_bytes += j - i
                    i = j
                    continue
                in_sync = True
                msgid, flen = got
                by_id[msgid] += 1
                st.records += 1
                wanted = self.wanted
                if wanted is None or msgid in wanted:
                    try:
                        msg = decode(buf, i, i + flen, msgid)
                    except DecodeError as exc:
                        st.decode_errors[exc.reason] += 1
                    else:
                        tb = getattr(msg, "time_boot_ms", None)
                        if tb is not None:
                            tb_s = tb * 1e-3
                            if latest_s is not None and tb_s < latest_s - REBOOT_BACK_S:
                                base_s += latest_s - tb_s + 1.0
                                latest_s = tb_s
                            elif latest_s is None or tb_s > latest_s:
                                latest_s = tb_s
                        self.position = i + flen
                        yield base_s + (latest_s or 0.0), msg
                i += flen
        finally:
            for msgid, count in by_id.most_common():
                st.by_name[dialect.msg_name(msgid)] += count
