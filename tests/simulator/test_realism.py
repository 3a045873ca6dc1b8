"""The realism stage between the emitter and the reader (sim/realism.py): each knob does what
it says, measured on what a reader receives."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mav_observer.core.observer import ObserverConfig
from mav_observer.mavlink.dialect import MSG_ID, codec
from mav_observer.tracking.tracker import Tracker, TrackerConfig
from sim import emitter as em
from sim import realism, scenarios

pytestmark = pytest.mark.slow  # whole flights, loopback services or the end-to-end harness

DEC = codec()
GIMBAL = MSG_ID["GIMBAL_DEVICE_ATTITUDE_STATUS"]
ATT = MSG_ID["ATTITUDE"]
LPN = MSG_ID["LOCAL_POSITION_NED"]


def emissions(duration_s=20.0, vehicle=None, **cfg):
    sc = scenarios.orbit(duration_s=duration_s)
    conf = em.EmitterConfig(duration_s=duration_s, **cfg)
    return em.Emitter(sc, conf, vehicle), conf


def received(link: realism.Realism, duration_s=20.0, **cfg):
    e, conf = emissions(duration_s, **cfg)
    return link.apply(e.emissions(), conf.t0_unix_s), conf


def decoded(arrivals, mid):
    return [(a, DEC.decode(bytearray(a.frame))) for a in arrivals if realism.msgid(a.frame) == mid]


def test_no_knob_changes_nothing() -> None:
    e, conf = emissions()
    ideal = list(e.emissions())
    got = realism.Realism().apply(ideal, conf.t0_unix_s)
    assert [a.frame for a in got] == [x.frame for x in ideal]
    assert [a.t_arrival_s for a in got] == [x.t_emit_s for x in ideal]


def test_latency_and_jitter_let_bearings_arrive_before_the_attitude_of_their_time() -> None:
    fast = {"attitude_hz": 50.0, "bearing_hz": 25.0}
    link = realism.Realism(bearing_latency_s=0.005, jitter_s=0.03, seed=1)

    def order(arrivals):
        """Shares of the bearings that arrive before the ATTITUDE just before their time,
        and after the one just after it."""
        att = np.array(sorted(m.time_boot_ms for _, m in decoded(arrivals, ATT)))
        latest, before, after, n = -1, 0, 0, 0
        for a in arrivals:
            mid = realism.msgid(a.frame)
            if mid == ATT:
                latest = max(latest, DEC.decode(bytearray(a.frame)).time_boot_ms)
            elif mid == GIMBAL:
                n += 1
                stamp = DEC.decode(bytearray(a.frame)).time_boot_ms
                prev = att[np.searchsorted(att, stamp, side="right") - 1]
                nxt = att[min(np.searchsorted(att, stamp, side="right"), len(att) - 1)]
                before += latest < prev
                after += latest >= nxt
        return before / n, after / n

    plain, _ = received(realism.Realism(), **fast)
    jittered, _ = received(link, **fast)
    assert order(plain) == (0.0, 0.0)
    before, after = order(jittered)
    assert 0.05 < before < 0.6 and 0.05 < after < 0.6
    # each stream keeps its order (first in, first out per sender)
    for mid in (ATT, GIMBAL, LPN):
        stamps = [m.time_boot_ms for _, m in decoded(jittered, mid)]
        assert stamps == sorted(stamps)
    t = [a.t_arrival_s for a in jittered]
    assert t == sorted(t)


def test_a_component_clock_with_offset_and_drift_is_what_the_reader_recovers() -> None:
    link = realism.Realism(
        component_id=154, component_boot_offset_s=3.7, component_clock_drift_ppm=40.0, seed=2
    )
    arrivals, conf = received(link, duration_s=120.0, attitude_hz=50.0, bearing_hz=25.0)
    gim = decoded(arrivals, GIMBAL)
    assert {m.get_srcComponent() for _, m in gim} == {154}
    t_true = np.array([a.truth["t_boot_s"] for a, _ in gim])
    stamp = np.array([m.time_boot_ms / 1000 for _, m in gim])
    slope, offset = np.polyfit(t_true, stamp, 1)
    assert (slope - 1) * 1e6 == pytest.approx(40.0, abs=1.0)  # ppm
    assert offset == pytest.approx(3.7, abs=0.002)
    # the reader maps that clock back onto the autopilot's, drift included
    tr = Tracker(TrackerConfig(observer=ObserverConfig(initial_range_m=20.0)))
    recs = []
    for a in arrivals:
        recs += tr.handle(a.t_tlog_unix_s, DEC.decode(bytearray(a.frame)))
    recs += tr.flush()
    truth_t = set(np.round(t_true, 3))
    assert len(recs) > 0.95 * len(gim)
    late = [r for r in recs if r.t_boot_s > conf.boot_at_start_s + 60.0]
    err = [min(abs(r.t_boot_s - t) for t in (round(r.t_boot_s, 3),)) for r in late]
    assert max(err) < 0.005
    assert all(round(r.t_boot_s, 2) in {round(t, 2) for t in truth_t} for r in late)


def test_yaw_swing_adds_a_sine_to_the_yaw_and_its_peak_rate() -> None:
    sc = scenarios.orbit(duration_s=20.0)
    base = realism.SwingVehicle(sc)
    swing = realism.SwingVehicle(sc, yaw_swing_deg=57.0, yaw_swing_period_s=6.0)
    t = np.arange(0.0, 20.0, 0.01)
    d = np.array([math.remainder(swing.state(x).yaw - base.state(x).yaw, 2 * math.pi) for x in t])
    # the heading swings by the sine (the Euler yaw of the tilted body within 0.05 deg)
    np.testing.assert_allclose(d, np.radians(57.0) * np.sin(2 * np.pi * t / 6.0), atol=1e-3)
    rate = np.degrees(np.max(np.abs(np.diff(d) / 0.01)))
    assert rate == pytest.approx(2 * math.pi * 57.0 / 6.0, rel=0.02)  # 60 deg/s


def test_velocity_error_gauss_markov_and_constant() -> None:
    bias = (0.3, -0.2, 0.1)
    link = realism.Realism(
        velocity_gm_std_mps=0.1, velocity_gm_tau_s=5.0, velocity_bias_ned_mps=bias, seed=3
    )
    ideal, _conf = received(realism.Realism(), duration_s=600.0, position_hz=5.0)
    noisy, _ = received(link, duration_s=600.0, position_hz=5.0)
    a = np.array([(m.vx, m.vy, m.vz) for _, m in decoded(ideal, LPN)])
    b = np.array([(m.vx, m.vy, m.vz) for _, m in decoded(noisy, LPN)])
    p_a = np.array([(m.x, m.y, m.z) for _, m in decoded(ideal, LPN)])
    p_b = np.array([(m.x, m.y, m.z) for _, m in decoded(noisy, LPN)])
    np.testing.assert_allclose(p_a, p_b, atol=1e-4)  # positions stay true
    err = b - a
    np.testing.assert_allclose(err.mean(axis=0), bias, atol=0.03)
    gm = err - err.mean(axis=0)
    assert np.std(gm, axis=0) == pytest.approx([0.1] * 3, rel=0.25)
    lag1 = np.mean([np.corrcoef(gm[:-1, j], gm[1:, j])[0, 1] for j in range(3)])
    assert lag1 == pytest.approx(math.exp(-0.2 / 5.0), abs=0.02)
    # the constant joins the truth's a: x' = -u_true = v + a with v = -u_measured
    t_ideal = next(x.truth for x in ideal if x.truth)
    t_noisy = next(x.truth for x in noisy if x.truth)
    np.testing.assert_allclose(
        np.array(t_noisy["bias_ned_mps"]) - t_ideal["bias_ned_mps"], bias, atol=1e-12
    )


def test_the_truths_a_integrates_the_measured_velocity_to_the_truths_position() -> None:
    # x(t1) - x(t0) = integral of (v + a), v = -u from LOCAL_POSITION_NED: the sign of the
    # constant velocity error in the truth
    link = realism.Realism(velocity_bias_ned_mps=(0.5, -0.4, 0.0), seed=4)
    arrivals, _ = received(link, duration_s=30.0, position_hz=50.0, bearing_hz=10.0)
    lpn = [(m.time_boot_ms / 1000, np.array([m.vx, m.vy, m.vz])) for _, m in decoded(arrivals, LPN)]
    truth = [a.truth for a in arrivals if a.truth]
    t0, t1 = truth[10], truth[-10]
    a = np.array(t0["bias_ned_mps"])
    t = np.array([x[0] for x in lpn])
    u = np.array([x[1] for x in lpn])
    grid = np.linspace(t0["t_boot_s"], t1["t_boot_s"], 20_001)
    ug = np.column_stack([np.interp(grid, t, u[:, j]) for j in range(3)])
    integral = np.trapezoid(-ug, grid, axis=0)
    dx = np.array(t1["rel_pos_ned_m"]) - np.array(t0["rel_pos_ned_m"])
    np.testing.assert_allclose(dx, integral + a * (t1["t_boot_s"] - t0["t_boot_s"]), atol=0.05)


def test_gimbal_lag_makes_the_boresight_follow_the_line_of_sight_late() -> None:
    from mav_observer.tracking import directions as adapters

    lag = 0.5
    arrivals, _ = received(realism.Realism(gimbal_lag_s=lag), duration_s=40.0, bearing_hz=20.0)
    err_now, err_lagged, turned = [], [], []
    los_hist = []
    for a, m in decoded(arrivals, GIMBAL):
        x = np.array(a.truth["rel_pos_ned_m"])
        los = x / np.linalg.norm(x)
        los_hist.append((a.truth["t_boot_s"], los))
        b = np.array(
            adapters.gimbal_boresight(
                tuple(m.q), m.flags, 0, vehicle_yaw=a.truth["attitude_rpy_rad"][2]
            )
        )
        if a.truth["t_boot_s"] - los_hist[0][0] < 5.0:
            continue  # the lag settles
        # a first-order lag trails a steadily turning line of sight by its time constant
        t_back = a.truth["t_boot_s"] - lag
        old = min(los_hist, key=lambda h: abs(h[0] - t_back))[1]
        err_now.append(math.degrees(math.acos(min(1.0, float(b @ los)))))
        err_lagged.append(math.degrees(math.acos(min(1.0, float(b @ old)))))
        turned.append(math.degrees(math.acos(min(1.0, float(los @ old)))))
    # the orbit turns the line of sight by 3.7 deg in 0.5 s: the boresight is that far behind
    assert np.median(err_now) == pytest.approx(np.median(turned), rel=0.1)
    assert np.median(turned) > 3.0
    assert np.median(err_lagged) < 0.3  # (a first-order lag also shrinks the arc a little)


def test_dropout_bursts_silence_the_bearings() -> None:
    link = realism.Realism(dropout_every_s=10.0, dropout_length_s=3.0, seed=5)
    full, _ = received(realism.Realism(), duration_s=100.0)
    cut, _ = received(link, duration_s=100.0)
    n_full = len(decoded(full, GIMBAL))
    t = np.array([a.t_arrival_s for a, _ in decoded(cut, GIMBAL)])
    assert len(t) == pytest.approx(0.7 * n_full, rel=0.05)
    gaps = np.diff(t)
    assert np.sum(gaps > 2.9) >= 9  # one 3 s silence per 10 s
    assert len(decoded(cut, ATT)) == len(decoded(full, ATT))  # only bearings are lost


def test_the_tlogs_own_clock_jitters_and_jumps(tmp_path: Path) -> None:
    link = realism.Realism(tlog_jitter_s=0.03, tlog_jumps=((10.0, 500.0), (15.0, -200.0)), seed=6)
    arrivals, conf = received(link, duration_s=20.0)
    off = np.array([a.t_tlog_unix_s - conf.t0_unix_s - a.t_arrival_s for a in arrivals])
    t = np.array([a.t_arrival_s for a in arrivals])
    before, mid, after = t < 10.0, (t >= 10.0) & (t < 15.0), t >= 15.0
    assert off[before].min() >= 0.0 and off[before].max() <= 0.03
    assert off[mid].min() >= 500.0 and off[mid].max() <= 500.03
    assert off[after].min() >= 300.0 and off[after].max() <= 300.03
    n = realism.write(arrivals, tlog=tmp_path / "j.tlog", truth=tmp_path / "j.jsonl")
    assert n == len(arrivals) and (tmp_path / "j.tlog").stat().st_size > 0


def test_bad_knobs_are_errors_naming_them() -> None:
    with pytest.raises(ValueError, match="jitter_s"):
        realism.Realism(jitter_s=-1.0)
    with pytest.raises(ValueError, match="dropout_length_s"):
        realism.Realism(dropout_every_s=5.0, dropout_length_s=6.0)
    with pytest.raises(ValueError, match="gimbal_lag_s"):
        realism.Realism(gimbal_lag_s=-0.1)
    with pytest.raises(ValueError, match="component_id"):
        realism.Realism(component_id=300)
