"""The velocity's drift from the positions, and the bias published against it (core/drift.py)."""

from __future__ import annotations

import math

import numpy as np

from mav_observer.core import drift
from mav_observer.core.drift import PositionDrift, position_at
from mav_observer.core.samples import Estimate, Status


def _estimate(a) -> Estimate:
    z = np.zeros(3)
    z.setflags(write=False)
    a = np.asarray(a, float)
    a.setflags(write=False)
    return Estimate(0.0, z, a, 0.0, 0.0, 1.0, Status.CONVERGED, True, 0.0, 0.0, 0.0)


def test_the_mean_velocity_is_the_position_change_less_the_learnt_drift() -> None:
    # the velocity 0.5 m/s off its positions along north: learnt on the first interval,
    # then every interval's mean is minus the position's change per second plus that drift
    d = PositionDrift()
    p, u = [0.0, 0.0, 0.0], [2.5, 0.0, 0.0]  # moving 2 m/s north, the velocity says 2.5
    means = []
    for k in range(1, 6):
        p1 = [2.0 * k, 0.0, 0.0]
        mean, reset = d.interval(k - 1.0, p, u, float(k), p1, u)
        assert not reset
        means.append(mean)
        p = p1
    np.testing.assert_allclose(d.learnt_mps, [-0.5, 0.0, 0.0], atol=1e-12)
    for mean in means:
        # v = -u less its error: -(dp/dt - drift) = -(2 + 0.5)
        np.testing.assert_allclose(mean, [-2.5, 0.0, 0.0], atol=1e-12)


def test_a_telemetry_gap_gives_the_position_change_and_teaches_nothing() -> None:
    # a 30 s gap in which the vehicle turned: the velocity at its two ends says 1 m/s north,
    # the positions 20 m east; the mean is the positions', and the drift stays unlearnt
    d = PositionDrift()
    gap = drift.DRIFT_INTERVAL_MAX_S + 25.0
    mean, reset = d.interval(0.0, [0, 0, 0], [1, 0, 0], gap, [0, 20.0, 0], [1, 0, 0])
    assert not reset
    np.testing.assert_allclose(mean, [0.0, -20.0 / gap, 0.0])
    assert d.learnt_over_s == 0.0 and d.correction_mps is None


def test_a_position_step_is_a_reset_and_a_steady_disagreement_is_not() -> None:
    d = PositionDrift()
    u = [1.0, 0.0, 0.0]
    for k in range(1, 4):
        assert d.interval(k - 1.0, [k - 1.0, 0, 0], u, float(k), [float(k), 0, 0], u)[1] is False
    mean, reset = d.interval(3.0, [3.0, 0, 0], u, 4.0, [34.0, 0, 0], u)  # a 30 m jump
    assert reset and mean is None
    # the same 30 m/s disagreement again is no step from the one before: no reset
    assert d.interval(4.0, [34.0, 0, 0], u, 5.0, [65.0, 0, 0], u)[1] is False


def test_the_published_bias_is_against_the_long_run_drift() -> None:
    # the first second's drift is 0.4 m/s, the long run 0.5 m/s: the estimator's ``a`` took up
    # the first; the published ``a`` is moved by the difference
    d = PositionDrift()
    u = [0.0, 0.0, 0.0]
    offs = [0.4] + [0.5 + 0.1 / 9.0] * 9  # mean over the 10 intervals: 0.5
    p = 0.0
    for k, off in enumerate(offs):
        d.interval(float(k), [p, 0, 0], u, k + 1.0, [p + off, 0, 0], u)
        p += off
    assert math.isclose(d.learnt_mps[0], 0.4)
    est = d.published(_estimate([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(est.a_mps, [1.0 + 0.4 - 0.5, 2.0, 3.0], atol=1e-12)
    assert not est.a_mps.flags.writeable
    assert PositionDrift().published(est) is est  # nothing learnt: unchanged


def test_a_position_is_moved_on_with_the_estimate_or_the_velocity() -> None:
    est = _estimate([0.5, 0.0, 0.0])
    # no observer: moved by the measured velocity u, then by minus a dt
    assert position_at((10.0, (1.0, 2.0, 3.0), (2.0, 0.0, 0.0)), None, est, 10.5, 1.0) == (
        1.0 + 2.0 * 0.5 - 0.5 * 0.5, 2.0, 3.0)  # fmt: skip
    assert position_at((10.0, (1.0, 2.0, 3.0), (2.0, 0.0, 0.0)), None, est, 12.0, 1.0) is None
    assert position_at(None, None, est, 10.0, 1.0) is None
