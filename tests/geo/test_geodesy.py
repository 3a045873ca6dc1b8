"""The local NED frame on WGS84 (mav_observer/geo/geodesy.py), checked against pymap3d."""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.errors import InvalidSampleError
from mav_observer.geo.geodesy import (
    LOCAL_RADIUS_M,
    Origin,
    OriginMean,
    origin_from,
    shifted,
    to_geodetic,
)


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


def test_a_shifted_origin_moves_every_point_by_the_shift() -> None:
    o = Origin(-35.363261, 149.16523, 584.0, "GLOBAL_POSITION_INT")
    s = shifted(o, 3e-8, -4e-8, 0.002)
    assert (s.lat_deg, s.lon_deg, s.alt_m) == pytest.approx((-35.36326097, 149.16522996, 584.002))
    for ned in ((0.0, 0.0, 0.0), (40.0, 30.0, -12.0), (-900.0, 1500.0, 80.0)):
        a, b = to_geodetic(o, ned), to_geodetic(s, ned)
        exact = pymap3d.ned2geodetic(*ned, s.lat_deg, s.lon_deg, s.alt_m)
        assert (b[0] - a[0], b[1] - a[1], b[2] - a[2]) == pytest.approx(
            (3e-8, -4e-8, 0.002), abs=1e-11
        )
        assert _horizontal_m(b[0], b[1], float(exact[0]), float(exact[1])) < 0.005


def test_the_mean_of_rounded_pairs_places_the_origin_nearer_than_one() -> None:
    """A vehicle flying a 60 m circle reports GLOBAL_POSITION_INT rounded to 1e-7 deg and 1 mm
    with its exact local position: the first pair puts the origin millimetres off, the mean of
    500 pairs within a millimetre."""
    lat0, lon0, alt0 = -35.36326123, 149.16523047, 584.0
    rng = np.random.default_rng(7)
    mean: OriginMean | None = None
    first_m = 0.0
    for k in range(500):
        th = 0.013 * k
        ned = (60.0 * math.cos(th) + rng.normal(0, 0.3), 60.0 * math.sin(th), -20.0 - 0.0137 * k)
        lat, lon, alt = (float(v) for v in pymap3d.ned2geodetic(*ned, lat0, lon0, alt0))
        lat, lon, alt = round(lat * 1e7) * 1e-7, round(lon * 1e7) * 1e-7, round(alt * 1e3) * 1e-3
        if mean is None:
            o = origin_from(lat, lon, alt, ned, "GLOBAL_POSITION_INT")
            mean = OriginMean(o)
            first_m = _horizontal_m(o.lat_deg, o.lon_deg, lat0, lon0)
        else:
            mean.add(lat, lon, alt, ned)
    o = mean.origin
    assert mean.n == 500 and o.source == "GLOBAL_POSITION_INT"
    assert first_m > 0.002  # this first pair: 2 mm or more off
    assert _horizontal_m(o.lat_deg, o.lon_deg, lat0, lon0) < 0.0007
    assert abs(o.alt_m - alt0) < 0.0002


# The shared SITL log's region of interest (../shared/tlogs/ardupilot_sitl_servo_mount_roi.json):
# home and the point 40 m north and 30 m east of it, as ArduPilot's Location::offset gave them.
SITL_HOME = (-35.363261, 149.1652299, 584.08)
SITL_ROI = (-35.362901673886356, 149.16556036583896)


def test_the_ardupilot_frame_places_a_point_as_ardupilot_does() -> None:
    o = Origin(*SITL_HOME, "HOME_POSITION", "ardupilot")
    lat, lon, alt = to_geodetic(o, (40.0, 30.0, -2.0))
    assert _horizontal_m(lat, lon, *SITL_ROI) < 0.001 and alt == pytest.approx(586.08)
    # the ellipsoid puts it 13-14 cm off (0.34 % of 40 m north at 35 deg south)
    w = to_geodetic(Origin(*SITL_HOME, "HOME_POSITION"), (40.0, 30.0, -2.0))
    assert 0.12 < _horizontal_m(w[0], w[1], *SITL_ROI) < 0.15


def test_the_px4_frame_is_azimuthal_equidistant_on_its_sphere() -> None:
    # every point is at its local distance from the origin along the great circle of its
    # local bearing, on a sphere of 6,371,000 m
    o = Origin(47.397742, 8.545594, 488.0, "GPS_GLOBAL_ORIGIN", "px4")
    for n, e in ((0.0, 0.0), (1500.0, -800.0), (-20.0, 35.0), (0.0, 3000.0)):
        lat, lon, alt = to_geodetic(o, (n, e, -10.0))
        p1, p2 = math.radians(o.lat_deg), math.radians(lat)
        dl = math.radians(lon - o.lon_deg)
        h = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
        assert 2 * math.asin(math.sqrt(h)) * 6371000.0 == pytest.approx(math.hypot(n, e), abs=1e-6)
        if n or e:
            y = math.sin(dl) * math.cos(p2)
            x = math.cos(p1) * math.sin(p2) - math.sin(p1) * math.cos(p2) * math.cos(dl)
            az = math.atan2(y, x)
            assert math.remainder(az - math.atan2(e, n), 2 * math.pi) == pytest.approx(
                0.0, abs=1e-9
            )
        assert alt == pytest.approx(498.0)


@pytest.mark.parametrize("frame", ["wgs84", "ardupilot", "px4"])
def test_the_origin_from_a_known_point_puts_it_back_in_each_frame(frame) -> None:
    o = origin_from(-35.3629, 149.1651, 584.0, (620.0, -340.0, -15.0), "HOME_POSITION", frame)
    assert o.frame == frame
    lat, lon, alt = to_geodetic(o, (620.0, -340.0, -15.0))
    assert _horizontal_m(lat, lon, -35.3629, 149.1651) < 1e-4 and alt == pytest.approx(584.0)
    s = shifted(o, 1e-7, 0.0, 0.0)
    assert s.frame == frame and to_geodetic(s, (620.0, -340.0, -15.0))[0] == pytest.approx(
        lat + 1e-7, abs=1e-12
    )


def test_an_unknown_frame_is_refused_naming_it() -> None:
    with pytest.raises(InvalidSampleError, match="origin frame 'nad83'"):
        Origin(0.0, 0.0, 0.0, "HOME_POSITION", "nad83")
    with pytest.raises(InvalidSampleError, match="origin frame 'enu'"):
        origin_from(0.0, 0.0, 0.0, (1.0, 0.0, 0.0), "HOME_POSITION", "enu")


def _ardupilot_point(lat0: float, lon0: float, alt0: float, ned) -> tuple[float, float, float]:
    # ArduPilot's Location::offset, from its source (libraries/AP_Common/Location.cpp),
    # rounded as GLOBAL_POSITION_INT rounds it
    k = 0.011131884502145034  # LOCATION_SCALING_FACTOR, m per 1e-7 deg
    dlat = ned[0] / k
    dlon = ned[1] / k / math.cos(math.radians(lat0 + 0.5e-7 * dlat))
    return round((lat0 + 1e-7 * dlat) * 1e7) * 1e-7, round((lon0 + 1e-7 * dlon) * 1e7) * 1e-7, alt0


def test_the_vote_tells_the_frame_once_the_pairs_spread_and_not_before() -> None:
    from mav_observer.geo.geodesy import FRAME_PAIRS, FrameVote

    home = (-35.363261, 149.1652299, 584.08)
    vote = FrameVote.start(*home, (0.0, 0.0, 0.0), "GPS_GLOBAL_ORIGIN")
    for k in range(200):  # hovering within a metre: the frames cannot be told apart
        ned = (0.5 * math.sin(0.1 * k), 0.5 * math.cos(0.1 * k), -10.0)
        vote.add(*_ardupilot_point(*home, ned), ned)
    assert vote.choice("wgs84") == ("wgs84", False)
    for k in range(FRAME_PAIRS):  # then out along a 40 m line and back
        ned = (40.0 * math.sin(0.1 * k), 25.0 * math.sin(0.1 * k), -10.0)
        vote.add(*_ardupilot_point(*home, ned), ned)
    assert vote.choice("wgs84")[0] == "ardupilot"
    scatter = {f: m.scatter_m() for f, m in vote.means.items()}
    assert scatter["ardupilot"] < 0.005 and scatter["wgs84"] > 0.01
    for k in range(200):
        ned = (40.0 * math.sin(0.05 * k), 40.0 * (1 - math.cos(0.05 * k)), -10.0)
        vote.add(*_ardupilot_point(*home, ned), ned)
    assert vote.choice("wgs84") == ("ardupilot", True)
