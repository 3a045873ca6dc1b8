"""Seeded, noisy sample streams (sim/stream.py)."""

import numpy as np
import pytest

from mav_observer import BearingSample, VelocitySample
from sim import scenarios
from sim.stream import PAPER_NOISE, Noise, generate, paper_noise, perturb_bearings


def test_paper_noise_scale() -> None:
    assert paper_noise() == PAPER_NOISE == Noise(position_noise_m=0.5)
    assert paper_noise(0.1).position_noise_m == pytest.approx(0.05)
    with pytest.raises(ValueError, match="scale must be >= 0"):
        paper_noise(-1.0)


def test_streams_are_seeded() -> None:
    sc = scenarios.orbit(duration_s=20.0)
    noise = Noise(bearing_sigma_deg=1.0, velocity_sigma_mps=0.1, drop_prob=0.1, jitter_frac=0.2)
    a, b, c = (generate(sc, seed=s, noise=noise) for s in (4, 4, 5))
    assert np.array_equal(a.y, b.y) and np.array_equal(a.t_velocity_s, b.t_velocity_s)
    assert not np.array_equal(a.y, c.y)


def test_bearing_noise_has_the_requested_angular_sigma() -> None:
    rng = np.random.default_rng(1)
    y = np.tile([0.0, 0.0, 1.0], (20000, 1))
    sigma = np.deg2rad(2.0)
    out = perturb_bearings(y, sigma, rng)
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0)
    ang = np.arccos(np.clip(out[:, 2], -1, 1))
    # isotropic in the tangent plane: the angle is Rayleigh with E[ang^2] = 2 sigma^2
    assert np.sqrt(np.mean(ang**2) / 2.0) == pytest.approx(sigma, rel=0.03)
    assert abs(np.mean(out[:, 0])) < 3 * sigma / np.sqrt(20000) * 3


def test_papers_uniform_position_noise_and_velocity_noise() -> None:
    sc = scenarios.paper(duration_s=200.0)
    clean = generate(sc)
    noisy = generate(sc, noise=Noise(position_noise_m=0.5, velocity_sigma_mps=0.2), seed=2)
    ang = np.arccos(np.clip(np.sum(clean.y * noisy.y, axis=1), -1, 1))
    assert 0.02 < ang.mean() < 0.2  # +-0.5 m at 3.2 m: several degrees
    dv = noisy.v_mps - clean.v_mps
    assert dv.std() == pytest.approx(0.2, rel=0.05)


def test_drops_and_jitter_keep_order() -> None:
    st = generate(scenarios.orbit(duration_s=100.0), noise=Noise(drop_prob=0.3, jitter_frac=0.45))
    for t in (st.t_bearing_s, st.t_velocity_s):
        assert np.all(np.diff(t) > 0)
        assert len(t) == pytest.approx(0.7 * 2001, rel=0.05)


def test_events_are_time_ordered_velocity_first() -> None:
    st = generate(scenarios.orbit(duration_s=2.0))
    evs = list(st.events())
    times = [e.t_s for e in evs]
    assert times == sorted(times)
    assert isinstance(evs[0], VelocitySample) and isinstance(evs[1], BearingSample)
    assert len(evs) == len(st.t_bearing_s) + len(st.t_velocity_s)


def test_bad_noise_is_refused() -> None:
    with pytest.raises(ValueError, match="drop_prob must be in"):
        Noise(drop_prob=1.0)
    with pytest.raises(ValueError, match="bearing_sigma_deg must be >= 0"):
        Noise(bearing_sigma_deg=-1.0)
