"""Rotation helpers (mav_observer/geo/frames.py): conventions and round trips."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from mav_observer.geo import frames as F

angles = st.tuples(
    st.floats(-math.pi + 1e-3, math.pi - 1e-3),
    st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3),
    st.floats(-math.pi + 1e-3, math.pi - 1e-3),
)


def test_conventions_by_hand() -> None:
    # yaw 90 deg: the nose (body x) points east
    assert np.allclose(F.mat_vec(F.euler_to_dcm(0, 0, math.pi / 2), (1, 0, 0)), (0, 1, 0))
    # pitch 30 deg up: the nose rises, i.e. goes to negative down
    assert np.allclose(
        F.mat_vec(F.euler_to_dcm(0, math.radians(30), 0), (1, 0, 0)), (math.sqrt(3) / 2, 0, -0.5)
    )
    # roll 30 deg right: body down (z) tilts to the west (negative east)
    assert np.allclose(
        F.mat_vec(F.euler_to_dcm(math.radians(30), 0, 0), (0, 0, 1)), (0, -0.5, math.sqrt(3) / 2)
    )
    assert F.direction_from_angles(-math.pi / 2, 1.0) == pytest.approx((0.0, 0.0, 1.0), abs=1e-15)


@given(angles)
def test_quaternion_and_euler_agree(rpy) -> None:
    q = F.quat_from_euler(*rpy)
    assert F.quat_norm(q) == pytest.approx(1.0)
    assert np.allclose(F.quat_to_dcm(q), F.euler_to_dcm(*rpy), atol=1e-12)
    assert np.allclose(F.euler_from_dcm(F.euler_to_dcm(*rpy)), rpy, atol=1e-9)


@given(angles, angles)
def test_quaternion_product_composes_rotations(a, b) -> None:
    qa, qb = F.quat_from_euler(*a), F.quat_from_euler(*b)
    assert np.allclose(
        F.quat_to_dcm(F.quat_mul(qa, qb)),
        F.mat_mul(F.quat_to_dcm(qa), F.quat_to_dcm(qb)),
        atol=1e-12,
    )


def test_yaw_rotation_and_wrap() -> None:
    assert np.allclose(F.yaw_rotate(math.pi / 2, (1.0, 0.0, 0.5)), (0.0, 1.0, 0.5))
    assert np.allclose(F.rot_z(0.3), F.euler_to_dcm(0, 0, 0.3))
    assert F.wrap_pi(3 * math.pi) == pytest.approx(-math.pi)
    assert F.normalize((3.0, 0.0, 4.0)) == pytest.approx((0.6, 0.0, 0.8))
