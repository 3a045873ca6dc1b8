"""The post-flight smoother (mav_observer/core/smoother.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mav_observer.core.smoother import SampleLog, smooth
from sim import scenarios
from sim.stream import perturb_bearings


def _orbit(duration_s: float, drift_mps_per_s: float, seed: int, outliers: float = 0.0):
    """An orbit at 10 Hz; the vehicle's measured velocity is off by a ``a`` that drifts
    linearly (m/s per s); bearings at 0.5 deg, a share of them 20 deg off."""
    rng = np.random.default_rng(seed)
    sc = scenarios.orbit(duration_s=duration_s)
    t = np.arange(0.0, duration_s, 0.1)
    x = sc.x(t)  # the truth, whose x' = v_true + a_true
    u_true = -sc.v(t)  # the vehicle's velocity (v = -u)
    err = np.outer(drift_mps_per_s * t, [1.0, -0.5, 0.0])  # a velocity error that drifts
    u_meas = u_true + err + np.asarray(sc.a_mps)  # so that -u_meas + a_true_total = x'
    y = perturb_bearings(x / np.linalg.norm(x, axis=1)[:, None], math.radians(0.5), rng)
    bad = rng.random(len(t)) < outliers
    y[bad] = perturb_bearings(y[bad], math.radians(20.0), rng)
    return t, x, y, u_meas


def test_a_constant_bias_is_one_fit_over_the_whole_log_and_honest() -> None:
    t, x, y, u = _orbit(300.0, 0.0, 1)
    s = smooth(t, y, t, u, sigma_rad=math.radians(0.5))
    assert len(s.fits) == 1 and s.fits[0][2] is not None  # the whole log won
    err = s.rel_pos_ned_m - x
    assert np.sqrt(np.mean(np.sum(err**2, axis=1))) < 0.02
    nees = np.einsum("ki,kij,kj->k", err, np.linalg.inv(s.rel_pos_cov_m2), err) / 3
    assert 0.3 < float(np.mean(nees)) < 3.0


def test_a_drifting_bias_is_fitted_by_windows_better_than_by_one_fit() -> None:
    t, x, y, u = _orbit(600.0, 0.002, 2)  # 1.2 m/s of drift over the flight
    windows = smooth(t, y, t, u, sigma_rad=math.radians(0.5), window_s=120.0)
    whole = smooth(t, y, t, u, sigma_rad=math.radians(0.5), window_s=math.inf)
    assert len(windows.fits) > 1
    rms = {k: float(np.sqrt(np.mean(np.sum((s.rel_pos_ned_m - x) ** 2, axis=1))))
           for k, s in (("windows", windows), ("whole", whole))}  # fmt: skip
    assert rms["windows"] < 0.5 * rms["whole"], rms


def test_gross_bearing_errors_weigh_little() -> None:
    t, x, y, u = _orbit(200.0, 0.0, 3, outliers=0.1)
    s = smooth(t, y, t, u, sigma_rad=math.radians(0.5))
    err = np.linalg.norm(s.rel_pos_ned_m - x, axis=1) / np.linalg.norm(x, axis=1)
    assert float(np.sqrt(np.mean(err**2))) < 0.005


def test_too_little_data_gives_no_estimate_and_says_why() -> None:
    t, _, y, u = _orbit(1.0, 0.0, 4)
    s = smooth(t, y, t, u, sigma_rad=math.radians(0.5))
    assert np.all(s.window == -1) and np.all(np.isnan(s.rel_pos_ned_m))
    assert "fewer than" in s.fits[0][3]
    with pytest.raises(ValueError, match="window_s must be a number > 0"):
        smooth(t, y, t, u, sigma_rad=0.01, window_s=0.0)


def test_the_sample_log_splits_where_the_clock_restarts() -> None:
    """A new epoch (a reboot the tracker detected) starts new tracks; a repeated time is
    kept once."""
    log = SampleLog()
    for k in range(5):
        log.local_position(1, 100.0 + k, (k, 0.0, 0.0), (1.0, 0.0, 0.0))
        log.bearing(1, "gimbal", 100.0 + k, [1.0, 0.0, 0.0])
    log.local_position(1, 104.0, (9.0, 0.0, 0.0), (1.0, 0.0, 0.0))  # repeated: ignored
    log.new_epoch(1)  # the tracker saw the autopilot reboot
    log.local_position(1, 3.0, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    log.local_position(1, 4.0, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    log.bearing(1, "gimbal", 4.0, [0.0, 1.0, 0.0])
    assert log.tracks() == [(1, "gimbal", 0), (1, "gimbal", 1)]
    first = log.data(1, "gimbal", 0)
    assert first is not None and len(first[0]) == 5 and len(first[2]) == 5
    second = log.data(1, "gimbal", 1)
    assert second is not None and second[1].tolist() == [[0.0, 1.0, 0.0]]


def test_forgotten_bearings_leave_the_other_targets_and_later_epochs() -> None:
    log = SampleLog()
    for k in range(3):
        log.local_position(1, float(k), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        log.bearing(1, "gimbal", float(k), [1.0, 0.0, 0.0])
        log.bearing(1, "camera", float(k), [0.0, 1.0, 0.0])
    log.forget_bearings(1, "gimbal")
    assert log.tracks() == [(1, "camera", 0)]
    log.bearing(1, "gimbal", 3.0, [1.0, 0.0, 0.0])  # read right from now on
    data = log.data(1, "gimbal", 0)
    assert data is not None and data[0].tolist() == [3.0]
    log.new_epoch(1)
    log.bearing(1, "gimbal", 0.5, [1.0, 0.0, 0.0])
    log.forget_bearings(1, "gimbal")  # the current epoch's only
    assert log.tracks() == [(1, "camera", 0), (1, "gimbal", 0)]
