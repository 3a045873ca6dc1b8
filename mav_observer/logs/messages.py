"""MAVLink messages made from a log's records, the same objects the tlog reader decodes.

A DataFlash or ULog record becomes the MAVLink message the autopilot would have sent for it
(an EKF position record a LOCAL_POSITION_NED, a mount record a MOUNT_ORIENTATION), so that one
tracker reads every format. The objects are the fast decoder's named tuples: the dialect's
fields in declared order, ``get_type()``, ``get_srcSystem()``, ``get_srcComponent()``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from functools import cache
from typing import Any

import numpy as np

from mav_observer.mavlink import dialect
from mav_observer.mavlink.fastdecode import message_class

#: The system and component ids given to a log's messages (a log holds one vehicle).
LOG_SYSID = 1
LOG_COMPID = 1


@cache
def maker(name: str) -> Callable[..., Any]:
    """A function of keyword fields that builds message ``name``; a field not given is 0 (an
    array field, zeros)."""
    wire = dialect.wire(dialect.MSG_ID[name])
    assert wire is not None
    _, fields, _, orders, lengths, _, _ = wire
    declared_lengths = [lengths[o] for o in orders]
    defaults = tuple([0.0] * n if n > 1 else 0 for n in declared_lengths)
    cls = message_class(name, list(fields))
    index = {f: i for i, f in enumerate(fields)}
    new = tuple.__new__

    def make(sysid: int = LOG_SYSID, compid: int = LOG_COMPID, **values: Any) -> Any:
        row = list(defaults)
        for key, value in values.items():
            row[index[key]] = value
        return new(cls, (*row, sysid, compid))

    return make


class Stream:
    """One message type of a log: its times (microseconds on the autopilot's boot clock),
    its rank among messages of the same time (lower first), and how record ``i`` becomes a
    message."""

    __slots__ = ("build", "rank", "t_us")

    def __init__(self, t_us: Any, rank: int, build: Callable[[int], Any]) -> None:
        self.t_us = t_us
        self.rank = rank
        self.build = build


def merged(streams: list[Stream]) -> Iterator[tuple[float, Any]]:
    """``(t_boot_s, message)`` of every stream, in time order (rank, then record order, at
    equal times); a record whose builder returns ``None`` is left out."""
    streams = [s for s in streams if len(s.t_us)]
    if not streams:
        return
    t = np.concatenate([np.asarray(s.t_us, dtype=np.int64) for s in streams])
    which = np.concatenate([np.full(len(s.t_us), k, np.int64) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s.t_us)) for s in streams])
    rank = np.array([s.rank for s in streams])[which]
    order = np.lexsort((index, rank, t))
    builds = [s.build for s in streams]
    for tt, k, i in zip(
        t[order].tolist(), which[order].tolist(), index[order].tolist(), strict=True
    ):
        msg = builds[k](i)
        if msg is not None:
            yield tt * 1e-6, msg
