"""The local NED frame on WGS84 (mav_observer/geodesy.py), checked against pymap3d."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.errors import InvalidSampleError
from mav_observer.geodesy import LOCAL_RADIUS_M, Origin, origin_from, to_geodetic


def _horizontal_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    dn = math.radians(lat1 - lat2) * 6.371e6
    de = math.radians(math.remainder(lon1 - lon2, 360.0)) * 6.371e6 * math.cos(math.radians(lat2))
    return math.hypot(dn, de)


@settings(max_examples=300, deadline=None)
@given(
    lat0=st.floats(-80.0, 80.0),
    lon0=st.floats(-180.0, 180.0),
    alt0=st.floats(-100.0, 4000.0),
    r=st.floats(0.0, LOCAL_RADIUS_M),
    th=st.floats(0.0, 2 * math.pi),
    d=st.floats(-500.0, 500.0),
)
def test_a_local_point_is_within_5_mm_of_pymap3d(lat0, lon0, alt0, r, th, d) -> None:
    o = Origin(lat0, lon0, alt0, "HOME_POSITION")
    ned = (r * math.cos(th), r * math.sin(th), d)
    lat, lon, alt = to_geodetic(o, ned)
    lat2, lon2, alt2 = pymap3d.ned2geodetic(*ned, lat0, lon0, alt0)
    assert _horizontal_m(lat, lon, float(lat2), float(lon2)) < 0.005
    assert abs(alt - float(alt2)) < 0.005
    assert -180.0 <= lon <= 180.0


def test_far_points_and_polar_origins_take_pymap3d_exactly() -> None:
    for o, ned in (
        (Origin(-35.36, 149.16, 584.0, "GPS_GLOBAL_ORIGIN"), (30_000.0, -12_000.0, -800.0)),
        (Origin(88.0, 10.0, 0.0, "GPS_GLOBAL_ORIGIN"), (500.0, 300.0, 0.0)),
    ):
        exact = pymap3d.ned2geodetic(*ned, o.lat_deg, o.lon_deg, o.alt_m)
        assert to_geodetic(o, ned) == pytest.approx([float(v) for v in exact], abs=1e-9)


def test_the_origin_from_a_known_point_puts_that_point_back() -> None:
    """HOME_POSITION at (-35.3629, 149.1651, 584 m) and local (120, -40, -15) m: the origin
    found maps the local point back onto the home within a millimetre."""
    o = origin_from(-35.3629, 149.1651, 584.0, (120.0, -40.0, -15.0), "HOME_POSITION")
    assert o.source == "HOME_POSITION"
    lat, lon, alt = to_geodetic(o, (120.0, -40.0, -15.0))
    assert _horizontal_m(lat, lon, -35.3629, 149.1651) < 0.001
    assert alt == pytest.approx(584.0, abs=0.001)
    # the origin is 120 m south, 40 m east and 15 m below the home
    assert _horizontal_m(o.lat_deg, o.lon_deg, -35.3629, 149.1651) == pytest.approx(
        math.hypot(120.0, 40.0),
        rel=5e-3,  # (the test's sphere, not the ellipsoid)
    )
    assert o.alt_m == pytest.approx(584.0 - 15.0, abs=0.01)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((91.0, 0.0, 0.0), "latitude 91.0"),
        ((0.0, 181.0, 0.0), "longitude 181.0"),
        ((0.0, 0.0, math.nan), "altitude nan"),
        ((0.0, 0.0, 2e5), "altitude 200000.0"),
    ],
)
def test_a_bad_origin_is_refused_naming_the_value(args, match) -> None:
    with pytest.raises(InvalidSampleError, match=match):
        Origin(*args, "HOME_POSITION")
    with pytest.raises(InvalidSampleError, match=match):
        origin_from(*args, (0.0, 0.0, 0.0), "HOME_POSITION")


def test_an_unknown_source_or_a_non_finite_local_point_is_refused() -> None:
    with pytest.raises(InvalidSampleError, match="origin source 'GPS'"):
        Origin(0.0, 0.0, 0.0, "GPS")
    with pytest.raises(InvalidSampleError, match=r"local position \[nan"):
        origin_from(0.0, 0.0, 0.0, (np.nan, 0.0, 0.0), "HOME_POSITION")
