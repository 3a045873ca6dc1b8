"""The tracker's observers saved across a restart, and resumed when their vehicle returns."""

from __future__ import annotations

import logging
from typing import Any

from mav_observer.core.targets import VehicleFix, check_saved
from mav_observer.tracking.vehicle import Vehicle, gimbal_device

log = logging.getLogger("mav_observer.tracking.tracker")


class SavedObservers:
    """Export and restore; mixed into :class:`~mav_observer.tracking.tracker.Tracker`."""

    def export_state(self) -> list[dict[str, Any]]:
        """Every started observer with what :meth:`restore` needs to carry it across a gap:
        its vehicle's latest position and velocity (LOCAL_POSITION_NED frame, autopilot clock)
        and the whole observer (:meth:`Targets.export`). JSON-serialisable."""
        out: list[dict[str, Any]] = []
        for sysid, veh in self.vehicles.items():
            if veh.position is not None:
                for e in veh.targets.export(sysid, VehicleFix(*veh.position)):
                    dev = gimbal_device(e["target"])
                    det = None if dev is None else veh.gimbal_frames.get(dev)
                    if det is not None and det.decided is not None:
                        e["gimbal_angles"] = det.decided  # what the data showed, kept too
                    out.append(e)
        # observers restored but whose vehicle has not come back yet are kept as they were
        for entries in self._pending.values():
            out.extend(entries)
        return out

    def restore(self, entries: list[dict[str, Any]]) -> None:
        """Take observers saved by :meth:`export_state`. Each waits for its vehicle's first
        LOCAL_POSITION_NED, then resumes (:meth:`Targets.resume`) moved by minus the
        vehicle's displacement since it was saved: the target is assumed to have stayed where
        it was in the local frame (a moving target resumes off by its own displacement, which
        the observer then corrects). It is discarded, with a warning, if the autopilot's
        clock went back (a reboot: the local frame may have moved) or more than
        ``config.restore_max_gap_s`` of vehicle time passed. Raises :class:`StateError` naming
        the bad entry (:func:`check_saved`); nothing is taken then."""
        for sysid, es in check_saved(entries).items():
            self._pending.setdefault(sysid, []).extend(es)
            for e in es:
                dev = gimbal_device(e["target"])
                if dev is not None and e.get("gimbal_angles") is not None:
                    self._saved_angles[(sysid, dev)] = e["gimbal_angles"]

    def _resume_saved(self, veh: Vehicle, entries: list[dict[str, Any]]) -> None:
        """Carry saved observers to the vehicle's current position (see :meth:`restore`)."""
        fix = VehicleFix(*veh.position)  # type: ignore[misc]
        for r in veh.targets.resume(entries, fix, self.config.restore_max_gap_s):
            who = (veh.sysid, r.target)
            if r.restored:
                self._note(veh, "restored")
                obs = veh.targets.get(r.target)
                log.info(
                    "vehicle %d: restored observer %r (%s), %.1f s of vehicle time after it "
                    "was saved, vehicle moved %.1f m since",
                    veh.sysid,
                    r.target,
                    "?" if obs is None else str(obs.status),
                    r.gap_s,
                    r.moved_m,
                )
            elif r.outcome == "superseded":
                log.info("vehicle %d: saved observer %r: a live one has its place", *who)
            else:
                why = "clock went back" if r.outcome == "clock_back" else f"{r.gap_s:.0f} s old"
                log.warning("vehicle %d: saved observer %r discarded (%s)", *who, why)
                self._note(veh, "restore_discarded")

