"""A bearing the tracker used as a geodetic ray: where the vehicle was, on which clock."""

from __future__ import annotations

import math

from mav_observer.fleet.rays import Ray
from mav_observer.geo.geodesy import Origin, to_geodetic
from mav_observer.tracking.rays import ray_of
from mav_observer.tracking.vehicle import Vehicle

NOISE = math.radians(0.5) ** 2  # the estimator's bearing noise variance (rad^2)
ORIGIN = Origin(-35.36, 149.16, 584.0, "GPS_GLOBAL_ORIGIN", "ardupilot")


def vehicle() -> Vehicle:
    veh = Vehicle(sysid=3, targets=None)  # type: ignore[arg-type]
    veh.origin = ORIGIN
    # flying north at 2 m/s while its velocity reads 4 m/s (a 2 m/s bias)
    for t in (10.0, 10.1):
        fix = (t, (2.0 * (t - 10.0), 0.0, -20.0), (4.0, 0.0, 0.0))
        veh.positions.append(fix)
        veh.position = fix
    return veh


def test_the_position_is_moved_on_by_the_positions_own_velocity_not_the_biased_one() -> None:
    out: list[Ray] = []
    ray_of(out, vehicle(), "gimbal", (10.15, 1e9), [1.0, 0.0, 0.0], NOISE)
    (r,) = out
    lat, lon, alt = to_geodetic(ORIGIN, (0.3, 0.0, -20.0))  # 0.2 + 2 m/s x 0.05 s
    assert abs(r.lat_deg - lat) < 1e-9 and abs(r.lon_deg - lon) < 1e-9 and abs(r.alt_m - alt) < 1e-6
    assert r.clock == "service" and r.t_unix_s == 1e9  # no SYSTEM_TIME Unix time yet
    assert r.vel_ned_mps == (4.0, 0.0, 0.0) and abs(r.sigma_rad - 0.0087266) < 1e-6


def test_the_autopilots_unix_time_is_used_when_it_has_one_and_its_offset_stated() -> None:
    veh = vehicle()
    veh.unix_minus_boot_s = 1.7e9
    out: list[Ray] = []
    ray_of(out, veh, "gimbal", (10.1, 1.7e9 + 10.05), [0.0, 1.0, 0.0], NOISE)
    assert out[0].clock == "autopilot" and out[0].t_unix_s == 1.7e9 + 10.1
    assert abs(out[0].clock_offset_s - 0.05) < 1e-6  # type: ignore[operator]


def test_no_ray_without_an_origin_or_a_recent_position() -> None:
    out: list[Ray] = []
    veh = vehicle()
    ray_of(out, veh, "gimbal", (30.0, 0.0), [1.0, 0.0, 0.0], NOISE)  # position 20 s old
    veh.origin = None
    ray_of(out, veh, "gimbal", (10.1, 0.0), [1.0, 0.0, 0.0], NOISE)
    assert out == []
