"""The sample streams (mav_observer/core/kernels/streams.py): checks on arrival (through the
observer), interpolation, holding, the positions' interval means and a sparse stream's
trend, breakpoints, the data horizon, trimming; the prediction past the data."""

from __future__ import annotations

import math

import kernel_calls as kc
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer import BiasObserver, InvalidSampleError, ObserverConfig


def test_a_sample_before_the_previous_one_is_refused_naming_both_times() -> None:
    obs = BiasObserver()
    obs.update_velocity_values(1.0, [0.0, 0.0, 0.0])
    with pytest.raises(InvalidSampleError, match=r"velocity t_s=0.5 .* t_s=1.0"):
        obs.update_velocity_values(0.5, [0.0, 0.0, 0.0])
    obs.update_bearing_values(2.0, [1.0, 0.0, 0.0])
    with pytest.raises(InvalidSampleError, match=r"bearing t_s=1.5 .* t_s=2.0"):
        obs.update_bearing_values(1.5, [1.0, 0.0, 0.0])
    assert obs.counts == {"velocity": 1, "bearing": 1}


def test_a_bearing_older_than_the_committed_time_is_refused_a_velocity_is_not() -> None:
    """A bearing at 0 s and velocities to 3 s: the bearing is stale after 2 s, the state is
    committed through the velocities; a bearing at 1 s (after the previous one) comes too
    late. The other way round a velocity at 1 s is still taken (it is after the previous
    velocity sample)."""
    obs = BiasObserver()
    obs.update_bearing_values(0.0, [1.0, 0.0, 0.0])
    for t in (0.0, 1.0, 2.0, 3.0):
        obs.update_velocity_values(t, [0.0, 0.0, 0.0])
    assert obs.committed_t_s == 3.0
    with pytest.raises(InvalidSampleError, match="older than the observer's committed time"):
        obs.add_bearing_values(1.0, [1.0, 0.0, 0.0])
    assert obs.counts == {"velocity": 4, "bearing": 1}
    late = BiasObserver(ObserverConfig(max_velocity_wait_s=1.5))
    late.update_velocity_values(0.0, [0.0, 0.0, 0.0])
    for t in (0.0, 1.0, 2.0, 3.0):
        late.update_bearing_values(t, [1.0, 0.0, 0.0])
    assert late.committed_t_s == 3.0
    late.update_velocity_values(1.0, [0.0, 0.0, 0.0])
    assert late.counts == {"velocity": 2, "bearing": 4}


def test_the_velocity_interval_is_the_latest_one_at_most_a_second() -> None:
    s = kc.Streams()
    assert s.velocity_dt_s == 0.05
    s.append_velocity(0.0, [0.0, 0.0, 0.0])
    s.append_velocity(0.2, [0.0, 0.0, 0.0])
    assert s.velocity_dt_s == pytest.approx(0.2)
    s.append_velocity(5.0, [0.0, 0.0, 0.0])
    assert s.velocity_dt_s == 1.0


def test_a_bearing_is_interpolated_along_the_chord_and_held_until_it_expires() -> None:
    s = kc.Streams()
    s.append_bearing(0.0, [1.0, 0.0, 0.0])
    s.append_bearing(1.0, [0.0, 1.0, 0.0])
    assert s.bearing_at(0.5) == pytest.approx([math.sqrt(0.5), math.sqrt(0.5), 0.0])
    y = s.bearing_at(0.25)
    assert y is not None and np.linalg.norm(y) == pytest.approx(1.0)
    assert y == pytest.approx(np.array([0.75, 0.25, 0.0]) / math.hypot(0.75, 0.25))
    assert s.bearing_at(2.9) == [0.0, 1.0, 0.0]  # held for max_bearing_age_s
    assert s.bearing_at(3.1) is None
    assert s.bearing_at(-0.1) is None
    far = kc.Streams()  # samples further apart than the age: the earlier held, then none
    far.append_bearing(0.0, [1.0, 0.0, 0.0])
    far.append_bearing(5.0, [0.0, 1.0, 0.0])
    assert far.bearing_at(1.0) == [1.0, 0.0, 0.0]
    assert far.bearing_at(3.0) is None


def test_hold_interpolation_holds_each_sample_to_the_next() -> None:
    s = kc.Streams(linear=False)
    s.append_bearing(0.0, [1.0, 0.0, 0.0])
    s.append_bearing(1.0, [0.0, 1.0, 0.0])
    assert s.bearing_at(0.9) == [1.0, 0.0, 0.0]
    s.append_velocity(0.0, [0.0, 0.0, 0.0])
    s.append_velocity(1.0, [2.0, 0.0, 0.0])
    assert s.velocity_at(0.9) == [0.0, 0.0, 0.0]
    linear = kc.Streams()
    linear.append_velocity(0.0, [0.0, 0.0, 0.0])
    linear.append_velocity(1.0, [2.0, 0.0, 0.0])
    assert linear.velocity_at(0.9) == pytest.approx([1.8, 0.0, 0.0])
    assert linear.velocity_at(-1.0) == [0.0, 0.0, 0.0]  # the first held backwards
    assert linear.velocity_at(9.0) == [2.0, 0.0, 0.0]  # the latest held


def test_an_interval_mean_shifts_the_interpolated_velocity_to_the_positions_mean() -> None:
    s = kc.Streams()
    s.append_velocity(0.0, [0.0, 0.0, 0.0])
    s.append_velocity(1.0, [2.0, 0.0, 0.0])
    assert s.velocity_at(0.5) == pytest.approx([1.0, 0.0, 0.0])
    assert not s.chord_at(0.5)
    s.set_interval_mean(1.0, [1.5, 0.0, 0.0])
    assert s.chord_at(0.5)
    # the samples' shape (a ramp) shifted by 0.5 so its mean is the positions' 1.5
    assert s.velocity_at(0.25) == pytest.approx([1.0, 0.0, 0.0])
    assert s.predicted_displacement(0.0, 1.0) == pytest.approx([1.5, 0.0, 0.0])


def _sparse(accel_mps2: list[float], dt_s: float = 1.0) -> kc.Streams:
    """A 1-axis stream whose every interval's mean is known, its acceleration over each
    interval ``accel_mps2[k]`` (velocity samples and means exact)."""
    s = kc.Streams(n=1)
    v, t = 5.0, 0.0
    s.append_velocity(t, [v])
    for acc in accel_mps2:
        v1 = v + acc * dt_s
        t += dt_s
        s.append_velocity(t, [v1])
        s.set_interval_mean(t, [0.5 * (v + v1)])
        s.trim(t - dt_s)  # (as the observer keeps it: the anchor and the one before)
        v = v1
    return s


def test_a_dense_stream_has_no_extrapolation_variance() -> None:
    s = kc.Streams()
    for k in range(5):
        s.append_velocity(0.1 * k, [1.0, 0.0, 0.0])
    assert not s.sparse
    assert s.extrapolation_var_m2(1.0) == 0.0


def test_a_sparse_stream_learns_how_far_its_trend_misses_and_the_prior_fades() -> None:
    """Alternate braking and holding (+-4 m/s^2 changes of acceleration each second): each
    interval's trend, continued, misses the next one's displacement by |d accel| / 2 * 1 s^2,
    a drift rate of 4 m/s^2 from the trend; a steady acceleration misses nothing."""
    braking = _sparse([-4.0, 0.0] * 150)
    assert braking.sparse
    assert braking.extrapolation_mps2 == pytest.approx(4.0, rel=0.01)
    tv = braking.velocities[-1][0]
    assert braking.extrapolation_var_m2(tv) == 0.0  # at the latest sample: nothing predicted
    # (alpha s^2 / 2)^2 after s
    assert braking.extrapolation_var_m2(tv + 0.5) == pytest.approx((4.0 * 0.25 / 2) ** 2, rel=0.02)
    steady = _sparse([1.0] * 300)
    assert steady.extrapolation_mps2 < 1e-3  # the prior (1 m/s^2) gone after five minutes
    # the trend continued for at most one interval, then held
    tv, vl = steady.velocities[-1]
    want = 0.5 * vl[0] + 0.5 * 1.0 * 0.5**2
    assert steady.predicted_displacement(tv, tv + 0.5) == pytest.approx([want])
    want2 = 2.0 * vl[0] + 0.5 * 1.0 + 1.0 * 1.0
    assert steady.predicted_displacement(tv, tv + 2.0) == pytest.approx([want2])


def test_a_gap_is_an_interval_over_the_age_limit_and_twice_the_one_before() -> None:
    """Inside a 6 s gap of a 10 Hz stream the path between the samples is uncertain (zero at
    both ends); a 0.4 Hz stream's own 2.5 s cadence is no gap, its 6 s interval is."""
    dense = kc.Streams(n=1)
    for k, t in enumerate([0.0, 0.1, 0.2, 6.2]):
        dense.append_velocity(t, [1.0])
        if k:
            dense.set_interval_mean(t, [1.0])
    mid = dense.shape_var_m2(3.2)
    assert mid == pytest.approx((0.5 * 1.0 * 3.0 * 3.0) ** 2)  # alpha >= 1 m/s^2
    assert dense.shape_var_m2(0.15) == 0.0
    slow = kc.Streams(n=1)
    for k, t in enumerate([0.0, 2.5, 5.0, 7.5]):
        slow.append_velocity(t, [1.0])
        if k:
            slow.set_interval_mean(t, [1.0])
    assert slow.shape_var_m2(6.0) == 0.0
    slow.append_velocity(13.5, [1.0])
    slow.set_interval_mean(13.5, [1.0])
    assert slow.shape_var_m2(10.5) > 0.0


def test_a_dense_stream_with_means_from_the_positions_holds_its_latest_sample() -> None:
    """At 10 Hz every interval's mean comes from the positions too, but a prediction past
    the latest sample holds it (no trend, no extrapolation variance, nothing learnt)."""
    dense = _sparse([-4.0, 0.0] * 150, dt_s=0.1)
    assert not dense.sparse
    tv, vl = dense.velocities[-1]
    assert dense.extrapolation_var_m2(tv + 0.05) == 0.0
    assert dense.predicted_displacement(tv, tv + 0.05) == pytest.approx([0.05 * vl[0]])
    assert np.array_equal(dense.q[3:], kc.Streams(n=1).q[3:])  # the prior, untouched


def test_breakpoints_are_unique_in_order_and_slivers_merge_when_asked() -> None:
    s = kc.Streams()
    for t in (0.0, 0.5, 1.0):
        s.append_velocity(t, [0.0, 0.0, 0.0])
    for t in (0.5, 0.505, 0.995):
        s.append_bearing(t, [1.0, 0.0, 0.0])
    assert s.breakpoints(0.0, 1.0, 0.0) == [0.0, 0.5, 0.505, 0.995, 1.0]
    assert s.breakpoints(0.0, 1.0, 0.01) == [0.0, 0.5, 1.0]
    assert 2.5 in s.breakpoints(2.0, 3.0, 0.0)  # a bearing's expiry is a breakpoint too


def test_the_horizon_is_the_earlier_stream_unless_the_other_is_stale_or_full() -> None:
    s = kc.Streams(max_buffer=3)
    s.append_velocity(0.0, [0.0, 0.0, 0.0])
    s.append_bearing(1.0, [1.0, 0.0, 0.0])
    s.append_velocity(2.0, [0.0, 0.0, 0.0])
    assert s.horizon() == 1.0 and s.can_wait()
    s.append_velocity(4.0, [0.0, 0.0, 0.0])  # the bearing is stale
    assert s.horizon() == 4.0 and not s.can_wait()
    t = kc.Streams(max_buffer=3)
    t.append_bearing(0.0, [1.0, 0.0, 0.0])
    for k in range(5):
        t.append_velocity(0.1 * k, [0.0, 0.0, 0.0])
    assert t.horizon() == pytest.approx(0.4)  # the buffer is full: no more waiting
    u = kc.Streams()  # (a velocity wait of 2 s)
    u.append_velocity(0.0, [0.0, 0.0, 0.0])
    u.append_bearing(3.0, [1.0, 0.0, 0.0])
    assert u.horizon() == 0.0  # the first bearing after a gap in both waits for the velocity
    for k in range(1, 6):
        u.append_bearing(3.0 + 0.5 * k, [1.0, 0.0, 0.0])
    assert u.horizon() == 5.5  # bearings for more than 2 s: the velocity is stale, held
    assert u.horizon(held=True) == 5.5  # and once held past it, the horizon follows
    w = kc.Streams()
    w.append_velocity(0.0, [0.0, 0.0, 0.0])
    w.append_bearing(0.5, [1.0, 0.0, 0.0])
    w.append_bearing(4.0, [1.0, 0.0, 0.0])  # (a gap in the bearings too)
    w.append_bearing(5.5, [1.0, 0.0, 0.0])
    assert w.horizon() == 0.0  # waiting since 4.0 s only


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 10.0), min_size=1, max_size=20), st.floats(0.0, 10.0))
def test_trim_keeps_the_anchor_and_everything_after_it(times: list[float], t_c: float) -> None:
    """Of the bearings the latest at or before the committed time (the interpolation's
    anchor) and all after; of the velocities the one before the anchor too (a prediction
    continues the latest interval's trend)."""
    s = kc.Streams()
    for t in sorted(times):
        s.append_bearing(t, [1.0, 0.0, 0.0])
        s.append_velocity(t, [0.0, 0.0, 0.0])
    before_b, before_v = s.bearing_times, [t for t, _ in s.velocities]
    s.trim(t_c)
    kept_b, kept_v = s.bearing_times, [t for t, _ in s.velocities]
    for before, kept in ((before_b, kept_b), (before_v, kept_v)):
        assert kept == before[len(before) - len(kept) :]  # a suffix
        assert [t for t in before if t > t_c] == [t for t in kept if t > t_c]
    anchors = [t for t in before_b if t <= t_c]
    if anchors:
        assert kept_b[0] == anchors[-1]
        assert kept_v[0] == anchors[-2 if len(anchors) > 1 else -1]


@pytest.mark.parametrize("estimator", ["riccati", "paper"])
def test_a_prediction_past_the_data_moves_x_by_v_plus_a(estimator: str) -> None:
    """Beyond the data horizon the estimate is predicted, not committed: ``x`` moves by the
    velocity held plus ``a`` over the span, and the committed state does not move."""
    obs = BiasObserver(ObserverConfig(estimator=estimator, initial_range_m=20.0))
    rng = np.random.default_rng(1)
    for k in range(101):
        t = 0.05 * k
        obs.update_velocity_values(t, [1.0, -0.5, 0.25])
        y = np.array([0.6, 0.8, 0.0]) + rng.normal(0.0, 0.01, 3)
        obs.update_bearing_values(t, (y / np.linalg.norm(y)).tolist())
    t_c = obs.committed_t_s
    x0, a0 = np.array(obs.x_m), np.array(obs.a_mps)
    est = obs.predict(t_c + 2.0)
    np.testing.assert_allclose(est.x_m - x0, 2.0 * (np.array([1.0, -0.5, 0.25]) + a0), atol=1e-9)
    np.testing.assert_array_equal(est.a_mps, a0)
    assert obs.committed_t_s == t_c and np.array_equal(obs.x_m, x0)


def test_started_after_the_only_velocity_the_bearings_wait_for_the_next_one() -> None:
    """A 1 Hz velocity: the observer starts at a bearing after the only velocity sample; the
    bearings after it wait for the next velocity (they are not committed on the velocity
    held, which only a stale velocity is)."""
    obs = BiasObserver()
    obs.update_velocity_values(0.0, [1.0, 0.0, 0.0])
    for k in range(1, 10):
        obs.update_bearing_values(0.1 * k, [0.0, 1.0, 0.0])
    assert obs.committed_t_s == pytest.approx(0.1)
    obs.update_velocity_values(1.0, [1.0, 0.0, 0.0])
    obs.update_bearing_values(1.05, [0.0, 1.0, 0.0])
    assert obs.committed_t_s == 1.0
