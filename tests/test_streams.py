"""The sample streams: checks on arrival, interpolation, holding, breakpoints, horizon."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.errors import InvalidSampleError
from mav_observer.streams import DEFAULT_VELOCITY_DT_S, MIN_INTERVAL_S, SampleStreams


def _streams(*, linear: bool = True, max_buffer: int = 256) -> SampleStreams:
    return SampleStreams(
        max_bearing_age_s=2.0, max_velocity_age_s=2.0, linear=linear, max_buffer=max_buffer
    )


def test_a_sample_before_the_previous_one_is_refused_naming_both_times() -> None:
    s = _streams()
    s.append("velocity", 1.0, [0.0, 0.0, 0.0], None)
    with pytest.raises(InvalidSampleError, match=r"velocity t_s=0.5 .* t_s=1.0"):
        s.append("velocity", 0.5, [0.0, 0.0, 0.0], None)
    assert len(s.velocities) == 1


def test_a_bearing_older_than_the_committed_time_is_refused() -> None:
    s = _streams()
    with pytest.raises(InvalidSampleError, match="older than the observer's committed time"):
        s.append("bearing", 1.0, [1.0, 0.0, 0.0], committed_t_s=2.0)
    s.append("velocity", 1.0, [0.0, 0.0, 0.0], committed_t_s=2.0)  # a velocity may be late
    assert s.bearings == [] and len(s.velocities) == 1


def test_the_velocity_interval_is_the_latest_one_at_most_a_second() -> None:
    s = _streams()
    assert s.velocity_dt_s == DEFAULT_VELOCITY_DT_S
    s.append("velocity", 0.0, [0.0, 0.0, 0.0], None)
    s.append("velocity", 0.2, [0.0, 0.0, 0.0], None)
    assert s.velocity_dt_s == pytest.approx(0.2)
    s.append("velocity", 5.0, [0.0, 0.0, 0.0], None)
    assert s.velocity_dt_s == 1.0


def test_a_bearing_is_interpolated_along_the_chord_and_held_until_it_expires() -> None:
    s = _streams()
    s.append("bearing", 0.0, [1.0, 0.0, 0.0], None)
    s.append("bearing", 1.0, [0.0, 1.0, 0.0], None)
    y = s.bearing_at(0.5)
    assert y == pytest.approx([math.sqrt(0.5), math.sqrt(0.5), 0.0])
    assert s.bearing_at(2.9) == [0.0, 1.0, 0.0]  # held for max_bearing_age_s
    assert s.bearing_at(3.1) is None
    assert s.bearing_at(-0.1) is None


def test_hold_interpolation_holds_each_bearing_to_the_next() -> None:
    s = _streams(linear=False)
    s.append("bearing", 0.0, [1.0, 0.0, 0.0], None)
    s.append("bearing", 1.0, [0.0, 1.0, 0.0], None)
    assert s.bearing_at(0.9) == [1.0, 0.0, 0.0]


def test_an_interval_mean_shifts_the_interpolated_velocity_to_the_positions_mean() -> None:
    s = _streams()
    s.append("velocity", 0.0, [0.0, 0.0, 0.0], None)
    s.append("velocity", 1.0, [2.0, 0.0, 0.0], None)
    assert s.velocity_at(0.5) == pytest.approx([1.0, 0.0, 0.0])
    assert not s.chord_at(0.5)
    s.set_interval_mean(1.0, [1.5, 0.0, 0.0])
    assert s.chord_at(0.5)
    # the samples' shape (a ramp) shifted by 0.5 so its mean is the positions' 1.5
    assert s.velocity_at(0.25) == pytest.approx([1.0, 0.0, 0.0])
    assert s.predicted_displacement(0.0, 1.0) == pytest.approx([1.5, 0.0, 0.0])


def _sparse(accel_mps2: list[float], dt_s: float = 1.0) -> SampleStreams:
    """A 1-axis sparse stream (every interval's mean known) whose acceleration over each
    interval is ``accel_mps2[k]`` (velocity samples and means exact)."""
    s = _streams()
    v, t = 5.0, 0.0
    s.append("velocity", t, [v], None)
    for acc in accel_mps2:
        v1 = v + acc * dt_s
        t += dt_s
        s.append("velocity", t, [v1], None)
        s.set_interval_mean(t, [0.5 * (v + v1)])
        v = v1
    return s


def test_a_dense_stream_has_no_extrapolation_variance() -> None:
    s = _streams()
    for k in range(5):
        s.append("velocity", 0.1 * k, [1.0, 0.0, 0.0], None)
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
    # the prior (1 m/s^2) is gone after five minutes of exact trends
    assert steady.extrapolation_mps2 < 1e-3


def test_a_dense_stream_with_means_from_the_positions_holds_its_latest_sample() -> None:
    """At 10 Hz every interval's mean comes from the positions too, but a prediction past
    the latest sample holds it (no trend, no extrapolation variance, nothing learnt), as a
    dense stream's always did: over 0.1 s the trend gains nothing and costs the service a
    position update per bearing."""
    dense = _sparse([-4.0, 0.0] * 150, dt_s=0.1)
    assert not dense.sparse
    tv, vl = dense.velocities[-1]
    assert dense.extrapolation_var_m2(tv + 0.05) == 0.0
    assert dense.predicted_displacement(tv, tv + 0.05) == pytest.approx([0.05 * vl[0]])
    assert dense.extrap == _sparse([]).extrap  # the prior, untouched


def test_breakpoints_are_unique_in_order_and_slivers_merge_when_asked() -> None:
    s = _streams()
    for t in (0.0, 0.5, 1.0):
        s.append("velocity", t, [0.0, 0.0, 0.0], None)
    for t in (0.5, 0.505, 0.995):
        s.append("bearing", t, [1.0, 0.0, 0.0], None)
    assert s.breakpoints(0.0, 1.0, 0.0) == [0.0, 0.5, 0.505, 0.995, 1.0]
    assert s.breakpoints(0.0, 1.0, MIN_INTERVAL_S) == [0.0, 0.5, 1.0]
    # a bearing's expiry is a breakpoint too
    assert 2.5 in s.breakpoints(2.0, 3.0, 0.0)


def test_the_horizon_is_the_earlier_stream_unless_the_other_is_stale_or_full() -> None:
    s = _streams(max_buffer=3)
    s.append("velocity", 0.0, [0.0, 0.0, 0.0], None)
    s.append("bearing", 1.0, [1.0, 0.0, 0.0], None)
    s.append("velocity", 2.0, [0.0, 0.0, 0.0], None)
    assert s.horizon() == 1.0
    s.append("velocity", 4.0, [0.0, 0.0, 0.0], None)  # the bearing is stale
    assert s.horizon() == 4.0 and not s.can_wait()
    t = _streams(max_buffer=3)
    t.append("bearing", 0.0, [1.0, 0.0, 0.0], None)
    for k in range(5):
        t.append("velocity", 0.1 * k, [0.0, 0.0, 0.0], None)
    assert t.horizon() == pytest.approx(0.4)  # the buffer is full: no more waiting


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.0, 10.0), min_size=1, max_size=20),
    st.floats(0.0, 10.0),
)
def test_trim_keeps_the_anchor_and_everything_after_it(times: list[float], t_c: float) -> None:
    s = _streams()
    for t in sorted(times):
        s.append("bearing", t, [1.0, 0.0, 0.0], None)
        s.append("velocity", t, [0.0, 0.0, 0.0], None)
    before_b = [t for t, _ in s.bearings]
    s.trim(t_c)
    kept = [t for t, _ in s.bearings]
    assert kept == before_b[len(before_b) - len(kept) :]  # a suffix
    assert [t for t in before_b if t > t_c] == [t for t in kept if t > t_c]
    anchors = [t for t in before_b if t <= t_c]
    if anchors:
        assert kept[0] == anchors[-1]  # the latest sample at or before t_c is kept
