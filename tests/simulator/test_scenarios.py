"""The simulator's truth generators and sample streams."""

import numpy as np
import pytest

from sim import scenarios


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


def test_unknown_scenario_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown scenario 'loop'"):
        scenarios.make("loop")
