"""The causal reference of the real-log bench (bench/accuracy/causal.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.accuracy.causal import causal_fits, main
from sim.stream import perturb_bearings


def _flight(om_rad_s: float) -> tuple[np.ndarray, ...]:
    """A vehicle 3 m above a target, weaving 1 m east-west at ``om_rad_s``; 10 Hz bearings
    (0.5 deg), LOCAL_POSITION_NED at 1 Hz (true positions and velocities)."""
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 40.0, 0.1)
    om, amp = om_rad_s, 1.0

    def pos(tt: np.ndarray) -> np.ndarray:
        return np.column_stack([0.1 * tt, amp * np.sin(om * tt), np.full_like(tt, -3.0)])

    def vel(tt: np.ndarray) -> np.ndarray:
        return np.column_stack(
            [np.full_like(tt, 0.1), amp * om * np.cos(om * tt), np.zeros_like(tt)]
        )

    # the truth between the samples is their straight line, as the real-log bench's
    tl = np.arange(-0.95, 41.0, 1.0)
    p_l = pos(tl)
    p = np.column_stack([np.interp(t, tl, p_l[:, i]) for i in range(3)])
    x = np.array([2.0, 0.0, 0.0]) - p
    y = perturb_bearings(x / np.linalg.norm(x, axis=1, keepdims=True), math.radians(0.5), rng)
    return t, y, x, tl, p_l, vel(tl)


def test_extrapolating_between_sparse_positions_costs_what_the_vehicle_accelerates() -> None:
    """A slow weave (0.01 m/s^2): the positions extrapolated past the latest sample are as
    good as interpolated; a fast one (2.25 m/s^2, 1 Hz samples) the extrapolated fit is many
    times the interpolated one, which stays within 1 % of range."""
    slow = causal_fits(*_flight(0.1), sigma_rad=math.radians(0.5), fits=20)
    assert slow["extrapolated"] < 1.2 * slow["interpolated"], slow
    weave = causal_fits(*_flight(1.5), sigma_rad=math.radians(0.5), fits=20)
    assert weave["interpolated"] < 0.01, weave
    assert weave["extrapolated"] > 10.0 * weave["interpolated"], weave


def test_a_missing_log_or_bad_count_is_refused_naming_it(tmp_path, capsys) -> None:
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nope.tlog")])
    assert "nope.tlog" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--fits", "0", str(tmp_path / "nope.tlog")])
    assert "--fits" in capsys.readouterr().err
