"""The geodetic ray: its JSON form and the refusals at the boundary."""

from __future__ import annotations

import json

import pytest

from mav_observer.fleet.rays import InvalidRayError, Ray, ray_from_dict, ray_from_json


def ray(**over: object) -> dict:
    d = Ray(
        sysid=2, target="gimbal", t_unix_s=1.7e9, t_boot_s=120.5, clock="autopilot",
        lat_deg=-35.36, lon_deg=149.16, alt_m=604.0, los_ned=(0.6, 0.0, 0.8),
        sigma_rad=0.0087, vel_ned_mps=(1.0, 0.0, 0.0), clock_offset_s=0.02,
    ).to_dict()  # fmt: skip
    d.update(over)
    return d


def test_a_ray_goes_through_its_json_unchanged() -> None:
    r = ray_from_json(json.dumps(ray()))
    assert r.key == "2/gimbal" and r.los_ned == (0.6, 0.0, 0.8) and r.clock == "autopilot"
    assert ray_from_dict(r.to_dict()) == r


@pytest.mark.parametrize(
    ("field", "value", "says"),
    [
        ("sysid", 0, "sysid"),
        ("target", "a/b", "target"),
        ("clock", "gps", "clock"),
        ("lat_deg", 95.0, "latitude"),
        ("alt_m", float("nan"), "alt_m"),
        ("los_ned", [1.0, 1.0, 0.0], "unit"),
        ("los_ned", [1.0, 0.0], "3 numbers"),
        ("sigma_rad", 0.0, "sigma_rad"),
        ("range_m", -1.0, "range_m"),
    ],
)
def test_a_bad_field_is_refused_by_name(field: str, value: object, says: str) -> None:
    with pytest.raises(InvalidRayError, match=says):
        ray_from_dict(ray(**{field: value}))


def test_a_payload_that_is_not_json_is_refused() -> None:
    with pytest.raises(InvalidRayError, match="not JSON"):
        ray_from_json(b"\xff{")
    with pytest.raises(InvalidRayError, match="not an object"):
        ray_from_json("[1, 2]")
