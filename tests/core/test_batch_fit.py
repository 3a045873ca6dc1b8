"""The batch least-squares fit (mav_observer.core.batch_fit): exact recovery, consistency of its
covariance, the linear initialisation, input checks and the displacement helper."""

import math

import numpy as np
import pytest

from mav_observer.core.batch_fit import (
    NotObservableError,
    displacement_at,
    fit_batch,
    linear_init,
)
from mav_observer.errors import ConfigError, InvalidSampleError
from sim import scenarios
from sim.stream import perturb_bearings


def exact_data(sc: scenarios.Scenario, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True relative positions, bearings and displacements ``D = x - x0 - a (t - t0)``."""
    x = sc.x(t)
    y = x / np.linalg.norm(x, axis=1, keepdims=True)
    d = x - x[0] - np.outer(t - t[0], sc.a_mps)
    return x, y, d


def test_noise_free_orbit_is_recovered_exactly() -> None:
    sc = scenarios.orbit()
    t = np.arange(0.0, 300.0, 0.1)
    x, y, d = exact_data(sc, t)
    fit = fit_batch(t, y, d)
    assert fit.converged and fit.method == "gauss_newton"
    assert np.linalg.norm(fit.x0_ned_m - x[0]) < 1e-6
    assert np.linalg.norm(fit.a_ned_mps - sc.a_mps) < 1e-6
    assert np.max(np.linalg.norm(fit.rel_pos_at() - x, axis=1)) < 1e-6
    assert fit.residual_rms_rad < 1e-9
    # between bearing times, D interpolated linearly: exact at them, close between
    assert np.allclose(fit.rel_pos_at(t[10]), x[10], atol=1e-6)
    assert np.allclose(fit.rel_pos_at(np.array([5.05])), sc.x(np.array([5.05])), atol=0.01)
    assert fit.covariance.shape == (6, 6)
    assert np.allclose(fit.covariance, fit.covariance.T)


def test_noise_free_with_integrated_velocity() -> None:
    """D from :func:`displacement_at` on 50 Hz velocity (trapezoid): a few mm off at most."""
    sc = scenarios.moving_target()
    t = np.arange(0.0, 200.0, 0.1)
    x, y, _ = exact_data(sc, t)
    tv = np.arange(-0.5, 200.5, 0.02)
    d = displacement_at(t, tv, -sc.v(tv))
    fit = fit_batch(t, y, d)
    assert np.linalg.norm(fit.x0_ned_m - x[0]) < 0.01
    assert np.linalg.norm(fit.a_ned_mps - sc.a_mps) < 1e-3


def test_covariance_is_consistent_with_the_errors() -> None:
    """50 seeded runs of the orbit at 0.5 deg noise: the normalised estimation error squared
    (6 degrees of freedom) averages about 6, and the residual RMS is sigma."""
    sc = scenarios.orbit()
    t = np.arange(0.0, 120.0, 0.2)
    x, y, d = exact_data(sc, t)
    sigma = math.radians(0.5)
    rng = np.random.default_rng(7)
    nees, rms = [], []
    for _ in range(50):
        yn = perturb_bearings(y, sigma, rng)
        fit = fit_batch(t, yn, d, sigma_rad=sigma)
        assert fit.converged
        err = np.concatenate((fit.x0_ned_m - x[0], fit.a_ned_mps - sc.a_mps))
        nees.append(err @ np.linalg.solve(fit.covariance, err))
        rms.append(fit.residual_rms_rad)
    assert 0.7 < np.mean(nees) / 6.0 < 1.4
    assert abs(np.mean(rms) / sigma - 1.0) < 0.05
    # the residual-scaled covariance agrees when sigma is right
    fit_r = fit_batch(t, yn, d, sigma_rad=sigma, covariance_from="residuals")
    ratio = np.diag(fit_r.covariance) / np.diag(fit.covariance)
    assert np.allclose(ratio, ratio[0]) and 0.8 < ratio[0] < 1.2


def test_gauss_newton_beats_the_linear_initialisation() -> None:
    """A weaving follow of a moving target (range 13 m to 27 m) at 2 deg: the linear
    pseudo-measurements weigh far bearings more and are biased by the noise; Gauss-Newton on
    the angles is markedly better on average (0.10 m against 0.22 m measured). With no
    iteration the fit is the linear solution."""
    sc = scenarios.moving_target()
    t = np.arange(0.0, 120.0, 0.1)
    x, y, d = exact_data(sc, t)
    sigma = math.radians(2.0)
    rng = np.random.default_rng(3)
    err_lin, err_gn = [], []
    for _ in range(30):
        yn = perturb_bearings(y, sigma, rng)
        lin = linear_init(t, yn, d)
        fit = fit_batch(t, yn, d, sigma_rad=sigma)
        err_lin.append(np.linalg.norm(lin[:3] - x[0]))
        err_gn.append(np.linalg.norm(fit.x0_ned_m - x[0]))
    assert np.mean(err_gn) < 0.7 * np.mean(err_lin)
    only = fit_batch(t, yn, d, sigma_rad=sigma, max_iterations=0)
    assert only.method == "linear" and only.iterations == 0
    assert np.allclose(np.concatenate((only.x0_ned_m, only.a_ned_mps)), linear_init(t, yn, d))


def test_huber_resists_outliers() -> None:
    sc = scenarios.orbit()
    t = np.arange(0.0, 120.0, 0.2)
    x, y, d = exact_data(sc, t)
    sigma = math.radians(0.5)
    rng = np.random.default_rng(0)
    yn = perturb_bearings(y, sigma, rng)
    bad = rng.choice(len(t), 60, replace=False)  # 10 % wild bearings, 10 deg noise
    yn[bad] = perturb_bearings(yn[bad], math.radians(10.0), rng)
    plain = fit_batch(t, yn, d, sigma_rad=sigma)
    robust = fit_batch(t, yn, d, sigma_rad=sigma, huber_k=1.345)
    e_plain = np.linalg.norm(plain.x0_ned_m - x[0])
    e_robust = np.linalg.norm(robust.x0_ned_m - x[0])
    assert e_robust < 0.3 * e_plain
    assert np.all(robust.weights[bad] < 0.5)


@pytest.mark.parametrize(
    ("kwargs", "exc", "words"),
    [
        ({"t_s": [0.0, 1.0, 1.0, 2.0]}, InvalidSampleError, "t_s must be increasing"),
        ({"t_s": [0.0, 1.0, math.nan, 3.0]}, InvalidSampleError, "t_s[2] is not finite"),
        ({"bearings": [[1, 0, 0]] * 3 + [[2, 0, 0]]}, InvalidSampleError, "bearings[3]"),
        ({"bearings": [[1, 0, 0]] * 3}, InvalidSampleError, "bearings must have shape"),
        ({"displacement_ned_m": [[0, 0, math.inf]] * 4}, InvalidSampleError, "displacement"),
        ({"sigma_rad": 0.0}, ConfigError, "sigma_rad"),
        ({"huber_k": -1.0}, ConfigError, "huber_k"),
        ({"covariance_from": "guess"}, ConfigError, "covariance_from"),
        ({"max_iterations": -1}, ConfigError, "max_iterations"),
    ],
)
def test_bad_input_is_named(kwargs: dict, exc: type, words: str) -> None:
    args = {
        "t_s": [0.0, 1.0, 2.0, 3.0],
        "bearings": [[1.0, 0.0, 0.0]] * 4,
        "displacement_ned_m": [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0], [0, 3.0, 0]],
    }
    args.update(kwargs)
    with pytest.raises(exc, match=None) as info:
        fit_batch(args.pop("t_s"), args.pop("bearings"), args.pop("displacement_ned_m"), **args)
    assert words in str(info.value)


def test_no_motion_is_not_observable() -> None:
    t = np.arange(10.0)
    y = np.tile([0.6, 0.0, 0.8], (10, 1))
    with pytest.raises(NotObservableError, match="too little motion"):
        fit_batch(t, y, np.zeros((10, 3)))


def test_trapezoid_is_exact_for_a_linear_velocity() -> None:
    """Irregular velocity samples, bearings between them and before the first velocity
    sample (the velocity held there)."""
    tv = np.array([0.0, 0.5, 1.0, 2.5, 3.0])
    u = np.column_stack((1.0 + 2.0 * tv, -tv, np.full_like(tv, 0.5)))
    tb = np.array([0.2, 0.7, 1.9, 2.9])

    def integral(t: np.ndarray) -> np.ndarray:  # of u
        return np.column_stack((t + t**2, -(t**2) / 2, 0.5 * t))

    d = displacement_at(tb, tv, u)
    assert np.allclose(d, -(integral(tb) - integral(tb[:1])), atol=1e-12)
    d2 = displacement_at(np.array([-1.0, 0.0, 1.0]), tv, u)
    assert np.allclose(d2[1], -u[0])  # held before the first sample
    assert np.allclose(d2[2] - d2[1], -(integral(np.array([1.0]))[0]))


def circle(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle circling (radius 15 m, 40 s a lap): position and velocity."""
    r, om = 15.0, 2.0 * math.pi / 40.0
    p = np.column_stack((r * np.cos(om * t), r * np.sin(om * t), np.full_like(t, -10.0)))
    v = np.column_stack((-r * om * np.sin(om * t), r * om * np.cos(om * t), np.zeros_like(t)))
    return p, v


def test_sparse_positions_keep_a_constant_velocity_error_in_a() -> None:
    """1 Hz velocity with a constant error e and true positions: the position path follows the
    true motion closely (the trapezoid on 1 Hz samples does not), the error e stays in the
    displacement (x' = -u_meas + e), and the fit finds a = +e."""
    e = np.array([1.0, -0.5, 0.2])
    target = np.array([5.0, 3.0, 0.0])
    tv = np.arange(0.0, 200.01, 1.0)
    p, v = circle(tv)
    u_meas = v + e
    tb = np.arange(0.05, 199.9, 0.1)
    x = target - circle(tb)[0]
    d_true = x - x[0] - np.outer(tb - tb[0], e)
    d_pos = displacement_at(tb, tv, u_meas, p)
    d_trap = displacement_at(tb, tv, u_meas)
    assert np.max(np.abs(d_pos - d_true)) < 0.002
    assert np.max(np.abs(d_trap - d_true)) > 10 * np.max(np.abs(d_pos - d_true))
    y = x / np.linalg.norm(x, axis=1, keepdims=True)
    fit = fit_batch(tb, y, d_pos)
    assert np.allclose(fit.a_ned_mps, e, atol=1e-4)
    assert np.linalg.norm(fit.x0_ned_m - x[0]) < 0.01
    # an EKF position reset (8 m jump in one interval): that interval keeps the trapezoid
    p_reset = p.copy()
    p_reset[100:] += [8.0, 0.0, 0.0]
    d_reset = displacement_at(tb, tv, u_meas, p_reset)
    assert np.max(np.abs(d_reset - d_true)) < 0.02


def test_displacement_input_checks() -> None:
    with pytest.raises(InvalidSampleError, match="t_vel must be increasing"):
        displacement_at([0.0], [0.0, 0.0], np.zeros((2, 3)))
    with pytest.raises(InvalidSampleError, match="vel_ned_mps must have shape"):
        displacement_at([0.0], [0.0, 1.0], np.zeros((3, 3)))
    with pytest.raises(InvalidSampleError, match=r"pos_ned_m\[1\] is not finite"):
        displacement_at([0.0], [0.0, 1.0], np.zeros((2, 3)), [[0, 0, 0], [0, math.nan, 0]])
