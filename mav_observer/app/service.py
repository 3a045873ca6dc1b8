"""The service: MAVLink in, one observer per vehicle and target, estimates out over Zenoh.

:class:`Service` wires the parts together and owns nothing but bookkeeping:

* a :class:`~mav_observer.mavlink.connection.ConnectionReader` (the MAVLink link, reopened
  by itself when it fails);
* a :class:`~mav_observer.tracking.tracker.Tracker` (messages to samples to observers, one per
  vehicle and target, created when data first arrives);
* :class:`~mav_observer.outputs.zenoh_io.Publications` on one Zenoh session (estimates, a status per
  vehicle, liveliness, a queryable);
* optionally a state file (:mod:`mav_observer.app.statefile`), saved periodically and on stop.

One thread runs the loop: read a message (waiting at most ``poll_s``), hand it to the tracker,
publish what it produced; every ``tick_s`` do the housekeeping (stale vehicles, the 1 Hz
status, saving the state). :meth:`Service.stop` (from a signal handler or another thread) ends
the loop within ``poll_s``; :meth:`Service.run` then publishes a last status, saves the state
and closes everything. Nothing grows with running time: per vehicle and target a fixed set of
counters and the latest payloads.

Clocks are injected: ``clock`` (Unix seconds, stamps and ages in the published records) and
``monotonic`` (seconds, for periods and staleness).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mav_observer import __version__
from mav_observer.app import statefile
from mav_observer.app.settings import Settings
from mav_observer.core import compiled
from mav_observer.core.samples import WARN_LAG1, Correlation
from mav_observer.errors import MavObserverError
from mav_observer.mavlink import signing
from mav_observer.mavlink.connection import ConnectionReader
from mav_observer.mavlink.dialect import type_key
from mav_observer.outputs.mavlink_out import MavlinkOut, OutConfig
from mav_observer.outputs.records import STATUS_SCHEMA, EstimateRecord
from mav_observer.outputs.web import MapFeed
from mav_observer.outputs.zenoh_io import Publications
from mav_observer.tracking.tracker import Tracker

log = logging.getLogger(__name__)

STALE = "stale"
UP = "up"


@dataclass
class _Target:
    """What the service remembers about one observer (beyond the observer itself)."""

    source: str
    status: str = ""
    next_pub_mono: float = -1e300
    last_estimate_mono: float | None = None
    last_record: EstimateRecord | None = None
    estimates: int = 0
    published: int = 0
    #: the innovations were said to be systematic (re-armed once they are white again)
    systematic_said: bool = False


@dataclass
class _VehicleView:
    """The service's bookkeeping for one vehicle: link state, counts, targets."""

    sysid: int
    last_mono: float
    state: str = UP
    counts: Counter[str] = field(default_factory=Counter)
    counts_at_status: Counter[str] = field(default_factory=Counter)
    status_mono: float = 0.0
    targets: dict[str, _Target] = field(default_factory=dict)


class Service:
    """The estimator service (see the module docstring).

    ``reader`` and ``publications`` may be injected (tests); by default they are built from
    ``settings`` (:meth:`from_settings`).
    """

    def __init__(
        self,
        settings: Settings,
        reader: ConnectionReader,
        publications: Publications,
        *,
        clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
        poll_s: float = 0.05,
        tick_s: float = 0.1,
    ) -> None:
        self.settings = settings
        self.reader = reader
        self.pub = publications
        self.clock = clock
        self.monotonic = monotonic
        self.poll_s = poll_s
        self.tick_s = tick_s
        self.tracker = Tracker(settings.tracker_config())
        z = settings["zenoh"]
        #: rays are made while someone subscribes to them (``zenoh.rays``, docs/fleet.md)
        self._rays = bool(z["rays"])
        if self._rays:
            self.pub.watch_rays()
        rate = float(z["estimate_max_rate_hz"])
        self.min_interval_s = 0.0 if rate <= 0.0 else 1.0 / rate
        self.status_period_s = float(z["status_period_s"])
        self.stale_after_s = float(settings["mavlink"]["stale_after_s"])
        self.max_bearing_age_s = float(settings["observer"]["max_bearing_age_s"])
        sf = settings["state"]["file"]
        self.state_file: Path | None = None if sf is None else Path(sf)
        self.save_period_s = float(settings["state"]["save_period_s"])
        self.vehicles: dict[int, _VehicleView] = {}
        #: the live map's feed (``run --web``), given each estimate published
        self.web: MapFeed | None = None
        self.messages = 0
        self.state_errors = 0
        self._stop = threading.Event()
        self._shut = False
        self._start_mono = monotonic()
        self._next_tick = 0.0
        self._next_save = self._start_mono + self.save_period_s
        self._link_state = "waiting"
        self._last_any_mono: float | None = None
        m = settings["mavlink"]
        #: the estimates sent back over MAVLink (``[mavlink] out``), if on
        self.mavlink_out: MavlinkOut | None = None
        self._out_link: ConnectionReader | None = None
        if m["out"]:
            cfg = OutConfig(True, m["out_url"], tuple(m["out_targets"]), float(m["out_rate_hz"]),
                            bool(m["out_statustext"]), m["out_frame"])  # fmt: skip
            send = self.reader.send
            if cfg.url is not None:
                key_file = m["signing_key_file"]
                self._out_link = ConnectionReader(
                    cfg.url,
                    heartbeat_period_s=None,
                    signing_key=None if key_file is None else signing.load_key(key_file),
                    signing_link_id=m["signing_link_id"],
                )
                send = self._out_link.send
            self.mavlink_out = MavlinkOut(cfg, send)

    # -- construction -----------------------------------------------------------------
    @classmethod
    def from_settings(cls, settings: Settings, session: Any) -> Service:
        """A service reading ``settings['mavlink']['url']`` and publishing on ``session``."""
        m = settings["mavlink"]
        z = settings["zenoh"]
        key_file = m["signing_key_file"]
        reader = ConnectionReader(
            m["url"],
            heartbeat_period_s=m["heartbeat_period_s"],
            signing_key=None if key_file is None else signing.load_key(key_file),
            signing_link_id=m["signing_link_id"],
        )
        pubs = Publications(session, z["prefix"], congestion_control=z["congestion_control"])
        return cls(settings, reader, pubs)

    # -- control ------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask the loop to end (safe from a signal handler or another thread)."""
        self._stop.set()

    def run(self, *, duration_s: float | None = None) -> None:
        """Run until :meth:`stop` (or for ``duration_s``), then shut down cleanly."""
        # the estimator loaded (compiled on a machine's first run) before any sample waits
        compiled.kernels()
        self.restore_state()
        end = None if duration_s is None else self.monotonic() + duration_s
        log.info(
            "reading MAVLink from %s, publishing under %s/", self.reader.source, self.pub.prefix
        )
        try:
            while not self._stop.is_set():
                item = self.reader.recv(self.poll_s)
                now = self.monotonic()
                if item is not None:
                    self.handle(item[0], item[1], now)
                if now >= self._next_tick:
                    self.housekeeping(now)
                    if end is not None and now >= end:
                        break
        finally:
            self.shutdown()

    def shutdown(self) -> None:
        """Give the bearings still waiting for their attitude to their observers (as replay
        does at the end of a log), publish a last status for every vehicle, save the state,
        close the link and the publications (the liveliness tokens go). Idempotent."""
        if self._shut:
            return
        self._shut = True
        now = self.monotonic()
        for rec in self.tracker.flush():
            view = self.vehicles.get(rec.sysid)
            if view is not None:
                self._on_estimate(view, rec, now)
        for view in self.vehicles.values():
            self._publish_status(view, now, final=True)
        self.save_state()
        self.reader.close()
        if self._out_link is not None:
            self._out_link.close()
        self.pub.close()
        log.info("stopped after %d messages", self.messages)

    # -- the data path ------------------------------------------------------------------
    def handle(self, t_unix_s: float, msg: Any, now: float) -> None:
        """One MAVLink message: count it, give it to the tracker, publish its estimates."""
        self.messages += 1
        if self._link_state != UP:
            log.info(
                "MAVLink link %s: data%s",
                self.reader.source,
                ""
                if self._last_any_mono is None
                else f" again after {now - self._last_any_mono:.1f} s",
            )
            self._link_state = UP
        self._last_any_mono = now
        want_rays = self._rays and self.pub.rays_listened
        if want_rays != (self.tracker.rays is not None):
            self.tracker.rays = [] if want_rays else None
        records = self.tracker.handle(t_unix_s, msg)
        sysid = msg.get_srcSystem()
        view = self.vehicles.get(sysid)
        if view is None:
            if not self.tracker.is_vehicle(sysid):
                return  # not (yet) a vehicle: a ground station, a stray component
            view = self._new_vehicle(sysid, now)
        view.counts[type_key(msg)] += 1
        if view.state != UP:
            log.info("vehicle %d: data again after %.1f s", sysid, now - view.last_mono)
            view.state = UP
        view.last_mono = now
        for rec in records:
            self._on_estimate(view, rec, now)
        if self.tracker.rays:
            self._publish_rays()

    def _publish_rays(self) -> None:
        rays = self.tracker.rays
        assert rays is not None
        sent = self.clock()
        for r in rays:
            d = r.to_dict()
            d["sent_unix_s"] = sent
            self.pub.ray(r.sysid, r.target, json.dumps(d, separators=(",", ":")))
        rays.clear()

    def _new_vehicle(self, sysid: int, now: float) -> _VehicleView:
        view = self.vehicles[sysid] = _VehicleView(sysid, now, status_mono=now)
        self.pub.vehicle(sysid)
        log.info("vehicle %d: first data, publishing under %s/%d/", sysid, self.pub.prefix, sysid)
        return view

    def _on_estimate(self, view: _VehicleView, rec: EstimateRecord, now: float) -> None:
        tgt = view.targets.get(rec.target)
        if tgt is None:
            tgt = view.targets[rec.target] = _Target(rec.source)
        status = str(rec.estimate.status)
        changed = status != tgt.status
        if changed:
            log.info(
                "vehicle %d, target %s: %s -> %s (range %.1f m, excitation %.3f)",
                view.sysid,
                rec.target,
                tgt.status or "new",
                status,
                rec.estimate.range_m,
                rec.estimate.excitation,
            )
            tgt.status = status
        tgt.estimates += 1
        tgt.last_record = rec
        tgt.last_estimate_mono = now
        # the vehicle's attitude at the estimate's time, looked up once for the map and MAVLink
        rpy = None
        if self.web is not None or self.mavlink_out is not None:
            rpy = self.tracker.vehicle_attitude(rec.sysid, rec.t_boot_s)
        if changed or now >= tgt.next_pub_mono:
            # a schedule rather than a minimum gap, so that the average is the configured
            # rate whatever the bearing rate (no catching up after a quiet spell)
            nxt = tgt.next_pub_mono + self.min_interval_s
            if changed or nxt <= now:
                nxt = now + self.min_interval_s
            tgt.next_pub_mono = nxt
            tgt.published += 1
            text = rec.to_json()
            self.pub.estimate(view.sysid, rec.target, text)
            if self.web is not None:  # the live map: an append, never a wait
                origin = self.tracker.origin(rec.sysid)
                self.web.add(rec, None if rpy is None else rpy[2], origin, text)
        if self.mavlink_out is not None:
            self.mavlink_out.on_estimate(rec, rpy, now)

    # -- housekeeping -------------------------------------------------------------------
    def housekeeping(self, now: float) -> None:
        """Bearings that waited long enough for their attitude, stale detection, the periodic
        status, the periodic save."""
        self._next_tick = now + self.tick_s
        for rec in self.tracker.release_due(self.clock()):
            view = self.vehicles.get(rec.sysid)
            if view is not None:
                self._on_estimate(view, rec, now)
        if self.tracker.rays:
            self._publish_rays()
        if (
            self._link_state == UP
            and self._last_any_mono is not None
            and now - self._last_any_mono > self.stale_after_s
        ):
            log.warning(
                "MAVLink link %s: no data for %.1f s", self.reader.source, self.stale_after_s
            )
            self._link_state = STALE
        for view in self.vehicles.values():
            if view.state == UP and now - view.last_mono > self.stale_after_s:
                view.state = STALE
                log.warning(
                    "vehicle %d: no data for %.1f s: stale, estimates stop",
                    view.sysid,
                    self.stale_after_s,
                )
                self._publish_status(view, now)
            elif now - view.status_mono >= self.status_period_s:
                self._publish_status(view, now)
        if self.state_file is not None and now >= self._next_save:
            self._next_save = now + self.save_period_s
            self.save_state()

    def _target_status(self, view: _VehicleView, tgt: _Target, now: float) -> str:
        if view.state == STALE or tgt.last_estimate_mono is None:
            return STALE
        if now - tgt.last_estimate_mono > self.max_bearing_age_s:
            return STALE  # the vehicle talks, but this target's bearings stopped
        return tgt.status

    def _say_systematic(self, sysid: int, name: str, tgt: _Target, ic: Correlation) -> None:
        """Log once, and count as the event ``innovations_systematic``, when a target's
        innovations turn systematic (:attr:`~mav_observer.core.samples.Correlation.systematic`);
        said again only after they have been white (lag-1 below half the warning's) since."""
        if ic.systematic and not tgt.systematic_said:
            tgt.systematic_said = True
            self.tracker.events["innovations_systematic"] += 1
            log.warning("vehicle %d: target %r: %s", sysid, name, ic.describe())
        elif tgt.systematic_said and ic.lag1 < WARN_LAG1 / 2.0:
            tgt.systematic_said = False

    def status_document(self, view: _VehicleView, now: float, *, final: bool = False) -> dict:
        """The status of one vehicle (``docs/schema.md``)."""
        span = max(now - view.status_mono, 1e-9)
        rates = {
            k: round((c - view.counts_at_status.get(k, 0)) / span, 2)
            for k, c in sorted(view.counts.items())
        }
        observers: dict[str, Any] = {}
        for name, tgt in sorted(view.targets.items()):
            rec = tgt.last_record
            e = None if rec is None else rec.estimate
            obs = self.tracker.observer(view.sysid, name)
            noise = None if obs is None else obs.noise()
            if noise is not None and noise.innovation_corr is not None:
                self._say_systematic(view.sysid, name, tgt, noise.innovation_corr)
            observers[name] = {
                "source": tgt.source,
                "status": self._target_status(view, tgt, now),
                "pe": None if e is None else e.excitation,
                "cond_m": None if e is None else e.cond_m,
                "range_m": None if e is None else e.range_m,
                "last_estimate_age_s": None
                if tgt.last_estimate_mono is None
                else round(now - tgt.last_estimate_mono, 3),
                "estimates": tgt.estimates,
                "published": tgt.published,
                "noise": None if noise is None else noise.to_dict(),
            }
        doc = {
            "schema": STATUS_SCHEMA,
            "t_unix_s": self.clock(),
            "sysid": view.sysid,
            "service": {
                "version": __version__,
                "state": "stopping" if final else "running",
                "uptime_s": round(now - self._start_mono, 3),
            },
            "link": {
                "url": self.reader.source,
                "state": view.state,
                "connected": self.reader.connected,
                "last_message_age_s": round(now - view.last_mono, 3),
                "link_errors": self.reader.link_errors,
                "kernel_drops": self.reader.kernel_drops(),
            },
            "rates_hz": rates,
            "messages": sum(view.counts.values()),
            "skipped": dict(sorted(self.tracker.vehicle_skipped(view.sysid).items())),
            "link_skipped": {
                k: v for k, v in sorted(self.tracker.skipped.items()) if k in _LINK_REASONS
            },
            "bearing_sources": sorted({t.source for t in view.targets.values()}),
            "origin": self.tracker.origin(view.sysid),
            "gimbal_angles": {
                str(dev): reading for dev, reading in self.tracker.gimbal_angles(view.sysid).items()
            },
            "observers": observers,
            "events": dict(sorted(self.tracker.events.items())),
        }
        return doc

    def _publish_status(self, view: _VehicleView, now: float, *, final: bool = False) -> None:
        doc = self.status_document(view, now, final=final)
        view.counts_at_status = Counter(view.counts)
        view.status_mono = now
        self.pub.status(view.sysid, json.dumps(doc, separators=(", ", ": ")))

    # -- state file ---------------------------------------------------------------------
    def restore_state(self) -> None:
        """Give the tracker the observers of the state file, if there is one. A missing file
        is normal (first start); an unreadable or invalid one is logged, moved aside to
        ``<file>.bad`` and the service starts afresh."""
        path = self.state_file
        if path is None:
            return
        try:
            saved_unix_s, observers = statefile.load(path)
            self.tracker.restore(observers)
        except FileNotFoundError:
            log.info("state file %s: none yet, starting afresh", path)
            return
        except (MavObserverError, OSError) as exc:
            self.state_errors += 1
            log.error("state file %s not used: %s", path, exc)
            try:
                path.replace(path.with_name(path.name + ".bad"))
            except OSError as exc2:
                log.error("cannot move %s aside: %s", path, exc2)
            return
        age = self.clock() - saved_unix_s
        log.info(
            "state file %s: %d observer(s) saved %.1f s ago, each resumes at its vehicle's "
            "first position",
            path,
            len(observers),
            age,
        )

    def save_state(self) -> None:
        """Save the observers (never raises: a failure is logged and counted)."""
        if self.state_file is None:
            return
        try:
            statefile.save(self.state_file, self.tracker.export_state(), saved_unix_s=self.clock())
        except (OSError, TypeError, ValueError) as exc:
            self.state_errors += 1
            if self.state_errors in (1, 10, 100) or self.state_errors % 1000 == 0:
                log.error(
                    "cannot save the state file %s (%d failures): %s",
                    self.state_file,
                    self.state_errors,
                    exc,
                )


#: Skip reasons that belong to the link rather than to a vehicle.
_LINK_REASONS = frozenset({"bad_data", "foreign_sysid"})

__all__ = ["STATUS_SCHEMA", "Service"]
