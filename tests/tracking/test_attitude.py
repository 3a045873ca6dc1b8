"""mav_observer.tracking.attitude: the vehicle attitude history, interpolated and extrapolated."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mav_observer.tracking.attitude import AttitudeHistory, euler_rates


def test_attitude_history_interpolates_yaw_across_the_wrap() -> None:
    h = AttitudeHistory()
    h.add(1.0, 0.0, 0.0, math.radians(179.0))
    h.add(2.0, 0.2, 0.0, math.radians(-179.0))
    r, _, y = h.at(1.5, 0.5)
    assert r == pytest.approx(0.1) and math.degrees(y) == pytest.approx(180.0)
    assert h.at(2.6, 0.5) is None and h.at(0.4, 0.5) is None


def test_past_the_latest_the_attitude_is_extrapolated_with_the_body_rates() -> None:
    h = AttitudeHistory()
    h.add(1.0, 0.0, 0.0, 0.0, body_rates=(0.0, 0.0, 0.5))  # level, yawing at 0.5 rad/s
    assert h.has_rates and h.latest_t_s == 1.0
    assert h.at(1.02, 0.05)[2] == pytest.approx(0.01)
    assert h.at(1.06, 0.05) is None  # beyond max_age_s: not made up


def test_without_rates_they_come_from_the_last_two_samples() -> None:
    h = AttitudeHistory()
    h.add(1.0, 0.0, 0.0, 0.0)
    h.add(1.1, 0.0, 0.0, 0.1)
    assert h.interval_s == pytest.approx(0.1)
    assert h.at(1.15, 0.1)[2] == pytest.approx(0.15)


def test_an_older_sample_does_not_disorder_the_history() -> None:
    h = AttitudeHistory()
    h.add(2.0, 0.0, 0.0, 0.2)
    h.add(1.0, 0.0, 0.0, 0.1)  # late: dropped
    assert h.latest_t_s == 2.0 and h.at(1.0, 0.5) is None


@given(
    st.floats(-1.2, 1.2), st.floats(-1.2, 1.2), st.floats(-3.0, 3.0),
    st.floats(-3.0, 3.0), st.floats(-3.0, 3.0),
)  # fmt: skip
def test_level_flight_euler_rates_are_the_body_rates_and_they_invert(roll, pitch, p, q, r):
    assert euler_rates(0.0, 0.0, (p, q, r)) == pytest.approx((p, q, r))
    dr, dp, dy = euler_rates(roll, pitch, (p, q, r))
    # back to body rates: p = dr - sin(pitch) dy, q = cos(roll) dp + sin(roll) cos(pitch) dy
    assert dr - math.sin(pitch) * dy == pytest.approx(p, abs=1e-9)
    assert math.cos(roll) * dp + math.sin(roll) * math.cos(pitch) * dy == pytest.approx(q, abs=1e-9)
