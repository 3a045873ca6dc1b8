"""The bearings' latency learnt online: a known delay recovered, none when there is none,
gross errors ignored, the saved state checked."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mav_observer.latency import LatencyLearner, LatencyStateError, Settling, advance, los_rate


def _orbit(delay_s: float, *, seed: int, outliers: float = 0.0, seconds: float = 120.0):
    """A vehicle circling 40 m from the target at 8 m/s (the paper's ``x``, ``v``, ``a = 0``)
    with 0.3 deg bearings that show the line of sight ``delay_s`` earlier."""
    rng = np.random.default_rng(seed)
    om = 8.0 / 40.0
    for k in range(int(seconds * 20)):
        t = 0.05 * k

        def x_at(s: float) -> np.ndarray:
            return np.array([40.0 * math.cos(om * s), 40.0 * math.sin(om * s), 10.0])

        x = x_at(t)
        v = np.array([-8.0 * math.sin(om * t), 8.0 * math.cos(om * t), 0.0])  # x' = v
        y = x_at(t - delay_s)
        y = y / np.linalg.norm(y) + rng.normal(0.0, math.radians(0.3), 3)
        if rng.random() < outliers:
            y = y + rng.normal(0.0, math.radians(20.0), 3)
        yield t, x.tolist(), v.tolist(), (y / np.linalg.norm(y)).tolist()


@pytest.mark.parametrize("delay_s", [0.0, 0.1, -0.05])
def test_a_delay_of_the_bearings_is_learnt_within_5_ms(delay_s: float) -> None:
    lat = LatencyLearner()
    for t, x, v, y in _orbit(delay_s, seed=3):
        lat.observe(t, x, [0.0, 0.0, 0.0], v, y, math.radians(0.3) ** 2)
    assert lat.tau_s == pytest.approx(delay_s, abs=0.005)


def test_gross_errors_teach_nothing() -> None:
    lat = LatencyLearner()
    for t, x, v, y in _orbit(0.1, seed=4, outliers=0.1):
        lat.observe(t, x, [0.0, 0.0, 0.0], v, y, math.radians(0.3) ** 2)
    assert lat.tau_s == pytest.approx(0.1, abs=0.01)


def test_a_still_line_of_sight_keeps_the_prior_and_the_latency_stays_bounded() -> None:
    lat = LatencyLearner(max_s=0.5)
    x = [40.0, 0.0, 0.0]
    for k in range(200):  # hovering: the line of sight does not turn
        lat.observe(0.05 * k, x, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 1e-4)
    assert lat.tau_s == 0.0
    # a line of sight turning one way while the bearings lag by seconds: clipped
    big = LatencyLearner(max_s=0.5)
    for t, x2, v, y in _orbit(2.0, seed=5, seconds=60.0):
        big.observe(t, x2, [0.0, 0.0, 0.0], v, y, 0.04)  # a noise that lets it all in
    assert big.tau_s == 0.5


def test_the_state_round_trips_and_a_bad_one_names_its_field() -> None:
    lat = LatencyLearner()
    for t, x, v, y in _orbit(0.1, seed=6, seconds=10.0):
        lat.observe(t, x, [0.0, 0.0, 0.0], v, y, math.radians(0.3) ** 2)
    other = LatencyLearner()
    other.restore(lat.to_dict())
    assert other == lat
    # a state saved before the blocks' scatter was kept: restored, the scatter starts afresh
    older = LatencyLearner()
    older.restore({k: lat.to_dict()[k] for k in ("s_zw", "s_ww", "tau_s", "t_s")})
    assert (older.tau_s, older.s_ww, older.n_b) == (lat.tau_s, lat.s_ww, 0.0)
    with pytest.raises(LatencyStateError, match="tau_s"):
        other.restore({**lat.to_dict(), "tau_s": 3.0})
    with pytest.raises(LatencyStateError, match="s_zw"):
        other.restore({**lat.to_dict(), "s_zw": math.nan})
    with pytest.raises(LatencyStateError, match="malformed"):
        other.restore({"s_zw": 1.0})


def test_a_late_bearing_is_brought_forward_to_its_own_time() -> None:
    """On the orbit, the bearing 0.1 s late (0.02 rad behind) is brought within 2e-4 rad
    of the line of sight at its time; with no latency it is returned as it is."""
    om, t = 8.0 / 40.0, 3.0

    def x_at(s: float) -> np.ndarray:
        return np.array([40.0 * math.cos(om * s), 40.0 * math.sin(om * s), 10.0])

    x = x_at(t)
    v = [-8.0 * math.sin(om * t), 8.0 * math.cos(om * t), 0.0]
    late = x_at(t - 0.1) / np.linalg.norm(x_at(t - 0.1))
    los = x / np.linalg.norm(x)
    assert math.acos(float(late @ los)) > 0.019
    y = advance(late.tolist(), x.tolist(), [0.0, 0.0, 0.0], v, 0.1)
    assert abs(np.linalg.norm(y) - 1.0) < 1e-12
    assert math.acos(min(1.0, float(np.dot(y, los)))) < 2e-4
    assert advance(late.tolist(), x.tolist(), [0.0, 0.0, 0.0], v, 0.0) == pytest.approx(
        late.tolist()
    )


def test_the_line_of_sight_rate_is_the_velocity_across_the_bearing_over_the_range() -> None:
    """``w = (I - u u^T)(v + a) / r``: orthogonal to ``u``; a velocity along ``u`` turns it
    not at all, one across it at speed s and range r turns it at s / r."""
    u = [0.6, 0.8, 0.0]
    w = los_rate(u, 10.0, [0.3, 0.4, 0.0], [0.0, 0.0, 2.0])
    assert sum(w[j] * u[j] for j in range(3)) == pytest.approx(0.0, abs=1e-15)
    assert w == pytest.approx([0.0, 0.0, 0.2])
    assert los_rate(u, 5.0, [0.0] * 3, [1.2, 1.6, 0.0]) == pytest.approx([0.0] * 3, abs=1e-15)


def test_a_latency_settles_once_learning_long_enough_and_no_longer_moving() -> None:
    """Checked once per window: not before ``after_s`` of learning, not while it moved by
    ``step_s`` or more over the window, and a clock that went back restarts the window."""
    s = Settling(window_s=20.0, step_s=0.003, after_s=30.0)
    assert not s.update(0.0, 0.0, 0.0)
    assert not s.update(20.0, 0.0, 20.0)  # still: but learning for 20 s < 30 s
    assert s.update(40.0, 0.002, 40.0)  # moved 2 ms over the window
    assert s.update(55.0, 0.090, 55.0)  # mid-window: unchanged until it ends
    assert not s.update(60.0, 0.090, 60.0)  # moved 88 ms
    assert not s.update(80.0, 0.084, 80.0)  # 6 ms
    assert s.update(100.0, 0.083, 100.0)
    assert s.update(90.0, 0.2, 100.0)  # back in time: the verdict kept, the window restarts
    assert (s.t_ref_s, s.tau_ref_s) == (90.0, 0.2)
    assert s.update(105.0, 0.0, 105.0)  # mid-window: the verdict kept
    assert s.update(110.0, 0.2, 110.0)  # over the window from 90 s it did not move


def test_a_copy_of_the_settling_is_independent() -> None:
    s = Settling(window_s=20.0, step_s=0.003, after_s=30.0)
    s.update(0.0, 0.1, 40.0)
    c = s.copy()
    assert c == s
    assert c.update(25.0, 0.1, 65.0) is True
    assert s.settled is False and s.t_ref_s == 0.0


def _wandering(seed: int, *, std_s: float = 0.1, corr_s: float = 20.0, seconds: float = 180.0):
    """The orbit of :func:`_orbit` with bearings that trail the line of sight by an apparent
    latency wandering about 0 (Gauss-Markov, ``std_s``, correlated over ``corr_s``): what a
    wandering velocity bias leaves in the innovations of a filter that has not learnt the
    walk yet, a bearing error that follows the line of sight's rate with no lasting sign."""
    rng = np.random.default_rng(seed)
    om = 8.0 / 40.0
    d = rng.normal(0.0, std_s)
    f = math.exp(-0.05 / corr_s)
    for k in range(int(seconds * 20)):
        t = 0.05 * k
        d = f * d + math.sqrt(1.0 - f * f) * rng.normal(0.0, std_s)

        def x_at(s: float) -> np.ndarray:
            return np.array([40.0 * math.cos(om * s), 40.0 * math.sin(om * s), 10.0])

        v = np.array([-8.0 * math.sin(om * t), 8.0 * math.cos(om * t), 0.0])
        y = x_at(t - d)
        y = y / np.linalg.norm(y) + rng.normal(0.0, math.radians(0.3), 3)
        yield t, x_at(t).tolist(), v.tolist(), (y / np.linalg.norm(y)).tolist()


def test_a_latency_that_does_not_stand_out_of_its_blocks_scatter_is_not_used() -> None:
    """The fit follows a wandering apparent latency; the latency in use is the fit only
    where it stands out of its 10 s blocks' scatter by 2 sigma, so it stays at 0 on most
    seeds (the e2e case velocity_coloured: a spurious 0.1 s taken for a lag cost 2x)."""
    fitted, used = [], []
    for seed in range(10):
        lat = LatencyLearner()
        for t, x, v, y in _wandering(seed):
            lat.observe(t, x, [0.0, 0.0, 0.0], v, y, math.radians(0.3) ** 2)
        fitted.append(lat.tau_fit_s)
        used.append(lat.tau_s)
    assert sum(abs(f) > 0.005 for f in fitted) >= 6  # the fit strays on most seeds ...
    assert sum(u == 0.0 for u in used) >= 8  # ... the latency used does not
    assert all(abs(u) <= abs(f) for u, f in zip(used, fitted, strict=True))


def test_a_real_latency_stands_out_of_the_scatter_within_20_s_of_blocks() -> None:
    """0 until two blocks have closed, then the delay (a lag explains every block alike)."""
    lat = LatencyLearner()
    seen = []
    for t, x, v, y in _orbit(0.1, seed=7, seconds=60.0):
        lat.observe(t, x, [0.0, 0.0, 0.0], v, y, math.radians(0.3) ** 2)
        seen.append((t, lat.tau_s))
    assert all(tau == 0.0 for t, tau in seen if t < 19.9)
    assert lat.tau_s == pytest.approx(0.1, abs=0.01)
