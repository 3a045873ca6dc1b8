"""Routing MAVLink to observers (mav_observer/tracking/tracker.py)."""

import functools
import math

import numpy as np
import pytest
from mavmsg import T0_UNIX, landing_target_fields, message

from mav_observer.core import drift
from mav_observer.core.observer import ObserverConfig
from mav_observer.errors import ConfigError, StateError
from mav_observer.mavlink.dialect import codec
from mav_observer.tracking.tracker import Tracker, TrackerConfig
from sim import fuzz

NAN = float("nan")
FLAGS_VEHICLE = 0x2C
Q_DOWN45 = (math.cos(math.radians(-22.5)), 0.0, math.sin(math.radians(-22.5)), 0.0)  # pitch -45


def lpn(ms, pos=(0.0, 0.0, -10.0), vel=(1.0, 0.0, 0.0), sysid=1):
    return message("LOCAL_POSITION_NED", ms, *pos, *vel, sysid=sysid)


def att(ms, yaw=0.0, roll=0.0, pitch=0.0, sysid=1):
    return message("ATTITUDE", ms, roll, pitch, yaw, 0.0, 0.0, 0.0, sysid=sysid)


def gimbal(ms, q=Q_DOWN45, flags=FLAGS_VEHICLE, failure=0, sysid=1, compid=1, dev=1):
    return message(
        "GIMBAL_DEVICE_ATTITUDE_STATUS", 0, 0, ms, flags, list(q),
        NAN, NAN, NAN, failure, NAN, NAN, dev, sysid=sysid, compid=compid,
    )  # fmt: skip


def feed(tr: Tracker, msgs, t0=T0_UNIX, boot0_ms=100_000):
    out = []
    for m in msgs:
        ms = getattr(m, "time_boot_ms", None)
        t = t0 + ((ms - boot0_ms) / 1000.0 if ms is not None else 0.0) + 0.01
        out += tr.handle(t, m)
    return out + tr.flush()  # the end of the stream: bearings waiting for an attitude


def flight(n=50, sysid=1, yaw=0.0, boot0=100_000):
    """A vehicle flying north at 1 m/s, gimbal 45 deg down: attitude, position, gimbal, 10 Hz."""
    msgs = []
    for i in range(n):
        ms = boot0 + 100 * i
        msgs += [
            att(ms, yaw, sysid=sysid),
            lpn(ms, (0.1 * i, 0.0, -10.0), sysid=sysid),
            gimbal(ms + 5, sysid=sysid),
        ]
    return msgs


def test_one_vehicle_one_gimbal_estimates_with_context() -> None:
    tr = Tracker()
    recs = feed(tr, flight())
    assert len(recs) == 50  # every bearing (a velocity sample precedes the first one)
    r = recs[-1]
    assert (r.sysid, r.target, r.source) == (1, "gimbal", "GIMBAL_DEVICE_ATTITUDE_STATUS")
    assert r.t_boot_s == pytest.approx(100.0 + 4.905)  # the autopilot clock
    assert r.t_unix_s == pytest.approx(T0_UNIX + 4.905 + 0.01)  # arrival (tlog) time
    # extrapolated 5 ms with the velocity less the estimated bias (its error, for a fixed target)
    a = r.estimate.a_mps.tolist()
    assert r.vehicle_pos_ned_m == pytest.approx(
        (4.9 + (1.0 - a[0]) * 0.005, -a[1] * 0.005, -10.0 - a[2] * 0.005)
    )
    assert tr.targets() == {(1, "gimbal"): "GIMBAL_DEVICE_ATTITUDE_STATUS"}
    assert tr.skipped == {}


def test_bearing_follows_the_vehicle_yaw() -> None:
    tr = Tracker(TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    recs = feed(tr, flight(yaw=math.pi / 2))
    y = recs[-1].estimate.x_m
    # gimbal yaw 0 relative to a vehicle heading east: the estimate lies east and below
    assert y[1] > 0 and y[2] > 0 and abs(y[0]) < 0.5 * y[1]


def test_two_vehicles_and_landing_targets_get_their_own_observers() -> None:
    tr = Tracker()
    msgs = flight(sysid=1) + flight(sysid=2)
    for i in range(20):
        ms = 100_000 + 100 * i + 7
        for num in (0, 3):
            msgs.append(
                message(
                    "LANDING_TARGET", *landing_target_fields(ms * 1000, num, 12, 0.1 * num, 0.0)
                )
            )
    msgs.sort(key=lambda m: getattr(m, "time_boot_ms", getattr(m, "time_usec", 0) // 1000))
    feed(tr, msgs)
    assert set(tr.targets()) == {
        (1, "gimbal"),
        (2, "gimbal"),
        (1, "landing_target_0"),
        (1, "landing_target_3"),
    }


def test_autopilot_reboot_resets_the_vehicle_and_says_so() -> None:
    tr = Tracker()
    feed(tr, flight(n=30))
    before = tr.observer(1, "gimbal")
    feed(tr, flight(n=30, boot0=5_000), boot0_ms=5_000, t0=T0_UNIX + 60)  # booted again
    assert tr.events["autopilot_reboot"] == 1
    assert tr.observer(1, "gimbal") is not before
    # the new clock is believed after 5 messages over 0.5 s: the first 5 bearings (10 Hz) are
    # refused while it is confirmed, with the other messages of that half second
    assert tr.observer(1, "gimbal").counts["bearing"] == 25
    assert tr.skipped["clock_unconfirmed"] >= 5


def test_bad_messages_are_counted_and_the_stream_goes_on() -> None:
    tr = Tracker()
    good = flight(n=40)
    bad = [  # between the good samples of 101.0 s and 101.1 s
        gimbal(101_010, q=(0.0, 0.0, 0.0, 0.0)),
        gimbal(101_020, failure=32),
        gimbal(101_030, flags=FLAGS_VEHICLE | 1),
        message("LOCAL_POSITION_NED", 101_040, 0.0, 0.0, 0.0, NAN, 0.0, 0.0),
        message("ATTITUDE", 101_050, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0),
        att(100_000),  # time went back 1.05 s: reordered, not a reboot
    ]
    msgs = good[:33] + bad + good[33:]
    recs = feed(tr, msgs)
    assert tr.skipped == {
        "zero_quaternion": 1,
        "gimbal_failure": 1,
        "gimbal_not_tracking": 1,
        "non_finite": 1,
        "attitude_out_of_range": 1,
        "out_of_order": 1,
    }
    assert len(recs) == 40 and recs[-1].t_boot_s == pytest.approx(103.905)


def test_camera_tracking_needs_a_field_of_view_and_an_attitude() -> None:
    tr = Tracker()
    feed(tr, flight(n=5))
    track = message(
        "CAMERA_TRACKING_IMAGE_STATUS", 1, 1, 4, 0.5, 0.5, NAN, NAN, NAN, NAN, NAN, 0, compid=100
    )
    t = T0_UNIX + 0.46
    assert tr.handle(t, track) == [] and tr.skipped["no_fov"] == 1
    fov = message(
        "CAMERA_FOV_STATUS", 100_450, 0, 0, 0, 0, 0, 0, [1.0, 0.0, 0.0, 0.0], 60.0, 45.0, compid=100
    )
    tr.handle(t, fov)
    recs = tr.handle(t, track)
    assert len(recs) == 1 and recs[0].target == "camera"
    idle = message(
        "CAMERA_TRACKING_IMAGE_STATUS", 0, 1, 4, 0.5, 0.5, NAN, NAN, NAN, NAN, NAN, 0, compid=100
    )
    assert tr.handle(t, idle) == [] and tr.skipped["tracking_inactive"] == 1


def test_sources_and_sysids_are_filtered() -> None:
    tr = Tracker(TrackerConfig(sources=("landing_target",), sysids=(2,)))
    feed(tr, flight(sysid=1) + flight(sysid=2))
    assert tr.targets() == {}
    assert tr.skipped["foreign_sysid"] == 150
    assert tr.config.enabled() == {"landing_target"}
    with pytest.raises(ConfigError, match="sources must be"):
        TrackerConfig(sources=("radar",))
    with pytest.raises(ConfigError, match="gimbal_angles"):
        TrackerConfig(gimbal_angles="sideways")


@functools.cache
def _converged_tracker():
    from mav_observer.mavlink.dialect import codec
    from sim import scenarios
    from sim.emitter import Emitter, EmitterConfig

    em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=160.0, bearing_noise_deg=0.5))
    mav = codec()
    items = [(em.unix_s(e.t_emit_s), mav.decode(bytearray(e.frame))) for e in em.emissions()]
    tr = Tracker()
    for t, m in items:
        if t >= em.unix_s(100.0):
            break
        tr.handle(t, m)
    return tr, items, em


@pytest.mark.slow
def test_exported_observers_resume_where_the_vehicle_is_now() -> None:
    tr, items, em = _converged_tracker()
    saved = tr.export_state()
    assert [(e["sysid"], e["target"]) for e in saved] == [(1, "gimbal")]
    tr2 = Tracker()
    tr2.restore(saved)
    recs = []
    for t, m in items:
        if t >= em.unix_s(130.0):  # 30 s later
            recs += tr2.handle(t, m)
    assert tr2.events["restored"] == 1
    first = recs[0]
    truth = em.vehicle.state(first.t_boot_s - em.boot_ms(0.0) / 1000).rel_pos_ned_m
    assert math.dist(first.estimate.x_m.tolist(), truth.tolist()) < 0.15  # of 18 m
    assert str(first.estimate.status) == "converged"


def test_saved_observers_are_dropped_after_a_reboot_or_a_long_gap() -> None:
    tr, _items, em = _converged_tracker()
    saved = tr.export_state()
    tr2 = Tracker()
    tr2.restore(saved)
    tr2.handle(T0_UNIX, lpn(5_000))  # the autopilot clock is far behind: it rebooted
    assert tr2.events["restore_discarded"] == 1 and tr2.observer(1, "gimbal") is None
    tr3 = Tracker(TrackerConfig(restore_max_gap_s=10.0))
    tr3.restore(saved)
    tr3.handle(T0_UNIX, lpn(em.boot_ms(130.0)))
    assert tr3.events["restore_discarded"] == 1


def _unstarted(e: dict) -> None:
    """A saved observer made to look as if it never started."""
    from mav_observer.core.kernels import layout as L

    data = e["observer"]["arrays"]["s"]["data"]
    data[L.S_T_C], data[L.S_STARTED] = None, 0.0


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda e: e.update(sysid=0), r"observers\[0\]\.sysid"),
        (lambda e: e.update(target=""), r"observers\[0\]\.target"),
        (lambda e: e["vehicle"].update(pos_ned_m=[0.0, 1.0]), r"observers\[0\]\.vehicle"),
        (_unstarted, r"observers\[0\]\.observer must be a started"),
        (lambda e: e["observer"].pop("arrays"), r"observers\[0\]\.observer: .*'arrays'"),
    ],
)
def test_restoring_bad_entries_names_them(mutate, match: str) -> None:
    import copy

    from mav_observer.errors import StateError

    tr, _, _ = _converged_tracker()
    saved = copy.deepcopy(tr.export_state())
    mutate(saved[0])
    with pytest.raises(StateError, match=match):
        Tracker().restore(saved)


# -- semantic nonsense: each has a defined reaction ----------------------------------------


def _estimates(recs) -> list[tuple[float, list[float]]]:
    return [(r.t_boot_s, r.estimate.x_m.tolist()) for r in recs]


def test_duplicated_messages_are_refused_and_change_nothing() -> None:
    """Every message sent twice (a routing loop, two links merged): each repeat is refused as
    ``duplicate`` and the estimates are those of the stream without repeats."""
    clean = _estimates(feed(Tracker(), flight(n=40)))
    tr = Tracker()
    doubled = [m for m in flight(n=40) for m in (m, m)]
    assert _estimates(feed(tr, doubled)) == clean
    assert tr.skipped["duplicate"] == 3 * 40


def test_a_heartbeat_flood_from_another_sysid_changes_nothing() -> None:
    """A second system floods autopilot HEARTBEATs (10,000): it becomes a vehicle of its own
    with no observer and no estimate; vehicle 1's estimates are exactly those without it."""
    clean = _estimates(feed(Tracker(), flight(n=40)))
    hb = message("HEARTBEAT", 2, 3, 0, 0, 4, 3, sysid=77)
    msgs = []
    for m in flight(n=40):
        msgs += [m, *([hb] * 83)]
    tr = Tracker()
    assert _estimates(feed(tr, msgs)) == clean
    assert set(tr.vehicles) == {1, 77} and not tr.vehicles[77].targets
    assert tr.received["HEARTBEAT"] >= 9_960


def test_unknown_message_ids_share_one_counter() -> None:
    """Garbage can carry any of 16 million message ids: they are counted under one key, so
    no counter grows with them."""
    m = codec()
    m.robust_parsing = True
    rng = np.random.default_rng(3)
    tr = Tracker()
    for _ in range(2000):
        for msg in m.parse_buffer(fuzz.unknown_msgid_frame(rng, 1)) or []:
            tr.handle(T0_UNIX, msg)
    assert tr.received["UNKNOWN"] >= 1900
    assert not [k for k in tr.received if k.startswith("UNKNOWN_")]


# -- the attitude of a bearing's own time, component clocks, sparse velocity ---------------

YAW_RATE = math.radians(30.0)  # rad/s


def steady_yaw(t):
    """Yaw (rad) and its rate (rad/s) of a vehicle yawing at 30 deg/s."""
    return YAW_RATE * t, YAW_RATE


def zigzag_yaw(t):
    """Yawing at +-60 deg/s, the rate switching every 40 ms (at an ATTITUDE's time)."""
    w, k = math.radians(60.0), math.floor(t / 0.04 + 1e-9)
    base = 0.04 * w if k % 2 else 0.0
    rate = -w if k % 2 else w
    return base + rate * (t - 0.04 * k), rate


def yawing_flight(
    n=200, bearing_first=False, attitude_until_ms=None, compid=154, yaw=steady_yaw, rates=True
):
    """A vehicle flying north at 1 m/s and yawing (``yaw(t) -> (yaw, rate)``), ATTITUDE at
    50 Hz (its yaw rate reported if ``rates``), its gimbal (its own component, on the
    autopilot's clock) at 25 Hz 7 ms after an ATTITUDE, yaw in the vehicle frame, always
    pointing the same way in NED (:data:`TRUE_LOS`). ``bearing_first``: each gimbal message
    arrives before the ATTITUDE that follows its time (else after)."""
    msgs = []
    for i in range(n):
        ms = 100_000 + 20 * i
        if attitude_until_ms is None or ms <= attitude_until_ms:
            y, r = yaw((ms - 100_000) / 1000.0)
            r = r if rates else 0.0
            a = message("ATTITUDE", ms, 0.0, 0.0, math.remainder(y, 2 * math.pi), 0.0, 0.0, r)
            msgs.append((ms, a))
        if i % 5 == 0:
            msgs.append((ms, lpn(ms, (0.001 * (ms - 100_000), 0.0, -10.0))))
        if i % 2 == 0:
            tb = ms + 7
            yaw_rel = -yaw((tb - 100_000) / 1000.0)[0]  # keeps the boresight north-east
            q = quat_about_z_then_pitch(math.radians(45.0) + yaw_rel, math.radians(-30.0))
            g = gimbal(tb, q=q, compid=compid)
            msgs.append((ms + (1 if bearing_first else 25), g))
    msgs.sort(key=lambda m: m[0])  # arrival order
    return [m for _, m in msgs]


def quat_about_z_then_pitch(yaw, pitch):
    from mav_observer.geo.frames import quat_from_euler

    return quat_from_euler(0.0, pitch, yaw)


TRUE_LOS = (
    math.cos(math.radians(-30.0)) * math.cos(math.radians(45.0)),
    math.cos(math.radians(-30.0)) * math.sin(math.radians(45.0)),
    -math.sin(math.radians(-30.0)),
)


def run_in_order(msgs, config=None):
    """Feed ``msgs``; returns the tracker, its records and the angle (deg) between each
    bearing direction used and the true line of sight."""
    tr = Tracker(config or TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    used = []
    orig = tr._bearing

    def spy(veh, target, source, tb, t_arrival, direction, out):
        c = sum(d * e for d, e in zip(direction, TRUE_LOS, strict=True))
        used.append(math.degrees(math.acos(max(-1.0, min(1.0, c)))))
        return orig(veh, target, source, tb, t_arrival, direction, out)

    tr._bearing = spy  # type: ignore[method-assign]
    recs = feed(tr, msgs)
    return tr, recs, used


def test_a_bearing_that_arrives_before_the_attitude_of_its_time_waits_for_it() -> None:
    # a gimbal (its own component) whose messages arrive before the ATTITUDE of their time:
    # the bearing is composed with the attitude of its own time, not the latest one (20 ms
    # old: 0.6 deg at 30 deg/s), whichever the arrival order
    for first in (False, True):
        tr, recs, err = run_in_order(yawing_flight(bearing_first=first))
        assert len(recs) == 100 and len(err) == 100
        assert max(err) < 1e-4  # deg
        assert "attitude_extrapolated" not in tr.events
    # a yaw rate that changes at every other ATTITUDE, no rate reported: waiting for the
    # attitude after the bearing gives it exactly; using the latest attitude (extrapolated
    # with the rate of the previous two) is off by up to 0.84 deg
    zig = functools.partial(yawing_flight, bearing_first=True, yaw=zigzag_yaw, rates=False)
    wait = TrackerConfig(
        attitude_extrapolate_s=0.0, observer=ObserverConfig(initial_range_m=20.0)
    )  # always wait for the bracketing attitude
    _, _, err = run_in_order(zig(), wait)
    assert max(err) < 1e-4
    cfg = TrackerConfig(attitude_wait_s=0.0, observer=ObserverConfig(initial_range_m=20.0))
    _, _, err = run_in_order(zig(), cfg)
    assert max(err) > 0.5
    # by default a bearing 7 ms past a 50 Hz attitude is extrapolated at once (no latency):
    # exact for a steady yaw rate, and no bearing waits
    tr, _, err = run_in_order(yawing_flight(bearing_first=True, rates=False))
    assert max(err) < 1e-4


def test_a_bearing_whose_attitude_never_comes_is_extrapolated_with_the_body_rates() -> None:
    # the attitude stream stops: the bearings after it are used with the attitude
    # extrapolated by its reported yaw rate (bounded by max_attitude_age_s), and counted
    cfg = TrackerConfig(attitude_extrapolate_s=0.0, observer=ObserverConfig(initial_range_m=20.0))
    flight = yawing_flight(bearing_first=True, attitude_until_ms=103_000)
    tr, recs, err = run_in_order(flight, cfg)
    assert tr.events["attitude_extrapolated"] >= 10
    late = [r for r in recs if r.t_boot_s > 103.0]
    assert len(late) >= 10  # used, not dropped, within max_attitude_age_s of the last attitude
    assert max(err) < 1e-4  # exact: the yaw rate is constant


def test_a_component_on_the_autopilot_clock_keeps_its_time_through_tlog_jitter_and_jumps() -> None:
    # tlog times with up to 30 ms of jitter and a jump of 500 s back: the gimbal's
    # time_boot_ms (the autopilot's clock) is used as it is
    rng = np.random.default_rng(3)
    tr = Tracker(TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    recs = []
    for i, m in enumerate(yawing_flight(n=300)):
        jump = -500.0 if i > 400 else 0.0
        ms = m.time_boot_ms
        recs += tr.handle(T0_UNIX + (ms - 100_000) / 1000 + rng.uniform(0, 0.03) + jump, m)
    recs += tr.flush()
    assert len(recs) == 150
    for r in recs:
        assert round(r.t_boot_s * 1000) % 20 == 7  # its own stamp, not moved
    assert tr.events["component_on_autopilot_clock"] == 1


def test_a_component_with_its_own_drifting_clock_is_mapped_onto_the_autopilots() -> None:
    # the gimbal booted 3.7 s after the autopilot and its clock runs 50 ppm fast
    tr = Tracker(TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    recs = []
    for m in yawing_flight(n=1500):
        ms = m.time_boot_ms
        t_arr = T0_UNIX + (ms - 100_000) / 1000 + 0.004
        sent = m
        if m.get_srcComponent() == 154:
            own = (ms - 3_700) * (1 + 50e-6)
            sent = gimbal(round(own), q=tuple(m.q), compid=154)
        recs += tr.handle(t_arr, sent)
    recs += tr.flush()
    assert len(recs) > 700
    err = [abs(r.t_boot_s * 1000 - (round(r.t_boot_s * 1000 / 20) * 20 + 7)) for r in recs]
    assert max(err) < 5.0  # ms: mapped onto the autopilot clock despite the drift


def test_an_untimed_bearing_across_a_tlog_clock_jump_stays_on_the_autopilot_clock() -> None:
    # MOUNT_STATUS has no time: its arrival maps onto the autopilot clock; a tlog that jumps
    # 500 s ahead must not move it 500 s ahead (an observer integrating 500 s of nothing)
    tr = Tracker(TrackerConfig(sources=("mount_status",)))
    recs = []
    for i in range(100):
        ms = 100_000 + 100 * i
        jump = 500.0 if i >= 50 else 0.0
        t = T0_UNIX + (ms - 100_000) / 1000 + jump
        recs += tr.handle(t + 0.001, att(ms))
        recs += tr.handle(t + 0.002, lpn(ms))
        recs += tr.handle(t + 0.005, message("MOUNT_STATUS", 0, 0, -4500, 0, 0, 2))
    recs += tr.flush()
    assert len(recs) >= 95
    for r in recs:
        assert abs(r.t_boot_s - r.estimate.t_s) < 1e-9
        lag = r.t_boot_s - (round((r.t_boot_s - 100.0) * 10) / 10 + 100.0)
        assert 0.0 <= lag < 0.05  # within the 5 ms it arrived after its vehicle's messages


def test_sparse_velocity_takes_the_displacement_from_the_position() -> None:
    # LOCAL_POSITION_NED at 1 Hz while circling: the velocity samples' trapezoid misses the
    # arc; the position's change gives it. The mean velocity handed to the observer over each
    # interval is minus the position's change per second (a constant velocity error kept out)
    tr = Tracker(TrackerConfig(sources=("home",)))
    om, rad = 2 * math.pi / 20.0, 15.0
    err = (0.5, -0.3, 0.0)  # the velocity's constant error: not in the position
    means = []
    orig = tr._interval_mean_velocity

    def spy(veh, tb, pos, vel):
        out = orig(veh, tb, pos, vel)
        means.append((tb, pos, out))
        return out

    tr._interval_mean_velocity = spy  # type: ignore[method-assign]
    prev = None
    for k in range(60):
        t = float(k)
        pos = (rad * math.cos(om * t), rad * math.sin(om * t), -10.0)
        vel = (-rad * om * math.sin(om * t) + err[0], rad * om * math.cos(om * t) + err[1], 0.0)
        tr.handle(T0_UNIX + t, lpn(100_000 + 1000 * k, pos, vel))
        if prev is not None and k > 30:
            _, p0 = prev
            _, p1, mean = means[-1]
            assert mean is not None
            chord = [-(p1[j] - p0[j]) for j in range(3)]  # -dp/dt, dt = 1 s
            # v = -u_measured = -(dp/dt + err): the drift (the velocity's error) stays in
            np.testing.assert_allclose(mean, [chord[j] - err[j] for j in range(3)], atol=0.05)
        prev = (t, pos)
    assert "position_reset" not in tr.events


def _home_orbit_at_10hz(velocity_error) -> tuple[Tracker, list]:
    """A vehicle circling its home point for 180 s with LOCAL_POSITION_NED at 10 Hz, its
    positions true and its velocity off them by ``velocity_error(t_s)`` (m/s, NED); bearings
    from the home source. Returns the tracker and every record."""
    tr = Tracker(TrackerConfig(sources=("home",)))
    tr.handle(T0_UNIX, _home(0.0, 0.0, 0.0))
    om, rad = 2 * math.pi / 30.0, 40.0
    recs = []
    for k in range(1800):
        t = 0.1 * k
        pos = (rad * math.cos(om * t) + 20.0, rad * math.sin(om * t), -15.0)
        e = velocity_error(t)
        vel = (-rad * om * math.sin(om * t) + e[0], rad * om * math.cos(om * t) + e[1], e[2])
        recs += tr.handle(T0_UNIX + t + 0.001, lpn(100_000 + 100 * k, pos, vel))
    recs += tr.flush()
    return tr, recs


def _wander(t_s: float) -> tuple[float, float, float]:
    """A constant plus a wander of 0.3 m/s over 50 s: a real EKF's velocity against its
    GNSS-held positions."""
    w = 0.3 * math.sin(2 * math.pi * t_s / 50.0)
    return (0.5 + w, -0.3 + w, 0.0)


def test_a_dense_stream_takes_the_displacement_from_the_position_too(monkeypatch) -> None:
    # at 10 Hz as at 1 Hz: the velocity's wander against the positions does not reach the
    # estimate (the positions are what the target is fixed against): over the last 60 s the
    # home point within 1 cm, converged
    _, recs = _home_orbit_at_10hz(_wander)
    off = max(float(np.linalg.norm(r.target_pos_ned_m)) for r in recs[-600:])
    assert off < 0.01 and recs[-1].estimate.status.value == "converged"
    # the same flight with the velocity integrated instead (no interval short enough for
    # the positions): the wander moves the estimated home by metres
    monkeypatch.setattr(drift, "SPARSE_VELOCITY_MAX_S", 0.05)
    _, recs = _home_orbit_at_10hz(_wander)
    off = max(float(np.linalg.norm(r.target_pos_ned_m)) for r in recs[-600:])
    assert off > 0.5 and recs[-1].estimate.status.value != "converged"


def test_the_bias_published_is_against_the_long_run_drift_not_the_first_second() -> None:
    # 10 Hz, the velocity 0.1 m/s white noise plus a constant (0.5, -0.3, 0) m/s error: the
    # drift handed to the observer is learnt over the first second (10 samples of that
    # noise), which its ``a`` takes up; the bias published is against every interval since
    rng = np.random.default_rng(1)
    err = np.array([0.5, -0.3, 0.0])
    tr, recs = _home_orbit_at_10hz(lambda t_s: err + rng.normal(0.0, 0.1, 3))
    first = tr.vehicles[1].drift.learnt_mps  # minus the velocity's error over the first second
    assert max(abs(first[j] + err[j]) for j in range(3)) > 0.03
    np.testing.assert_allclose(recs[-1].estimate.a_mps, err, atol=0.01)


def test_the_drift_is_learnt_from_the_first_interval_and_then_kept() -> None:
    # LOCAL_POSITION_NED at 1 Hz in a hover whose velocity is off its positions by a
    # constant plus 0.1 m/s of noise per sample (a real EKF's): the drift taken out of every
    # interval's mean is the same from the first interval on (a constant, which ``a`` takes
    # up), not a running mean that moves the velocity handed to the estimator each second
    rng = np.random.default_rng(7)
    tr = Tracker(TrackerConfig(sources=("home",)))
    drifts = []
    orig = tr._interval_mean_velocity

    def spy(veh, tb, pos, vel):
        out = orig(veh, tb, pos, vel)
        if out is not None:
            drifts.append([out[j] + (pos[j] - spy.p0[j]) for j in range(3)])  # mean + dp/dt
        spy.p0 = pos
        return out

    spy.p0 = None
    tr._interval_mean_velocity = spy  # type: ignore[method-assign]
    for k in range(20):
        pos = (0.3 * math.sin(0.2 * k), 0.2 * math.cos(0.3 * k), -3.0)
        vel = tuple(float(c) for c in np.array([2.0, -1.0, 0.0]) + rng.normal(0.0, 0.1, 3))
        tr.handle(T0_UNIX + k, lpn(100_000 + 1000 * k, pos, vel))
    assert len(drifts) == 19
    np.testing.assert_allclose(drifts, [drifts[0]] * len(drifts), atol=1e-12)
    assert "position_reset" not in tr.events


def test_a_position_jump_keeps_the_velocity_and_is_counted() -> None:
    tr = Tracker(TrackerConfig(sources=("home",)))
    for k in range(10):
        jump = 30.0 if k >= 6 else 0.0  # an EKF position reset
        tr.handle(T0_UNIX + k, lpn(100_000 + 1000 * k, (1.0 * k + jump, 0.0, -10.0)))
    assert tr.events["position_reset"] == 1


def test_a_velocity_off_the_position_for_seconds_is_no_position_reset() -> None:
    # LOCAL_POSITION_NED at 2 Hz, after 40 s of hover (the drift learnt: 0), climbing at
    # 1 m/s while its vertical velocity says 6 m/s for 5 s (an EKF whose velocity and height
    # disagree: a real log's climb): the intervals are 2.5 m off, above the 1.75 m gate, but
    # after the first none steps from the one before; the positions' displacement is kept (a
    # reset taken in such a climb cost one real log 2,700 % of range)
    tr = Tracker(TrackerConfig(sources=("home",)))
    means = []
    orig = tr._interval_mean_velocity

    def spy(veh, tb, pos, vel):
        out = orig(veh, tb, pos, vel)
        means.append(out)
        return out

    tr._interval_mean_velocity = spy  # type: ignore[method-assign]
    for k in range(120):
        t = 0.5 * k
        z = -10.0 - max(0.0, min(t, 45.0) - 40.0)
        vz = -6.0 if 40.0 < t <= 45.0 else 0.0
        tr.handle(T0_UNIX + t, lpn(100_000 + 500 * k, (0.0, 0.0, z), (0.0, 0.0, vz)))
    assert tr.events.get("position_reset", 0) <= 1  # the onset steps, the rest do not
    assert sum(m is None for m in means[1:]) <= 1


def _slow_attitude_flight(n: int = 60, attitude_until_ms: int | None = None) -> list:
    """ATTITUDE at 20 Hz with its yaw rate (30 deg/s), the gimbal 40 ms after each, arriving
    before the next ATTITUDE; LOCAL_POSITION_NED at 10 Hz."""
    msgs = []
    for i in range(n):
        ms = 100_000 + 50 * i
        y, r = steady_yaw((ms - 100_000) / 1000.0)
        if attitude_until_ms is None or ms <= attitude_until_ms:
            msgs.append(message("ATTITUDE", ms, 0.0, 0.0, math.remainder(y, 2 * math.pi),
                                0.0, 0.0, r))  # fmt: skip
        if i % 2 == 0:
            msgs.append(lpn(ms, (0.001 * (ms - 100_000), 0.0, -10.0)))
        tb = ms + 40
        yaw_rel = -steady_yaw((tb - 100_000) / 1000.0)[0]
        q = quat_about_z_then_pitch(math.radians(45.0) + yaw_rel, math.radians(-30.0))
        msgs.append(gimbal(tb, q=q, compid=154))
    return msgs


def test_bearings_waiting_when_the_stream_pauses_are_released_by_time() -> None:
    # the ATTITUDE stops and then everything does: the bearings past it wait; the clock
    # alone (the service's housekeeping) releases them once they have waited long enough
    tr = Tracker(TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    msgs = _slow_attitude_flight(attitude_until_ms=102_800)  # 0.15 s before the end
    recs = [r for m in msgs for r in tr.handle(T0_UNIX + m.time_boot_ms / 1000.0, m)]
    waiting = sum(len(v.waiting) for v in tr.vehicles.values())
    assert waiting == 4  # 40, 90, 140 and 190 ms past the last ATTITUDE
    last = T0_UNIX + msgs[-1].time_boot_ms / 1000.0
    assert tr.release_due(last + 0.05) == []  # not waited long enough yet
    released = tr.release_due(last + 1.0)
    assert len(released) == waiting and len(recs) + waiting == 60
    assert tr.events["attitude_extrapolated"] == 4


def test_a_target_that_moves_far_is_reacquired_and_the_event_counted() -> None:
    """Converged on a target 20 m ahead, then the gimbal follows another one 40 m to the
    side (a tracker that locked onto something else): the estimate starts again, the event
    is counted and logged, and the estimate ends near the new target."""
    tr = Tracker(TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    msgs = []
    for i in range(1200):  # 120 s at 10 Hz, a 20 m circle around the origin
        ms = 100_000 + 100 * i
        th = 2 * math.pi * i / 600
        p = (20.0 * math.cos(th), 20.0 * math.sin(th), -10.0)
        u = (-20.0 * math.sin(th) * 2 * math.pi / 60, 20.0 * math.cos(th) * 2 * math.pi / 60, 0.0)
        tgt = (0.0, 0.0, 0.0) if i < 600 else (0.0, 40.0, 0.0)
        d = [tgt[k] - p[k] for k in range(3)]
        yaw = math.atan2(d[1], d[0])
        pitch = math.atan2(-d[2], math.hypot(d[0], d[1]))
        q = (
            math.cos(yaw / 2) * math.cos(pitch / 2),
            -math.sin(yaw / 2) * math.sin(pitch / 2),
            math.cos(yaw / 2) * math.sin(pitch / 2),
            math.sin(yaw / 2) * math.cos(pitch / 2),
        )
        msgs += [att(ms), lpn(ms, p, u), gimbal(ms + 5, q=q, flags=FLAGS_VEHICLE | 0x10)]
    recs = feed(tr, msgs)
    assert tr.events["reacquired"] >= 1
    assert any(e == "reacquired" and t > 160.0 for t, _, e in tr.event_log)
    last = recs[-1]
    assert last.target_pos_ned_m is not None
    assert math.dist(last.target_pos_ned_m, (0.0, 40.0, 0.0)) < 2.0
    obs = tr.observer(1, "gimbal")
    assert obs is not None and obs.reacquisitions == tr.events["reacquired"]


HOME_LL = (-35.3629, 149.1651, 584.0)  # deg, deg, m AMSL


def _home(x: float, y: float, z: float, lat_lon_alt: tuple[float, float, float] = HOME_LL):
    lat, lon, alt = lat_lon_alt
    return message("HOME_POSITION", round(lat * 1e7), round(lon * 1e7), round(alt * 1e3),
                   x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)  # fmt: skip


def _gpi(ms: int, lat: float, lon: float, alt: float):
    return message("GLOBAL_POSITION_INT", ms, round(lat * 1e7), round(lon * 1e7),
                   round(alt * 1e3), 0, 0, 0, 0, 0)  # fmt: skip


def test_the_local_origin_from_home_position_and_its_move_is_counted() -> None:
    from mav_observer.geo.geodesy import to_geodetic

    tr = Tracker(TrackerConfig())
    tr.handle(T0_UNIX, lpn(100_000))
    tr.handle(T0_UNIX + 0.1, _home(12.0, -7.0, 1.5))
    o = tr.vehicles[1].origin
    assert o is not None and o.source == "HOME_POSITION"
    lat, lon, alt = to_geodetic(o, (12.0, -7.0, 1.5))  # the home, placed back
    assert (lat, lon) == pytest.approx(HOME_LL[:2], abs=2e-8)
    assert alt == pytest.approx(HOME_LL[2], abs=0.002)
    tr.handle(T0_UNIX + 0.2, _home(12.0, -7.0, 1.5))  # the same home again: nothing moves
    assert tr.vehicles[1].origin is o and "origin_changed" not in tr.events
    tr.handle(T0_UNIX + 0.3, _home(22.0, -7.0, 1.5))  # a new home 10 m north, same place
    assert tr.vehicles[1].origin is not o and tr.events["origin_changed"] == 1


def test_gps_global_origin_wins_and_global_position_pairs_with_local_position() -> None:
    # GLOBAL_POSITION_INT and LOCAL_POSITION_NED at the same time_boot_ms place the origin;
    # at different ones they do not; HOME_POSITION replaces it, GPS_GLOBAL_ORIGIN replaces
    # that, and neither lesser source moves it any more (the local frame told by the
    # settings: no pair is then needed to tell it)
    tr = Tracker(TrackerConfig(local_frame="wgs84"))
    tr.handle(T0_UNIX, lpn(100_000, (30.0, 40.0, -10.0)))
    tr.handle(T0_UNIX + 0.05, _gpi(100_050, *HOME_LL))
    assert tr.vehicles[1].origin is None
    tr.handle(T0_UNIX + 0.1, _gpi(100_100, *HOME_LL))
    tr.handle(T0_UNIX + 0.1, lpn(100_100, (30.0, 40.0, -10.0)))
    o = tr.vehicles[1].origin
    assert o is not None and o.source == "GLOBAL_POSITION_INT"
    assert o.alt_m == pytest.approx(HOME_LL[2] - 10.0, abs=0.01)  # the vehicle 10 m up
    gpi_id = _gpi(1, *HOME_LL).get_msgId()
    assert gpi_id not in tr.redundant_message_ids()  # it places the origin: still decoded
    tr.handle(T0_UNIX + 0.2, _home(0.0, 0.0, 0.0))
    assert tr.vehicles[1].origin.source == "HOME_POSITION"
    ggo = message("GPS_GLOBAL_ORIGIN", -353600000, 1491600000, 580_000)
    tr.handle(T0_UNIX + 0.3, ggo)
    o = tr.vehicles[1].origin
    assert (o.source, o.lat_deg, o.lon_deg, o.alt_m) == ("GPS_GLOBAL_ORIGIN", -35.36, 149.16, 580.0)
    assert gpi_id in tr.redundant_message_ids()  # a better origin: no need to decode it
    tr.handle(T0_UNIX + 0.4, _home(5.0, 5.0, 0.0))
    tr.handle(T0_UNIX + 0.5, _gpi(100_500, -35.0, 149.0, 100.0))
    tr.handle(T0_UNIX + 0.5, lpn(100_500, (30.0, 40.0, -10.0)))
    assert tr.vehicles[1].origin is o and tr.events["origin_changed"] == 2


def test_global_position_pairs_are_averaged_into_the_origin() -> None:
    # GLOBAL_POSITION_INT rounds to 1e-7 deg (about 1 cm): one pair puts the origin
    # millimetres off for the whole flight; 300 pairs along a 50 m circle, averaged, within a
    # millimetre, and no pair counts as a move
    import pymap3d

    lat0, lon0, alt0 = -35.36326123, 149.16523047, 584.0
    tr = Tracker(TrackerConfig())
    for k in range(300):
        ms = 100_000 + 100 * k
        ned = (50.0 * math.cos(0.02 * k), 50.0 * math.sin(0.02 * k), -20.0 - 0.013 * k)
        tr.handle(T0_UNIX + 0.1 * k, _gpi(ms, *pymap3d.ned2geodetic(*ned, lat0, lon0, alt0)))
        tr.handle(T0_UNIX + 0.1 * k, lpn(ms, ned))
        if k == 0:
            first = tr.vehicles[1].origin
    o = tr.vehicles[1].origin
    assert o.source == "GLOBAL_POSITION_INT" and "origin_changed" not in tr.events
    n, e, d = pymap3d.geodetic2ned(o.lat_deg, o.lon_deg, o.alt_m, lat0, lon0, alt0)
    n1, e1, _ = pymap3d.geodetic2ned(first.lat_deg, first.lon_deg, first.alt_m, lat0, lon0, alt0)
    assert math.hypot(n1, e1) > 0.002  # the first pair alone
    assert math.hypot(n, e) < 0.001 and abs(d) < 0.0005


def _flight_pairs(tr: Tracker, place, n: int = 80, t0: float = T0_UNIX) -> None:
    """GLOBAL_POSITION_INT and LOCAL_POSITION_NED pairs along a 50 m circle, each local point
    placed on the map by ``place(lat0, lon0, alt0, ned)`` from the origin (-35.363261,
    149.1652299, 584.08) and rounded as MAVLink rounds it."""
    for k in range(n):
        ms = 100_000 + 100 * k
        ned = (50.0 * math.sin(0.04 * k), 50.0 * (1.0 - math.cos(0.04 * k)), -20.0)
        tr.handle(t0 + 0.1 * k, _gpi(ms, *place(-35.363261, 149.1652299, 584.08, ned)))
        tr.handle(t0 + 0.1 * k, lpn(ms, ned))


def _ardupilot_place(lat0, lon0, alt0, ned):
    # ArduPilot's Location::offset, written from its source (libraries/AP_Common/Location.cpp)
    dlat_e7 = ned[0] / 0.011131884502145034
    scale = max(math.cos(math.radians(lat0 + 0.5e-7 * dlat_e7)), 0.01)
    return lat0 + 1e-7 * dlat_e7, lon0 + 1e-7 * ned[1] / 0.011131884502145034 / scale, alt0 - ned[2]


def _px4_place(lat0, lon0, alt0, ned):
    # PX4's MapProjection::reproject (src/lib/geo), on its sphere of 6,371,000 m
    x, y = ned[0] / 6371000.0, ned[1] / 6371000.0
    c = math.hypot(x, y)
    if c == 0.0:
        return lat0, lon0, alt0 - ned[2]
    p0, l0 = math.radians(lat0), math.radians(lon0)
    lat = math.asin(math.cos(c) * math.sin(p0) + x * math.sin(c) * math.cos(p0) / c)
    lon = l0 + math.atan2(
        y * math.sin(c), c * math.cos(p0) * math.cos(c) - x * math.sin(p0) * math.sin(c)
    )
    return math.degrees(lat), math.degrees(lon), alt0 - ned[2]


def _wgs84_place(lat0, lon0, alt0, ned):
    import pymap3d

    return tuple(float(v) for v in pymap3d.ned2geodetic(*ned, lat0, lon0, alt0))


@pytest.mark.parametrize(
    ("place", "frame"),
    [(_ardupilot_place, "ardupilot"), (_px4_place, "px4"), (_wgs84_place, "wgs84")],
)
@pytest.mark.parametrize("origin_from", ["GLOBAL_POSITION_INT", "GPS_GLOBAL_ORIGIN"])
def test_the_pairs_tell_the_autopilots_local_frame(place, frame, origin_from) -> None:
    # the origin on the WGS84 ellipsoid until the vehicle has flown 30 m; then its own
    # GLOBAL_POSITION_INT and LOCAL_POSITION_NED pairs say which frame it maps them by, the
    # origin is placed again on it, and a point 40 m north and 30 m east of it lands where
    # the autopilot would place it (ArduPilot's: the SITL log's ROI, within 2 mm)
    from mav_observer.geo.geodesy import to_geodetic

    tr = Tracker(TrackerConfig())
    if origin_from == "GPS_GLOBAL_ORIGIN":
        tr.handle(T0_UNIX, message("GPS_GLOBAL_ORIGIN", -353632610, 1491652299, 584_080))
    gpi_id = _gpi(1, *HOME_LL).get_msgId()
    _flight_pairs(tr, place, n=4)
    assert tr.vehicles[1].origin.frame == "wgs84" and tr.vehicles[1].local_frame is None
    assert gpi_id not in tr.redundant_message_ids()  # still needed: the frame is not told
    _flight_pairs(tr, place, n=80)
    veh = tr.vehicles[1]
    assert veh.local_frame == frame and tr.events[f"local_frame_{frame}"] == 1
    assert veh.origin.frame == frame and veh.origin.source == origin_from
    assert tr.origin(1)["frame"] == frame and "origin_changed" not in tr.events
    want = place(-35.363261, 149.1652299, 584.08, (40.0, 30.0, 0.0))
    lat, lon, _ = to_geodetic(veh.origin, (40.0, 30.0, 0.0))
    gap_m = math.hypot(
        math.radians(lat - want[0]) * 6.371e6,
        math.radians(lon - want[1]) * 6.371e6 * math.cos(math.radians(lat)),
    )
    assert gap_m < 0.003, gap_m
    if frame == "ardupilot":
        assert (lat, lon) == pytest.approx((-35.362901673886356, 149.16556036583896), abs=3e-8)
    if origin_from == "GPS_GLOBAL_ORIGIN":
        assert gpi_id in tr.redundant_message_ids()  # told, and a better origin: not needed


def test_a_local_frame_set_is_not_voted_on() -> None:
    tr = Tracker(TrackerConfig(local_frame="px4"))
    _flight_pairs(tr, _ardupilot_place, n=80)
    assert tr.vehicles[1].origin.frame == "px4" and tr.vehicles[1].frame_vote is None
    assert not any(k.startswith("local_frame_") for k in tr.events)


def test_a_bad_local_frame_setting_is_refused_naming_it() -> None:
    with pytest.raises(ConfigError, match=r"local_frame must be .* got 'utm'"):
        TrackerConfig(local_frame="utm")


def test_an_impossible_origin_is_skipped_and_counted() -> None:
    tr = Tracker(TrackerConfig())
    tr.handle(T0_UNIX, message("GPS_GLOBAL_ORIGIN", 950_000_000, 0, 0))  # latitude 95 deg
    assert tr.vehicles[1].origin is None
    assert tr.skipped["out_of_range"] == 1


def test_a_better_source_at_the_same_place_is_no_origin_change() -> None:
    # GLOBAL_POSITION_INT places the origin; HOME_POSITION then says the same: a better
    # source, the origin kept in place, nothing counted as a move
    tr = Tracker(TrackerConfig())
    tr.handle(T0_UNIX, _gpi(100_000, *HOME_LL))
    tr.handle(T0_UNIX, lpn(100_000, (0.0, 0.0, 0.0)))
    assert tr.vehicles[1].origin.source == "GLOBAL_POSITION_INT"
    tr.handle(T0_UNIX + 0.1, _home(0.0, 0.0, 0.0))
    assert tr.vehicles[1].origin.source == "HOME_POSITION"
    assert "origin_changed" not in tr.events


def _rocking_flight(servo: bool, n: int = 200):
    """A vehicle flying north at 1 m/s and rocking (roll and pitch up to 9 and 6 deg), its
    camera held on a point at (30, 10, 0) m NED: a gimbal that reports horizon-relative
    angles (``servo=False``) or a servo mount that reports its body angles under the same
    flags (ArduPilot's MNT1_TYPE 1)."""
    from mav_observer.geo.frames import euler_from_dcm, euler_to_dcm, quat_from_euler

    target = np.array([30.0, 10.0, 0.0])
    msgs = []
    for i in range(n):
        ms, t = 100_000 + 100 * i, 0.1 * i
        roll, pitch, yaw = 0.15 * math.sin(1.2 * t), 0.1 * math.sin(0.8 * t + 1.0), 0.3
        pos = np.array([0.1 * i, 0.0, -10.0])
        los = (target - pos) / np.linalg.norm(target - pos)
        el, az = math.asin(-los[2]), math.atan2(los[1], los[0])
        if servo:
            r_cam = np.array(euler_to_dcm(0.0, el, az))
            q = quat_from_euler(*euler_from_dcm(np.array(euler_to_dcm(roll, pitch, yaw)).T @ r_cam))
        else:
            q = quat_from_euler(0.0, el, az - yaw)
        msgs += [
            message("ATTITUDE", ms, roll, pitch, yaw, 0.0, 0.0, 0.0),
            lpn(ms, tuple(pos)),
            gimbal(ms + 5, q=q),
        ]
    return msgs, target


@pytest.mark.parametrize("servo", [False, True])
def test_the_gimbals_frame_is_told_from_the_vehicles_tilt(servo: bool) -> None:
    msgs, target = _rocking_flight(servo)
    tr = Tracker()
    recs = feed(tr, msgs)
    assert tr.gimbal_angles(1) == {1: "body" if servo else "flags"}
    assert tr.events[f"gimbal_angles_{'body' if servo else 'flags'}"] == 1
    # read right, the last bearings point at the target
    last = recs[-1]
    pos = np.array([0.1 * 199, 0.0, -10.0])
    los = (target - pos) / np.linalg.norm(target - pos)
    y = last.estimate.x_m / np.linalg.norm(last.estimate.x_m)
    assert math.degrees(math.acos(min(1.0, float(y @ los)))) < 3.0
    told = Tracker(TrackerConfig(gimbal_angles="flags"))
    feed(told, msgs)
    assert told.gimbal_angles(1) == {} and "gimbal_angles_body" not in told.events


def test_a_gimbal_reading_found_from_the_data_survives_a_restart() -> None:
    msgs, _ = _rocking_flight(servo=True)
    tr = Tracker()
    feed(tr, msgs)
    saved = tr.export_state()
    assert [e.get("gimbal_angles") for e in saved if e["target"] == "gimbal"] == ["body"]
    tr2 = Tracker()
    tr2.restore(saved)
    level = flight(n=20, boot0=120_000)  # no tilt: nothing to decide from
    feed(tr2, level, boot0_ms=120_000)
    assert tr2.gimbal_angles(1) == {1: "body"}  # read so from its first message
    assert "gimbal_angles_body" not in tr2.events
    bad = [dict(saved[0], gimbal_angles="sideways")]
    with pytest.raises(StateError, match=r"observers\[0\]\.gimbal_angles"):
        Tracker().restore(bad)


# -- committed publishing (replay's default) ---------------------------------------


def _sparse_flight(n_s: int = 30) -> list:
    """A vehicle flying north at 1 m/s with LOCAL_POSITION_NED at 1 Hz, attitude and gimbal
    (45 deg down) at 10 Hz."""
    msgs = []
    for i in range(10 * n_s):
        ms = 100_000 + 100 * i
        msgs.append(att(ms))
        if i % 10 == 0:
            msgs.append(lpn(ms, (0.1 * i, 0.0, -10.0)))
        msgs.append(gimbal(ms + 5))
    return msgs


def test_committed_records_come_once_the_velocity_after_them_is_in() -> None:
    """``publish = "committed"``: one record per bearing, as live, but each once the
    LOCAL_POSITION_NED after it has arrived (the last second's at the end, from ``flush``),
    with its bearing's arrival time and the vehicle's position: the LOCAL_POSITION_NED at or
    before it moved on the way the estimate was (the velocity, 1 m/s north, less the
    estimated bias ``a``: the vehicle's error where the target stands still)."""
    msgs = _sparse_flight()
    live = feed(Tracker(), msgs)
    tr = Tracker(TrackerConfig(publish="committed"))
    out, when = [], []
    for m in msgs:
        ms = getattr(m, "time_boot_ms", None)
        recs = tr.handle(T0_UNIX + (ms - 100_000) / 1000.0 + 0.01, m)
        when += [(r.t_boot_s, m.get_type(), ms) for r in recs]
        out += recs
    tail = tr.flush()
    assert [r.t_boot_s for r in out + tail] == [r.t_boot_s for r in live]
    # a bearing's record waits for the next second's position: published by a later message
    assert all(t < ms / 1000.0 for t, _, ms in when)
    assert max(ms / 1000.0 - t for t, _, ms in when) < 1.0 + 0.1  # at most one interval
    assert all(math.floor(r.t_boot_s) == 129 for r in tail) and len(tail) == 10
    for r in out + tail:
        assert r.t_unix_s == pytest.approx(T0_UNIX + r.t_boot_s - 100.0 + 0.01)
        t_fix = math.floor(r.t_boot_s)  # the second's LOCAL_POSITION_NED
        dt = r.t_boot_s - t_fix
        a = r.estimate.a_mps.tolist()
        expected = (t_fix - 100.0 + (1.0 - a[0]) * dt, -a[1] * dt, -10.0 - a[2] * dt)
        assert r.vehicle_pos_ned_m == pytest.approx(expected, abs=1e-9)


def test_publish_names_a_bad_value() -> None:
    with pytest.raises(ConfigError, match="publish must be one of"):
        TrackerConfig(publish="later")


def _hovering(orientation: int, compid: int = 154, n: int = 40):
    """A vehicle hovering 10 m up, yaw north, its gimbal 45 deg down, and a DISTANCE_SENSOR of
    14.14 m (the target 10 m north on the ground) before each gimbal message."""
    msgs = []
    for i in range(n):
        ms = 100_000 + 100 * i
        ds = message("DISTANCE_SENSOR", ms + 4, 10, 20000, 1414, 0, 1, orientation, 255,
                     compid=compid)  # fmt: skip
        msgs += [att(ms), lpn(ms, (0.0, 0.0, -10.0), (0.0, 0.0, 0.0)), ds, gimbal(ms + 5)]
    return msgs


def test_a_rangefinder_on_the_gimbal_is_fused_a_downward_one_is_not() -> None:
    """A DISTANCE_SENSOR of orientation MAV_SENSOR_ROTATION_CUSTOM (or from a gimbal's
    component) measures along the gimbal's bearing: the hovering vehicle's target is found at
    once; the vehicle's own downward rangefinder (orientation 25) says nothing about it."""
    on_gimbal = feed(Tracker(), _hovering(orientation=100, compid=1))
    assert on_gimbal[-1].estimate.range_m == pytest.approx(14.14, abs=0.05)
    assert on_gimbal[-1].estimate.status == "converged"
    by_comp = feed(Tracker(), _hovering(orientation=0, compid=154))
    assert by_comp[-1].estimate.range_m == pytest.approx(14.14, abs=0.05)
    tr = Tracker()
    downward = feed(tr, _hovering(orientation=25, compid=1))
    assert downward[-1].estimate.status != "converged"
    assert abs(downward[-1].estimate.range_m - 14.14) > 1.0 and tr.skipped == {}
