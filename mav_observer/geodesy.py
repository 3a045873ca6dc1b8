"""The autopilot's local NED frame on the WGS84 ellipsoid: its origin, and positions in it as
latitude, longitude and altitude (``docs/geolocation.md``).

LOCAL_POSITION_NED's ``x, y, z`` are north, east and down from an origin the autopilot chose
(ArduPilot: the EKF origin, PX4: the local reference). Where that origin is comes from, in
order of preference (:data:`ORIGIN_SOURCES`):

* ``GPS_GLOBAL_ORIGIN``: the origin itself;
* ``HOME_POSITION``: the home's latitude, longitude and altitude and its local ``x, y, z``;
* ``GLOBAL_POSITION_INT``: the vehicle's latitude, longitude and altitude at the same
  ``time_boot_ms`` as a LOCAL_POSITION_NED sample.

Altitudes are AMSL (MAVLink's ``altitude``/``alt`` fields) and are carried as heights along
the origin's normal: over the few kilometres of a flight the geoid's slope is far below a
millimetre per metre. A local point's conversion is pymap3d's ``ned2geodetic`` expanded
to second order around the origin (:func:`to_geodetic`; the expansion from pymap3d once per
origin): within 5 mm of pymap3d up to :data:`LOCAL_RADIUS_M` from the origin and
:data:`LOCAL_MAX_LAT_DEG` of latitude (``tests/test_geodesy.py``), at 3 us instead of 85;
farther, pymap3d's exact conversion. No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mav_observer.errors import InvalidSampleError

#: Where an origin came from, most trusted first.
ORIGIN_SOURCES = ("GPS_GLOBAL_ORIGIN", "HOME_POSITION", "GLOBAL_POSITION_INT")
#: Horizontal distance from the origin (m) within which the local expansion is used.
LOCAL_RADIUS_M = 2000.0
#: Latitude (deg, either way) beyond which pymap3d's exact conversion is always used.
LOCAL_MAX_LAT_DEG = 80.0


def check_geodetic(lat_deg: float, lon_deg: float, alt_m: float, what: str) -> None:
    """Raise :class:`InvalidSampleError` naming ``what`` for a latitude outside [-90, 90]
    deg, a longitude outside [-180, 180] deg or an altitude outside [-1,000, 100,000] m (or
    any non-finite value)."""
    if not (math.isfinite(lat_deg) and -90.0 <= lat_deg <= 90.0):
        raise InvalidSampleError(f"{what}: latitude {lat_deg!r} deg is not within [-90, 90]")
    if not (math.isfinite(lon_deg) and -180.0 <= lon_deg <= 180.0):
        raise InvalidSampleError(f"{what}: longitude {lon_deg!r} deg is not within [-180, 180]")
    if not (math.isfinite(alt_m) and -1000.0 <= alt_m <= 100_000.0):
        raise InvalidSampleError(f"{what}: altitude {alt_m!r} m is not within [-1000, 100000]")


@dataclass(frozen=True)
class Origin:
    """The local NED frame's origin: WGS84 latitude and longitude (deg), altitude AMSL (m),
    and the message it came from (one of :data:`ORIGIN_SOURCES`)."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    source: str
    #: (lat, lon, alt) at the origin and their gradients and Hessians in (n, e, d), from
    #: pymap3d (:func:`_quadratic`), made when first needed (:attr:`model`): an origin
    #: no estimate is placed in costs nothing
    _model: tuple[tuple[float, ...], ...] | None = field(
        init=False, repr=False, compare=False, default=None
    )

    def __post_init__(self) -> None:
        check_geodetic(self.lat_deg, self.lon_deg, self.alt_m, f"origin from {self.source}")
        if self.source not in ORIGIN_SOURCES:
            raise InvalidSampleError(
                f"origin source {self.source!r} is not one of {ORIGIN_SOURCES}"
            )

    @property
    def model(self) -> tuple[tuple[float, ...], ...]:
        """The second-order expansion of pymap3d's conversion at the origin (made once)."""
        m = self._model
        if m is None:
            m = _quadratic(self.lat_deg, self.lon_deg, self.alt_m)
            object.__setattr__(self, "_model", m)
        return m

    def to_dict(self) -> dict[str, float | str]:
        return {
            "lat_deg": self.lat_deg,
            "lon_deg": self.lon_deg,
            "alt_m": self.alt_m,
            "source": self.source,
        }


def origin_from(
    lat_deg: float, lon_deg: float, alt_m: float, ned_m: tuple[float, float, float], source: str
) -> Origin:
    """The origin of a local frame in which the point at ``lat_deg, lon_deg, alt_m`` (AMSL)
    is at ``ned_m`` (m, north, east, down), by pymap3d's exact conversions."""
    check_geodetic(lat_deg, lon_deg, alt_m, source)
    if not all(math.isfinite(c) for c in ned_m):
        raise InvalidSampleError(f"{source}: local position {list(ned_m)} is not finite")
    n, e, d = ned_m
    if n == e == d == 0.0:  # the point is the origin
        return Origin(lat_deg, lon_deg, alt_m, source)
    lat, lon, alt = _exact(lat_deg, lon_deg, alt_m, (-n, -e, -d))
    # -ned_m is along the point's axes, not the origin's (they differ by |ned_m| / R rad):
    # corrected until the origin maps ned_m onto the point (two rounds: micrometres)
    for _ in range(2):
        lat_p, lon_p, alt_p = _exact(lat, lon, alt, (n, e, d))
        lat, lon, alt = (
            lat + (lat_deg - lat_p),
            lon + math.remainder(lon_deg - lon_p, 360.0),
            alt + (alt_m - alt_p),
        )
    return Origin(lat, math.remainder(lon, 360.0), alt, source)


def _exact(lat0: float, lon0: float, alt0: float, ned: tuple[float, ...]) -> tuple[float, ...]:
    import pymap3d  # when first needed: its import is a tenth of a replay's start-up

    lat, lon, alt = pymap3d.ned2geodetic(ned[0], ned[1], ned[2], lat0, lon0, alt0)
    return float(lat), float(lon), float(alt)


#: Step (m) of the central differences of :func:`_quadratic`.
_STEP_M = 1000.0


def _quadratic(lat0: float, lon0: float, alt0: float) -> tuple[tuple[float, ...], ...]:
    """(latitude, longitude, altitude) around the origin to second order in (n, e, d): the
    values, the gradients (3 per output) and the Hessians' six distinct terms (nn, ee, dd, ne,
    nd, ed), by central differences of pymap3d's exact conversion over 1 km (their own
    error, of fourth order, is far below a millimetre)."""
    h = _STEP_M
    f0 = _exact(lat0, lon0, alt0, (0.0, 0.0, 0.0))
    axes = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    def at(*terms: tuple[float, tuple[float, ...]]) -> tuple[float, ...]:
        p = [sum(c * u[i] for c, u in terms) for i in range(3)]
        out = _exact(lat0, lon0, alt0, (p[0], p[1], p[2]))
        return (out[0], math.remainder(out[1] - f0[1], 360.0) + f0[1], out[2])

    plus = [at((h, u)) for u in axes]
    minus = [at((-h, u)) for u in axes]
    grad = tuple(tuple((plus[i][k] - minus[i][k]) / (2 * h) for i in range(3)) for k in range(3))
    diag = tuple(
        tuple((plus[i][k] - 2 * f0[k] + minus[i][k]) / (h * h) for i in range(3)) for k in range(3)
    )
    mixed = []
    for i, j in ((0, 1), (0, 2), (1, 2)):
        pp = at((h, axes[i]), (h, axes[j]))
        pm = at((h, axes[i]), (-h, axes[j]))
        mp = at((-h, axes[i]), (h, axes[j]))
        mm = at((-h, axes[i]), (-h, axes[j]))
        mixed.append(tuple((pp[k] - pm[k] - mp[k] + mm[k]) / (4 * h * h) for k in range(3)))
    hess = tuple((*diag[k], mixed[0][k], mixed[1][k], mixed[2][k]) for k in range(3))
    return (f0, *grad, *hess)


def gap_m(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    """The larger of the horizontal and vertical distances (m) between two points given as
    (latitude deg, longitude deg, altitude m); the horizontal one on a sphere of the mean
    earth radius (within 0.5 %: for thresholds, not for scoring)."""
    dn = math.radians(a[0] - b[0]) * 6.371e6
    de = math.radians(math.remainder(a[1] - b[1], 360.0)) * 6.371e6 * math.cos(math.radians(b[0]))
    return max(math.hypot(dn, de), abs(a[2] - b[2]))


def to_geodetic(origin: Origin, ned_m: tuple[float, float, float]) -> tuple[float, float, float]:
    """``ned_m`` (m, in the frame of ``origin``) as (latitude deg, longitude deg, altitude m
    AMSL): within :data:`LOCAL_RADIUS_M` of the origin and away from the poles (within
    :data:`LOCAL_MAX_LAT_DEG`), the second-order expansion of pymap3d's conversion around the origin
    (:func:`_quadratic`); else pymap3d's exact ``ned2geodetic``."""
    n, e, d = ned_m
    if n * n + e * e > LOCAL_RADIUS_M * LOCAL_RADIUS_M or abs(origin.lat_deg) > LOCAL_MAX_LAT_DEG:
        lat, lon, alt = _exact(origin.lat_deg, origin.lon_deg, origin.alt_m, ned_m)
        return lat, math.remainder(lon, 360.0), alt
    f0, g0, g1, g2, h0, h1, h2 = origin.model
    q = (0.5 * n * n, 0.5 * e * e, 0.5 * d * d, n * e, n * d, e * d)
    out = []
    for f, g, hh in ((f0[0], g0, h0), (f0[1], g1, h1), (f0[2], g2, h2)):
        out.append(
            f + g[0] * n + g[1] * e + g[2] * d + sum(a * b for a, b in zip(hh, q, strict=True))
        )
    return out[0], math.remainder(out[1], 360.0), out[2]
