"""The velocity's white noise learnt from its samples (mav_observer/noise.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.noise import NoiseStateError, VelocityNoise
from sim import scenarios


def _feed(vn: VelocityNoise, t: np.ndarray, v: np.ndarray) -> None:
    for tk, vk in zip(t, v, strict=True):
        vn.update(float(tk), vk.tolist())


@pytest.mark.parametrize("sigma", [0.02, 0.1, 0.2])
def test_white_noise_on_a_manoeuvring_flight_is_learnt_within_10_percent(sigma: float) -> None:
    """Figure-8 at 10 Hz with 5 ms of timestamp jitter, white noise of 0.02 to 0.2 m/s,
    the prior 0.05 m/s: after 90 s the estimate is within 10 % of the truth."""
    rng = np.random.default_rng(5)
    sc = scenarios.figure8(duration_s=90.0)
    t = np.arange(0.0, 90.0, 0.1) + rng.uniform(-0.005, 0.005, 900)
    v = sc.v(t) + rng.normal(0.0, sigma, (len(t), 3))
    vn = VelocityNoise(prior_mps=0.05)
    _feed(vn, t, v)
    assert vn.sigma_mps == pytest.approx(sigma, rel=0.1)


def test_exact_velocity_is_learnt_as_nearly_exact() -> None:
    """The motion itself (a figure-8, quadratic locally) is not noise: below 1 mm/s after a
    minute, from a prior of 0.05 m/s."""
    sc = scenarios.figure8(duration_s=120.0)
    t = np.arange(0.0, 120.0, 0.1)
    vn = VelocityNoise(prior_mps=0.05)
    _feed(vn, t, sc.v(t))
    assert vn.sigma_mps < 0.001


def test_sparse_samples_keep_the_prior() -> None:
    """At 1 Hz the motion between samples dominates: nothing is learnt."""
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 60.0, 1.0)
    vn = VelocityNoise(prior_mps=0.05)
    _feed(vn, t, rng.normal(0.0, 1.0, (len(t), 3)))
    assert vn.sigma_mps == pytest.approx(0.05)


def test_a_glitch_moves_the_estimate_little() -> None:
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 120.0, 0.1)
    v = rng.normal(0.0, 0.05, (len(t), 3))
    v[600] += 30.0  # one sample 30 m/s off
    vn = VelocityNoise(prior_mps=0.05)
    _feed(vn, t, v)
    assert vn.sigma_mps < 0.08


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 12))
def test_save_and_restore_is_exact(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = VelocityNoise(), VelocityNoise()
    t = np.cumsum(rng.uniform(0.05, 0.15, n))
    v = rng.normal(0.0, 0.1, (n, 3))
    _feed(a, t, v)
    b.restore(a.to_dict())
    more_t, more_v = t[-1:] + 0.1 if n else np.array([0.1]), rng.normal(0.0, 0.1, (1, 3))
    _feed(a, more_t, more_v)
    _feed(b, more_t, more_v)
    assert a.sigma_mps == b.sigma_mps
    assert math.isfinite(a.sigma_mps)


def test_a_bad_saved_state_is_refused_naming_the_field() -> None:
    good = VelocityNoise().to_dict()
    with pytest.raises(NoiseStateError, match=r"w_prior=-1\.0 must be finite >= 0"):
        VelocityNoise().restore({**good, "w_prior": -1.0})
    with pytest.raises(NoiseStateError, match="malformed"):
        VelocityNoise().restore({"w": 1.0})
    with pytest.raises(ValueError, match="prior_mps must be a finite number >= 0"):
        VelocityNoise(prior_mps=math.nan)
