"""The fusion of several vehicles' rays: maximum likelihood on the angles, its covariance the
joint bound, on WGS84, robust, bounded."""

from __future__ import annotations

import math

import numpy as np
import pymap3d

from mav_observer.fleet.fusion import FusedTarget
from mav_observer.fleet.rays import Ray

ANCHOR = (-35.363261, 149.165230, 584.0)
TARGET_NED = np.array([40.0, 30.0, 0.0])
SIGMA = math.radians(0.5)


def make_ray(
    sysid: int, vehicle_ned: np.ndarray, rng: np.random.Generator | None, t: float,
    *, sigma: float = SIGMA, outlier_deg: float = 0.0, vel: tuple | None = None,
    range_m: float | None = None, target: np.ndarray = TARGET_NED,
) -> Ray:  # fmt: skip
    """A ray from a vehicle at ``vehicle_ned`` (the anchor's WGS84 NED, exact) toward the
    target, its line of sight in the vehicle's own NED, with Gaussian noise across it."""
    lat, lon, alt = pymap3d.ned2geodetic(*vehicle_ned, *ANCHOR)
    tl, to, ta = pymap3d.ned2geodetic(*target, *ANCHOR)
    x, y, z = pymap3d.geodetic2ecef(tl, to, ta)
    xv, yv, zv = pymap3d.geodetic2ecef(lat, lon, alt)
    los = np.array(pymap3d.ecef2nedv(x - xv, y - yv, z - zv, lat, lon))
    los /= np.linalg.norm(los)
    a = np.cross(los, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(los, a)
    if rng is not None:
        n = rng.normal(0.0, sigma, 2)
        if outlier_deg:
            n = n + math.radians(outlier_deg) * np.array([1.0, 0.0])
        los = los + n[0] * a + n[1] * b
        los /= np.linalg.norm(los)
    return Ray(sysid=sysid, target="gimbal", t_unix_s=t, t_boot_s=100.0 + t, clock="autopilot",
               lat_deg=float(lat), lon_deg=float(lon), alt_m=float(alt),
               los_ned=tuple(float(c) for c in los), sigma_rad=sigma, vel_ned_mps=vel,
               range_m=range_m)  # fmt: skip


def hover_pair(az2_deg: float = 75.0) -> tuple[np.ndarray, np.ndarray]:
    def at(az: float) -> np.ndarray:
        a = math.radians(az)
        return TARGET_NED + np.array([50.0 * math.cos(a), 50.0 * math.sin(a), -20.0])

    return at(180.0), at(180.0 + az2_deg)


def error(ft: FusedTarget, t: float) -> tuple[np.ndarray, np.ndarray, str]:
    est = ft.estimate(t)
    truth = ft.to_anchor_ned(*pymap3d.ned2geodetic(*TARGET_NED, *ANCHOR))
    assert est.pos_ned_m is not None and est.cov_ned_m2 is not None, est.status
    return np.asarray(est.pos_ned_m) - truth, np.asarray(est.cov_ned_m2), est.status


def test_two_hovering_vehicles_locate_the_target_at_their_first_pair() -> None:
    v1, v2 = hover_pair()
    ft = FusedTarget("t", ["1/gimbal", "2/gimbal"])
    rng = np.random.default_rng(1)
    assert ft.add(make_ray(1, v1, rng, 0.0), 0.0)
    assert ft.estimate(0.0).status in ("waiting", "unobservable")  # one ray: no range
    ft.add(make_ray(2, v2, rng, 0.01), 0.01)
    e, cov, status = error(ft, 0.01)
    assert status == "converged"  # 1-sigma under 2 % of the 54 m range at once
    assert float(e @ np.linalg.solve(cov, e)) < 16.0


def test_the_fused_error_matches_its_covariance_and_the_joint_bound_over_many_runs() -> None:
    v1, v2 = hover_pair()
    sq, tr, nees = [], [], []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        ft = FusedTarget("t", ["1/gimbal", "2/gimbal"])
        for i in range(60):
            ft.add(make_ray(1 + i % 2, v1 if i % 2 == 0 else v2, rng, 0.05 * i), 0.05 * i)
        e, cov, _ = error(ft, 3.0)
        sq.append(float(e @ e))
        tr.append(float(np.trace(cov)))
        nees.append(float(np.mean(e**2 / np.diag(cov))))
    ratio = math.sqrt(sum(sq) / sum(tr))
    assert 0.8 < ratio < 1.25, ratio
    assert 0.5 < float(np.mean(nees)) < 1.6


def test_the_points_are_placed_on_the_ellipsoid_not_a_sphere() -> None:
    """Without noise the fused point is the target to a millimetre: the vehicles' positions
    go through ECEF exactly (a spherical shortcut puts it centimetres off at 50 m)."""
    v1, v2 = hover_pair()
    ft = FusedTarget("t", ["1/gimbal", "2/gimbal"])
    for i in range(10):
        ft.add(make_ray(1 + i % 2, v1 if i % 2 == 0 else v2, None, 0.1 * i), 0.1 * i)
    e, _cov, _ = error(ft, 1.0)
    assert np.max(np.abs(e)) < 1e-3


def test_one_hovering_vehicle_alone_cannot_tell_the_range_but_one_moving_can() -> None:
    rng = np.random.default_rng(2)
    v1, _ = hover_pair()
    still = FusedTarget("t", ["1/gimbal"])
    for i in range(50):
        still.add(make_ray(1, v1, rng, 0.1 * i), 0.1 * i)
    assert still.estimate(5.0).pos_ned_m is None
    assert still.estimate(5.0).status == "unobservable"
    moving = FusedTarget("t", ["1/gimbal"])
    for i in range(200):
        a = 0.05 * i
        moving.add(make_ray(1, v1 + 15.0 * np.array([math.cos(a), math.sin(a), 0.0]), rng, a), a)
    e, cov, _ = error(moving, 10.0)
    assert float(e @ np.linalg.solve(cov, e)) < 16.0


def test_a_range_with_the_bearing_makes_one_hovering_vehicle_enough() -> None:
    rng = np.random.default_rng(3)
    v1, _ = hover_pair()
    ft = FusedTarget("t", ["1/gimbal"])
    r = float(np.linalg.norm(TARGET_NED - v1))
    for i in range(20):
        ft.add(make_ray(1, v1, rng, 0.1 * i, range_m=r + rng.normal(0, 0.3)), 0.1 * i)
    e, cov, status = error(ft, 2.0)
    assert status in ("converging", "converged")
    assert float(e @ np.linalg.solve(cov, e)) < 16.0


def test_gross_outliers_are_absorbed() -> None:
    v1, v2 = hover_pair()
    rng = np.random.default_rng(4)
    ft = FusedTarget("t", ["1/gimbal", "2/gimbal"])
    for i in range(400):
        bad = 20.0 if i % 20 == 7 else 0.0  # 5 % of the rays 20 deg off
        ft.add(make_ray(1 + i % 2, v1 if i % 2 == 0 else v2, rng, 0.05 * i, outlier_deg=bad), i)
    e, cov, _ = error(ft, 400.0)
    assert float(e @ np.linalg.solve(cov, e)) < 16.0
    assert ft.outliers >= 15


def test_a_vehicle_that_goes_quiet_keeps_its_rays_and_is_listed_inactive() -> None:
    v1, v2 = hover_pair()
    rng = np.random.default_rng(5)
    ft = FusedTarget("t", ["1/gimbal", "2/gimbal"], stale_after_s=2.0)
    for i in range(100):
        ft.add(make_ray(1 + i % 2, v1 if i % 2 == 0 else v2, rng, 0.05 * i), 0.05 * i)
    for i in range(100, 200):
        ft.add(make_ray(1, v1, rng, 0.05 * i), 0.05 * i)  # vehicle 2 lost
    e, cov, status = error(ft, 10.0)
    assert status == "converged" and float(e @ np.linalg.solve(cov, e)) < 16.0
    active = {v["key"]: v["active"] for v in ft.estimate(10.0).vehicles}
    assert active == {"1/gimbal": True, "2/gimbal": False}


def test_a_long_run_folds_its_oldest_rays_into_a_prior_without_losing_them() -> None:
    v1, v2 = hover_pair()
    rays = []
    rng = np.random.default_rng(6)
    for i in range(600):
        rays.append(make_ray(1 + i % 2, v1 if i % 2 == 0 else v2, rng, 0.05 * i))
    full, folded = FusedTarget("t", ["1/gimbal", "2/gimbal"]), FusedTarget(
        "t", ["1/gimbal", "2/gimbal"], max_rays=90
    )
    for r in rays:
        full.add(r, r.t_unix_s)
        folded.add(r, r.t_unix_s)
    e1, c1, _ = error(full, 30.0)
    e2, c2, _ = error(folded, 30.0)
    assert folded.estimate(30.0).rays == 600
    assert np.max(np.abs(e1 - e2)) < 0.35 * math.sqrt(np.max(np.diag(c1)))
    assert np.allclose(np.diag(c1), np.diag(c2), rtol=0.1)


def test_each_vehicles_velocity_bias_is_the_drift_of_its_positions_from_its_velocities() -> None:
    rng = np.random.default_rng(7)
    v1, v2 = hover_pair()
    ft = FusedTarget("t", ["1/gimbal", "2/gimbal"])
    bias = np.array([2.0, -1.0, 0.0])  # true minus measured
    for i in range(100):
        t = 0.1 * i
        pos = v1 + np.array([1.0, 0.5, 0.0]) * t  # flying 1.1 m/s
        ft.add(make_ray(1, pos, rng, t, vel=tuple(np.array([1.0, 0.5, 0.0]) - bias)), t)
        ft.add(make_ray(2, v2, rng, t, vel=(0.0, 0.0, 0.0)), t)
    est = {v["key"]: v for v in ft.estimate(10.0).vehicles}
    assert np.allclose(est["1/gimbal"]["vel_bias_ned_mps"], bias, atol=0.01)
    assert np.allclose(est["2/gimbal"]["vel_bias_ned_mps"], 0.0, atol=0.01)


def test_a_ray_of_another_vehicle_target_is_not_taken() -> None:
    ft = FusedTarget("t", ["1/gimbal"])
    v1, _ = hover_pair()
    assert not ft.add(make_ray(3, v1, None, 0.0), 0.0)
    assert ft.estimate(0.0).rays == 0
