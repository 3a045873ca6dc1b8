"""The service's loop in-process, with a scripted reader, fake publications and an injected
clock: rate limiting, status documents, staleness, the state file, shutdown."""

from __future__ import annotations

import errno
import itertools
import json
import math
import os
from pathlib import Path
from typing import Any

import pytest
from mavmsg import TLOGS

from mav_observer.app import settings as st
from mav_observer.app import statefile
from mav_observer.app.service import Service
from mav_observer.mavlink.dialect import codec
from mav_observer.mavlink.tlog import TlogReader
from mav_observer.outputs import records
from sim import scenarios
from sim.emitter import Emitter, EmitterConfig


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class ScriptReader:
    """Stands in for ConnectionReader: hands out ``(t_unix_s, msg)`` and moves the clock to
    each message's emission time (wall time = scenario time)."""

    source = "script:"
    connected = True
    link_errors = 0

    def __init__(self, items: list[tuple[float, Any]], clock: Clock, t0: float) -> None:
        self.items = items
        self.i = 0
        self.clock = clock
        self.t0 = t0
        self.closed = False

    def recv(self, timeout_s: float | None = None) -> tuple[float, Any] | None:
        if self.i >= len(self.items):
            self.clock.t += timeout_s or 0.05
            return None
        t, msg = self.items[self.i]
        due = t - self.t0 + 1000.0
        wait = timeout_s or 0.05
        if due > self.clock.t + wait:  # nothing arrives within the timeout
            self.clock.t += wait
            return None
        self.i += 1
        self.clock.t = max(self.clock.t, due)
        return t, msg

    def close(self) -> None:
        self.closed = True

    def kernel_drops(self) -> int | None:
        return None


class FakePublications:
    prefix = "mav_observer"

    def __init__(self) -> None:
        self.estimates: list[tuple[int, str, dict[str, Any]]] = []
        self.statuses: list[tuple[int, dict[str, Any]]] = []
        self.vehicles: list[int] = []
        self.rays: list[tuple[int, str, dict[str, Any]]] = []
        self.rays_listened = True  # a fuse node subscribes
        self.watching = False
        self.closed = False

    def vehicle(self, sysid: int) -> None:
        self.vehicles.append(sysid)

    def estimate(self, sysid: int, target: str, payload: str) -> None:
        self.estimates.append((sysid, target, json.loads(payload)))

    def status(self, sysid: int, payload: str) -> None:
        self.statuses.append((sysid, json.loads(payload)))

    def ray(self, sysid: int, target: str, payload: str) -> None:
        self.rays.append((sysid, target, json.loads(payload)))

    def watch_rays(self) -> None:
        self.watching = True

    def close(self) -> None:
        self.closed = True


def messages(
    duration_s: float,
    *,
    sysid: int = 1,
    bearing: str = "gimbal",
    seed: int = 0,
    bearing_noise_deg: float = 0.0,
):
    em = Emitter(
        scenarios.orbit(),
        EmitterConfig(
            duration_s=duration_s,
            sysid=sysid,
            bearing=bearing,
            seed=seed,
            bearing_noise_deg=bearing_noise_deg,
        ),
    )
    mav = codec()
    out = []
    for e in em.emissions():
        out.append((em.unix_s(e.t_emit_s), mav.decode(bytearray(e.frame))))
    return out, em


def make_service(
    items, em, overrides=None, start_s: float = 0.0
) -> tuple[Service, FakePublications, Clock]:
    clock = Clock()
    reader = ScriptReader(items, clock, em.unix_s(start_s))
    pubs = FakePublications()
    settings = st.resolve(None, overrides or {})
    svc = Service(settings, reader, pubs, clock=clock, monotonic=clock)  # type: ignore[arg-type]
    return svc, pubs, clock


def test_estimates_are_rate_limited_but_status_changes_always_go_out() -> None:
    items, em = messages(60.0)
    svc, pubs, _ = make_service(items, em, {"zenoh": {"estimate_max_rate_hz": 2.0}})
    svc.run(duration_s=61.0)
    n_est = svc.vehicles[1].targets["gimbal"].estimates
    assert n_est > 500  # 10 Hz bearings for 60 s
    times = [e[2]["t_boot_s"] for e in pubs.estimates]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    statuses = [e[2]["status"] for e in pubs.estimates]
    changes = sum(1 for a, b in itertools.pairwise(statuses) if a != b)
    assert 2 * 60 - 2 <= len(pubs.estimates) <= 2 * 60 + 2 + changes  # 2 Hz on average
    # every gap is at least 0.5 s except where the status changed
    short = [g for g, a, b in zip(gaps, statuses, statuses[1:], strict=False) if g < 0.49]
    assert len(short) <= changes
    assert pubs.vehicles == [1]


def test_status_document_reports_rates_sources_and_observers() -> None:
    items, em = messages(30.0)
    svc, pubs, _ = make_service(items, em)
    svc.run(duration_s=20.0)
    assert len(pubs.statuses) >= 15  # 1 Hz
    sysid, doc = pubs.statuses[10]
    assert sysid == 1 and doc["sysid"] == 1 and doc["schema"] == records.STATUS_SCHEMA
    assert tuple(doc) == records.STATUS_KEYS  # the schema beside the estimate's
    assert doc["link"]["state"] == "up"
    # the emitter's rates: attitude 20 Hz, position 10 Hz, bearing 10 Hz, heartbeat 1 Hz
    assert doc["rates_hz"]["ATTITUDE"] == pytest.approx(20.0, rel=0.15)
    assert doc["rates_hz"]["GIMBAL_DEVICE_ATTITUDE_STATUS"] == pytest.approx(10.0, rel=0.15)
    assert doc["bearing_sources"] == ["GIMBAL_DEVICE_ATTITUDE_STATUS"]
    # the emitter's vehicle flies level: its gimbal's reading stays the flags', undecided
    assert doc["gimbal_angles"] == {"1": "auto"}
    obs = doc["observers"]["gimbal"]
    assert obs["status"] in ("converging", "converged")
    assert obs["range_m"] > 0 and 0.0 <= obs["pe"] <= 1.0
    # the last status is the final one
    assert pubs.statuses[-1][1]["service"]["state"] == "stopping"
    assert pubs.closed and svc.reader.closed  # type: ignore[attr-defined]


@pytest.mark.slow
def test_silence_makes_the_vehicle_stale_and_data_brings_it_back() -> None:
    items, em = messages(40.0)
    t_cut = em.unix_s(15.0)
    t_back = em.unix_s(25.0)
    kept = [(t, m) for t, m in items if not t_cut <= t < t_back]  # 10 s of silence
    svc, pubs, _ = make_service(kept, em, {"mavlink": {"stale_after_s": 2.0}})
    svc.run(duration_s=41.0)
    states = [(d["t_unix_s"], d["link"]["state"], d["observers"]) for _, d in pubs.statuses]
    stale = [s for s in states if s[1] == "stale"]
    assert stale, "no stale status during 10 s of silence"
    assert all(o["status"] == "stale" for _, _, obs in stale for o in obs.values())
    first_stale = stale[0][0] - 1000.0
    assert 17.0 <= first_stale <= 17.3  # 2 s after the last message, at the next tick
    # no estimate during the silence, estimates again after it
    est_t = [e[2]["t_unix_s"] for e in pubs.estimates]
    assert not any(t_cut + 0.01 < t < t_back for t in est_t)
    assert any(t > t_back for t in est_t)
    assert states[-1][1] == "up"


def test_a_target_whose_bearings_stop_is_stale_while_the_vehicle_talks() -> None:
    items, em = messages(30.0)
    t_cut = em.unix_s(10.0)
    kept = [
        (t, m)
        for t, m in items
        if not (t >= t_cut and m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS")
    ]
    svc, pubs, _ = make_service(kept, em)
    svc.run(duration_s=25.0)
    last = pubs.statuses[-2][1]  # before the final one
    assert last["link"]["state"] == "up"
    assert last["observers"]["gimbal"]["status"] == "stale"


def test_bearings_waiting_for_their_attitude_at_shutdown_are_not_lost() -> None:
    # the last 0.4 s of vehicle attitude never arrives: the bearings of that time wait for it; the
    # shutdown gives them to the observer (extrapolated attitude), as replay's end does
    from mav_observer.tracking.tracker import Tracker

    items, em = messages(20.0)
    t_cut = items[-1][0] - 0.4
    att = ("ATTITUDE", "ATTITUDE_QUATERNION")
    items = [(t, m) for t, m in items if not (t > t_cut and m.get_type() in att)]
    svc, _, _ = make_service(items, em)
    svc.run(duration_s=21.0)
    tr = Tracker(st.resolve(None, {}).tracker_config())
    handled = sum(len(tr.handle(t, m)) for t, m in items)
    flushed = len(tr.flush())
    assert flushed >= 2  # bearings were waiting at the end
    assert svc.vehicles[1].targets["gimbal"].estimates == handled + flushed


def test_ground_station_heartbeats_make_no_vehicle() -> None:
    mav = codec(255, 190)
    from mav_observer.mavlink.dialect import mavlink

    hb = mav.decode(
        bytearray(
            mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav)  # GCS, no autopilot
        )
    )
    items, em = messages(5.0)
    items = [(items[0][0], hb), *items]
    svc, pubs, _ = make_service(items, em)
    svc.run(duration_s=6.0)
    assert pubs.vehicles == [1]
    assert set(svc.vehicles) == {1}


@pytest.mark.slow
def test_state_is_saved_and_restored_across_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    items, em = messages(150.0, seed=3)
    first = [(t, m) for t, m in items if t < em.unix_s(120.0)]
    svc, pubs, _ = make_service(first, em, {"state": {"file": str(path)}})
    svc.run(duration_s=121.0)
    assert pubs.estimates[-1][2]["status"] == "converged"
    _saved_unix, observers = statefile.load(path)
    assert len(observers) == 1 and observers[0]["target"] == "gimbal"
    # restart 20 s later: the vehicle flew on meanwhile
    later = [(t, m) for t, m in items if t >= em.unix_s(140.0)]
    svc2, pubs2, _ = make_service(later, em, {"state": {"file": str(path)}}, start_s=140.0)
    svc2.run(duration_s=3.0)
    first_est = pubs2.estimates[0][2]
    assert first_est["status"] == "converged"
    assert first_est["t_boot_s"] - em.boot_ms(140.0) / 1000 < 0.2
    truth = em.vehicle.state(first_est["t_boot_s"] - em.boot_ms(0.0) / 1000).rel_pos_ned_m
    err = math.dist(first_est["rel_pos_ned_m"], truth.tolist())
    assert err < 0.05 * float(math.hypot(*truth))


def test_a_bad_state_file_is_moved_aside_and_the_service_starts_afresh(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    path.write_text('{"kind": "mav-observer state", "schema": 2, "saved_unix_s": "x"}')
    items, em = messages(10.0)
    svc, pubs, _ = make_service(items, em, {"state": {"file": str(path)}})
    svc.run(duration_s=11.0)
    assert svc.state_errors == 1
    assert (tmp_path / "state.json.bad").exists()
    assert pubs.estimates  # it ran
    assert statefile.load(path)[1]  # and saved a good state on stop


def test_an_unwritable_state_file_is_an_error_logged_not_fatal(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "no_such_dir" / "state.json"
    items, em = messages(10.0)
    svc, pubs, _ = make_service(items, em, {"state": {"file": str(path), "save_period_s": 1.0}})
    svc.run(duration_s=11.0)
    assert svc.state_errors >= 5
    assert "cannot save the state file" in caplog.text
    assert len(pubs.estimates) > 50  # estimating and publishing went on


def test_a_full_disk_is_an_error_logged_not_fatal(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The disk fills up: every save fails with ENOSPC (os.fsync refusing, as on a full
    filesystem); no partial file is left, estimating and publishing go on, and the next save
    after space returns succeeds."""
    path = tmp_path / "state.json"
    full = {"on": True}
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        if full["on"]:
            raise OSError(errno.ENOSPC, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    items, em = messages(10.0)
    svc, pubs, _ = make_service(items, em, {"state": {"file": str(path), "save_period_s": 1.0}})
    svc.run(duration_s=6.0)
    assert svc.state_errors >= 3
    assert "No space left on device" in caplog.text
    assert not path.exists() and not list(tmp_path.glob(".state.json.*"))
    assert len(pubs.estimates) > 30
    full["on"] = False
    svc.run(duration_s=5.0)
    assert path.exists()


@pytest.mark.slow
def test_memory_stays_bounded_per_vehicle() -> None:
    """Nothing in the service's bookkeeping grows with the number of messages."""
    items, em = messages(120.0)
    svc, _, _ = make_service(items, em)
    svc.run(duration_s=121.0)
    view = svc.vehicles[1]
    assert len(view.counts) < 20 and len(view.targets) == 1
    veh = svc.tracker.vehicles[1]
    obs = svc.tracker.observer(1, "gimbal")
    assert obs is not None
    assert obs.buffered["bearing"] < 10 and obs.buffered["velocity"] < 10
    assert len(veh.attitude._h) <= 128


@pytest.mark.slow
def test_systematic_bearing_errors_are_said_once_and_counted(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The shared SITL log's servo mount points with errors that wander over seconds
    (docs/geolocation.md): the service logs once that the target's innovations are
    systematic, counts the event ``innovations_systematic`` and its status carries the
    correlation. The emitter's bearings say nothing: white at 0.5 deg; noise-free, correlated
    but thousands of times smaller than the noise learnt, which covers them."""
    items = list(TlogReader(str(TLOGS / "ardupilot_sitl_servo_mount_roi.tlog")))
    clock = Clock()
    reader = ScriptReader(items, clock, items[0][0])
    pubs = FakePublications()
    settings = st.resolve(None, {})
    svc = Service(settings, reader, pubs, clock=clock, monotonic=clock)  # type: ignore[arg-type]
    with caplog.at_level("WARNING", logger="mav_observer.app.service"):
        svc.run(duration_s=items[-1][0] - items[0][0] + 2.0)
    said = [r.getMessage() for r in caplog.records if "systematic" in r.getMessage()]
    assert len(said) == 1 and "target 'gimbal'" in said[0], said
    last = pubs.statuses[-1][1]
    assert last["events"]["innovations_systematic"] == 1
    assert last["observers"]["gimbal"]["noise"]["innovation_lag1"] > 0.8
    for noise_deg in (0.5, 0.0):
        items, em = messages(120.0, bearing_noise_deg=noise_deg)
        svc, pubs, _ = make_service(items, em)
        with caplog.at_level("WARNING", logger="mav_observer.app.service"):
            caplog.clear()
            svc.run(duration_s=121.0)
        assert not [r for r in caplog.records if "systematic" in r.getMessage()]
        last = pubs.statuses[-1][1]
        assert "innovations_systematic" not in last["events"]
        noise = last["observers"]["gimbal"]["noise"]
        if noise_deg:
            assert abs(noise["innovation_lag1"]) < 0.1
            assert noise["innovation_var_ratio"] == pytest.approx(1.0, abs=0.3)
        else:
            assert noise["innovation_lag1"] > 0.5 and noise["innovation_var_ratio"] < 1e-3


def test_each_bearing_used_is_published_as_a_geodetic_ray_on_the_autopilots_clock() -> None:
    items, em = messages(10.0)
    svc, pubs, _ = make_service(items, em)
    svc.run(duration_s=11.0)
    assert len(pubs.rays) > 80  # 10 Hz bearings, from the first velocity on
    sysid, target, ray = pubs.rays[-1]
    assert (sysid, target, ray["sysid"], ray["target"]) == (1, "gimbal", 1, "gimbal")
    assert ray["clock"] == "autopilot"  # SYSTEM_TIME carries the Unix time
    assert abs(ray["t_unix_s"] - em.unix_s(ray["t_boot_s"] - em.config.boot_at_start_s)) < 1e-3
    assert abs(ray["lat_deg"] + 35.36) < 0.01 and ray["sent_unix_s"] is not None
    assert abs(math.hypot(*ray["los_ned"]) - 1.0) < 1e-9


def test_rays_can_be_turned_off() -> None:
    items, em = messages(5.0)
    svc, pubs, _ = make_service(items, em, {"zenoh": {"rays": False}})
    svc.run(duration_s=6.0)
    assert pubs.rays == [] and not pubs.watching
    assert svc.vehicles[1].targets["gimbal"].estimates > 30


def test_rays_are_made_only_while_someone_subscribes_to_them() -> None:
    items, em = messages(10.0)
    svc, pubs, _ = make_service(items, em)
    pubs.rays_listened = False
    svc.run(duration_s=5.0)
    assert pubs.watching and pubs.rays == [] and svc.tracker.rays is None
    pubs.rays_listened = True  # a fuse node came
    svc.run(duration_s=11.0)
    assert len(pubs.rays) > 30
    assert all(r[2]["t_boot_s"] > em.boot_ms(4.5) / 1000 for r in pubs.rays)
