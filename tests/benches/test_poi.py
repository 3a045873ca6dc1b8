"""The point-of-interest comparison (bench/accuracy/poi.py): one ray to an assumed ground."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.accuracy.poi import point_of_interest


def test_a_ray_meets_the_assumed_ground_and_one_at_the_horizon_does_not() -> None:
    vehicle = np.array([[0.0, 0.0, -10.0], [5.0, 5.0, -10.0], [0.0, 0.0, -10.0]])
    s = math.sqrt(0.5)
    los = np.array([[s, 0.0, s], [0.0, s, s], [1.0, 0.0, 0.0]])  # 45 deg down, level
    poi, ok = point_of_interest(vehicle, los, 0.0)
    assert ok.tolist() == [True, True, False]
    assert poi[0] == pytest.approx([10.0, 0.0, 0.0])
    assert poi[1] == pytest.approx([5.0, 15.0, 0.0])
    # a target 8 m above that ground, seen 45 deg down: the point of interest 8 m beyond it
    poi, _ = point_of_interest(vehicle[:1], los[:1], 0.0)
    target = np.array([2.0, 0.0, -8.0])
    assert np.hypot(*(poi[0] - target)[:2]) == pytest.approx(8.0)
