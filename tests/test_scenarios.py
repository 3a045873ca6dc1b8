"""The simulator's truth generators and sample streams."""

import numpy as np
import pytest

from mav_observer import BearingSample, VelocitySample
from sim import scenarios
from sim.stream import Noise, generate, perturb_bearings


@pytest.mark.parametrize("name", sorted(scenarios.SCENARIOS))
def test_velocity_is_the_derivative_of_position(name: str) -> None:
    sc = scenarios.make(name)
    t = np.linspace(0.5, sc.duration_s - 0.5, 2001)
    dt = 1e-5
    num = (sc.x(t + dt) - sc.x(t - dt)) / (2 * dt)
    assert np.abs(num - sc.xdot(t)).max() < 1e-5
    assert sc.x(t).shape == (len(t), sc.n)
    assert np.allclose(sc.v(t) + sc.a_mps, sc.xdot(t))
    assert np.linalg.norm(sc.x(t), axis=1).min() > 1.0  # never at the target


def test_paper_scenario_is_the_papers() -> None:
    sc = scenarios.paper()
    assert np.allclose(sc.x(0.0), [1.0, 0.0, 3.0])
    assert np.allclose(sc.a_mps, [0.33, 0.66, 0.99])
    t = np.array([1.0, 7.3])
    assert np.allclose(
        sc.v(t) + sc.a_mps, np.column_stack((-0.5 * np.sin(0.5 * t), 0.5 * np.cos(0.5 * t), [0, 0]))
    )


def test_orbit_is_a_ground_target_seen_from_above_in_ned() -> None:
    sc = scenarios.orbit()
    x = sc.x(np.linspace(0, 40, 100))
    assert np.allclose(np.linalg.norm(x[:, :2], axis=1), 15.0)
    assert np.allclose(x[:, 2], 10.0)  # target below the vehicle: +down
    assert np.allclose(sc.a_mps, [-3.0, 2.0, 0.0])  # a = -wind


def test_orbit_pause_holds_still_and_resumes() -> None:
    sc = scenarios.orbit(pause=(10.0, 50.0))
    still = np.linspace(14.0, 60.0, 50)
    assert np.abs(sc.xdot(still)).max() == 0.0
    assert np.allclose(sc.x(still), sc.x(14.0))
    assert np.linalg.norm(sc.xdot(70.0)) == pytest.approx(15 * 2 * np.pi / 40)


def test_straight_pass_ends_in_a_hover() -> None:
    sc = scenarios.straight_pass()
    assert np.abs(sc.xdot(np.linspace(33.0, 120.0, 20))).max() == 0.0
    assert np.linalg.norm(sc.xdot(10.0)) == pytest.approx(5.0)


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


def test_unknown_scenario_and_bad_noise_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown scenario 'loop'"):
        scenarios.make("loop")
    with pytest.raises(ValueError, match="drop_prob must be in"):
        Noise(drop_prob=1.0)
    with pytest.raises(ValueError, match="bearing_sigma_deg must be >= 0"):
        Noise(bearing_sigma_deg=-1.0)
