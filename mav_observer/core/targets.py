"""The observers of one vehicle, one per target, and how they are saved and resumed.

A role of its own beside the tracker (:mod:`mav_observer.tracking.tracker`, which turns
messages into samples per vehicle): :class:`Targets` creates a target's observer on its first
bearing, feeds every observer the vehicle's velocity, and exports and resumes them across a
restart of the service (:func:`check_saved`, :meth:`Targets.export`, :meth:`Targets.resume`).

Pure: numpy-free even, no I/O, no MAVLink. Frames: NED; ``v`` is the paper's ``v = -u``
(minus the vehicle's measured velocity, m/s); positions are the LOCAL_POSITION_NED frame's, m;
times on the vehicle's autopilot clock, s.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from mav_observer.core.observer import BiasObserver, ObserverConfig
from mav_observer.core.samples import Estimate
from mav_observer.errors import InvalidSampleError, StateError


@dataclass(frozen=True)
class VehicleFix:
    """Where the vehicle was: ``t_boot_s`` (autopilot clock, s), ``pos_ned_m`` and
    ``vel_ned_mps`` (its measured velocity ``u``, NED)."""

    t_boot_s: float
    pos_ned_m: tuple[float, float, float]
    vel_ned_mps: tuple[float, float, float]


@dataclass(frozen=True)
class Resumed:
    """What became of one saved observer: ``outcome`` is ``restored``, or why it was not:
    ``clock_back`` (the autopilot's clock went back: a reboot, the local frame may have
    moved), ``too_old`` (more than the allowed gap), ``superseded`` (a live observer of the
    target exists). ``gap_s``: vehicle time since it was committed; ``moved_m``: how far the
    vehicle moved since."""

    target: str
    outcome: str
    gap_s: float
    moved_m: float = 0.0

    @property
    def restored(self) -> bool:
        return self.outcome == "restored"


class Targets:
    """The observers of one vehicle by target name, each with the message it reads."""

    def __init__(self, config: ObserverConfig, *, committed: bool = False) -> None:
        """``committed``: the observers publish the estimate at each bearing once committed
        through it (:meth:`take_committed`), not a live one at its arrival
        (``BiasObserver(committed=True)``)."""
        self.config = config
        self.committed = committed
        self._obs: dict[str, tuple[BiasObserver, str]] = {}

    def __len__(self) -> int:
        return len(self._obs)

    def __contains__(self, target: object) -> bool:
        return target in self._obs

    def __iter__(self) -> Iterator[str]:
        return iter(self._obs)

    def get(self, target: str) -> BiasObserver | None:
        """The observer of ``target``, ``None`` if there is none."""
        entry = self._obs.get(target)
        return None if entry is None else entry[0]

    def sources(self) -> dict[str, str]:
        """``target -> source message`` of every observer."""
        return {name: src for name, (_, src) in self._obs.items()}

    def velocity(
        self, t_s: float, v_mps: Sequence[float], interval_mean_mps: Sequence[float] | None
    ) -> list[InvalidSampleError]:
        """Give every observer the velocity ``v`` (the paper's, ``-u``) at ``t_s``, with the
        mean over the interval since the previous one when known; returns the refusals."""
        refused = []
        for obs, _ in self._obs.values():
            try:
                obs.update_velocity_values(t_s, v_mps, interval_mean_mps)
            except InvalidSampleError as exc:
                refused.append(exc)
        return refused

    def bearing(
        self,
        target: str,
        source: str,
        t_s: float,
        y: Sequence[float],
        latest_velocity: tuple[float, Sequence[float]] | None,
        range_m: float | None = None,
        range_std_m: float = 1.0,
    ) -> tuple[Estimate | None, bool]:
        """Give ``target``'s observer the unit bearing ``y`` (NED) at ``t_s``, creating it
        (started from ``latest_velocity``, ``(t_s, v)``) on its first bearing. Returns the
        estimate (``None`` while the observer has no velocity yet, and always with
        ``committed``: see :meth:`take_committed`) and whether the observer is new; raises
        :class:`InvalidSampleError` when the observer refuses the bearing. ``range_m``: the
        distance measured with the bearing (m, standard deviation ``range_std_m``)."""
        entry = self._obs.get(target)
        new = entry is None
        if entry is None:
            obs = BiasObserver(self.config, committed=self.committed)
            if latest_velocity is not None:
                obs.update_velocity_values(*latest_velocity)
            self._obs[target] = entry = (obs, source)
        if self.committed:
            entry[0].add_bearing_values(t_s, y, range_m, range_std_m)
            return None, new
        est = entry[0].update_bearing_values(t_s, y, range_m, range_std_m)
        return (est if entry[0].started else None), new

    def take_committed(self, *, end: bool = False) -> list[tuple[str, str, Estimate]]:
        """``(target, source, estimate)`` of every estimate committed since the previous call
        (``committed``), each target's in time order; ``end``: the data have ended, the
        bearings after the latest velocity are committed too (``commit_pending``)."""
        out = []
        for target, (obs, source) in self._obs.items():
            ests = obs.commit_pending() if end else obs.take_committed()
            out.extend((target, source, e) for e in ests)
        return out

    def restart(self, target: str) -> bool:
        """Forget ``target``'s observer (its bearings were read wrongly): the next bearing
        starts a new one. Returns whether there was one."""
        return self._obs.pop(target, None) is not None

    # -- persistence ------------------------------------------------------------------
    def export(self, sysid: int, fix: VehicleFix) -> list[dict[str, Any]]:
        """Every started observer with what :meth:`resume` needs: the vehicle's fix and the
        whole observer (:meth:`BiasObserver.to_dict`). JSON-serialisable."""
        return [
            {
                "sysid": sysid,
                "target": target,
                "source": source,
                "vehicle": {
                    "t_boot_s": fix.t_boot_s,
                    "pos_ned_m": list(fix.pos_ned_m),
                    "vel_ned_mps": list(fix.vel_ned_mps),
                },
                "observer": obs.to_dict(),
            }
            for target, (obs, source) in self._obs.items()
            if obs.started
        ]

    def resume(
        self, entries: Sequence[dict[str, Any]], fix: VehicleFix, max_gap_s: float
    ) -> list[Resumed]:
        """Take saved observers (checked by :func:`check_saved`) at the vehicle's ``fix``,
        each moved by minus the vehicle's displacement since its committed time: the target is
        assumed to have stayed where it was in the local frame. One is discarded if the
        autopilot's clock went back (a reboot) or more than ``max_gap_s`` passed, or if a live
        observer already took its place."""
        out = []
        for e in entries:
            obs = BiasObserver.from_dict(e["observer"], committed=self.committed)
            saved = e["vehicle"]
            t_c = float(obs.committed_t_s)  # type: ignore[arg-type]
            gap = fix.t_boot_s - t_c
            if gap < 0.0 or gap > max_gap_s:
                out.append(Resumed(e["target"], "clock_back" if gap < 0.0 else "too_old", gap))
                continue
            if e["target"] in self._obs:
                out.append(Resumed(e["target"], "superseded", gap))
                continue
            # the vehicle's position at the committed time, from the saved one: it moves at
            # its measured velocity less its error, u - ahat (x' = v + a = -(u - a))
            dt = t_c - float(saved["t_boot_s"])
            a = obs.a_mps
            p_c = [saved["pos_ned_m"][j] + dt * (saved["vel_ned_mps"][j] - a[j]) for j in range(3)]
            dx = [p_c[j] - fix.pos_ned_m[j] for j in range(3)]  # x = target - vehicle
            u = fix.vel_ned_mps
            obs.resume(fix.t_boot_s, dx, [-u[0], -u[1], -u[2]])
            self._obs[e["target"]] = (obs, e["source"])
            out.append(Resumed(e["target"], "restored", gap, math.sqrt(sum(c * c for c in dx))))
        return out


def check_saved(entries: Sequence[Any]) -> dict[int, list[dict[str, Any]]]:
    """Saved observers (as :meth:`Targets.export` wrote them) by sysid, every field checked;
    raises :class:`StateError` naming the bad entry (``observers[i].field``)."""
    checked: dict[int, list[dict[str, Any]]] = {}
    for i, e in enumerate(entries):
        where = f"observers[{i}]"
        if not isinstance(e, dict):
            raise StateError(f"{where} must be a table, got {type(e).__name__}")
        sysid, target, source = e.get("sysid"), e.get("target"), e.get("source")
        if not isinstance(sysid, int) or isinstance(sysid, bool) or not 0 < sysid < 256:
            raise StateError(f"{where}.sysid must be an integer in 1..255, got {sysid!r}")
        if not isinstance(target, str) or not target:
            raise StateError(f"{where}.target must be a non-empty string, got {target!r}")
        if not isinstance(source, str):
            raise StateError(f"{where}.source must be a string, got {source!r}")
        angles = e.get("gimbal_angles")
        if angles is not None and angles not in ("flags", "body"):
            raise StateError(f"{where}.gimbal_angles must be 'flags' or 'body', got {angles!r}")
        veh = e.get("vehicle")
        try:
            tp = float(veh["t_boot_s"])  # type: ignore[index]
            pos = [float(c) for c in veh["pos_ned_m"]]  # type: ignore[index]
            vel = [float(c) for c in veh["vel_ned_mps"]]  # type: ignore[index]
        except (KeyError, TypeError, ValueError) as exc:
            raise StateError(f"{where}.vehicle is malformed: {exc!r}") from exc
        if len(pos) != 3 or len(vel) != 3 or not all(map(math.isfinite, (tp, *pos, *vel))):
            raise StateError(f"{where}.vehicle must hold finite 3-vectors and a time")
        try:
            obs = BiasObserver.from_dict(e.get("observer"))  # type: ignore[arg-type]
        except StateError as exc:
            raise StateError(f"{where}.observer: {exc}") from exc
        if obs.config.n != 3 or not obs.started:
            raise StateError(f"{where}.observer must be a started observer with n = 3")
        checked.setdefault(sysid, []).append(e)
    return checked


__all__ = ["Resumed", "Targets", "VehicleFix", "check_saved"]
