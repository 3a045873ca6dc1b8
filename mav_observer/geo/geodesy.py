"""The autopilot's local NED frame on the earth: its origin, and positions in it as
latitude, longitude and altitude (``docs/geolocation.md``).

LOCAL_POSITION_NED's ``x, y, z`` are north, east and down from an origin the autopilot chose
(ArduPilot: the EKF origin, PX4: the local reference). Where that origin is comes from, in
order of preference (:data:`ORIGIN_SOURCES`):

* ``GPS_GLOBAL_ORIGIN``: the origin itself;
* ``HOME_POSITION``: the home's latitude, longitude and altitude and its local ``x, y, z``;
* ``GLOBAL_POSITION_INT``: the vehicle's latitude, longitude and altitude at the same
  ``time_boot_ms`` as a LOCAL_POSITION_NED sample.

The local frame is the autopilot's (:data:`LOCAL_FRAMES`): ArduPilot and PX4 place their GPS
fixes in it on a sphere, not on the WGS84 ellipsoid, and the ellipsoid would put a point 40 m
north of an ArduPilot origin 14 cm off at 35 deg of latitude. Altitudes are AMSL (MAVLink's
``altitude``/``alt`` fields) and are carried as heights along the origin's normal: over the
few kilometres of a flight the geoid's slope is far below a millimetre per metre. On the
WGS84 frame a local point's conversion is pymap3d's ``ned2geodetic`` expanded to second
order around the origin (:func:`to_geodetic`; the expansion from pymap3d once per origin):
within 5 mm of pymap3d up to :data:`LOCAL_RADIUS_M` from the origin and
:data:`LOCAL_MAX_LAT_DEG` of latitude (``tests/geo/test_geodesy.py``), far cheaper than a call
to pymap3d; farther, pymap3d's exact conversion. No I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mav_observer.errors import InvalidSampleError

#: Where an origin came from, most trusted first.
ORIGIN_SOURCES = ("GPS_GLOBAL_ORIGIN", "HOME_POSITION", "GLOBAL_POSITION_INT")
#: How an autopilot maps its local frame onto latitude and longitude (:func:`to_geodetic`):
#:
#: * ``"wgs84"``: the WGS84 ellipsoid's local NED frame (pymap3d's ``ned2geodetic``);
#: * ``"ardupilot"``: ArduPilot's ``Location::offset`` and ``get_distance_NE``
#:   (``libraries/AP_Common/Location.cpp``): north and east scaled on a sphere of
#:   ``RADIUS_OF_EARTH`` = 6,378,100 m, east by the cosine of the mean latitude. Its EKF
#:   places GPS fixes in the local frame that way and reports GLOBAL_POSITION_INT back the
#:   same way, so the ellipsoid is 0.2-0.7 % off in north (0.34 % at 35 deg: 14 cm at 40 m);
#: * ``"px4"``: PX4's ``MapProjection`` (``src/lib/geo``): an azimuthal equidistant
#:   projection on a sphere of ``CONSTANTS_RADIUS_OF_EARTH`` = 6,371,000 m.
#:
#: Altitudes are the origin's minus ``down`` in all three.
LOCAL_FRAMES = ("wgs84", "ardupilot", "px4")
#: ArduPilot's ``RADIUS_OF_EARTH`` (m, ``libraries/AP_Math/definitions.h``).
ARDUPILOT_EARTH_RADIUS_M = 6378100.0
#: PX4's ``CONSTANTS_RADIUS_OF_EARTH`` (m, ``src/lib/geo/geo.h``).
PX4_EARTH_RADIUS_M = 6371000.0
#: Horizontal distance from the origin (m) within which the local expansion is used.
LOCAL_RADIUS_M = 2000.0
#: The earth's mean radius (m): distances for thresholds and scatter, not for placing points.
MEAN_EARTH_RADIUS_M = 6.371e6
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
    the message it came from (one of :data:`ORIGIN_SOURCES`) and how the autopilot maps its
    local frame onto latitude and longitude (one of :data:`LOCAL_FRAMES`)."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    source: str
    frame: str = "wgs84"
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
        if self.frame not in LOCAL_FRAMES:
            raise InvalidSampleError(f"origin frame {self.frame!r} is not one of {LOCAL_FRAMES}")

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
            "frame": self.frame,
        }


def origin_from(
    lat_deg: float,
    lon_deg: float,
    alt_m: float,
    ned_m: tuple[float, float, float],
    source: str,
    frame: str = "wgs84",
) -> Origin:
    """The origin of a local frame (``frame``, one of :data:`LOCAL_FRAMES`) in which the
    point at ``lat_deg, lon_deg, alt_m`` (AMSL) is at ``ned_m`` (m, north, east, down), by
    that frame's exact conversions."""
    check_geodetic(lat_deg, lon_deg, alt_m, source)
    if not all(math.isfinite(c) for c in ned_m):
        raise InvalidSampleError(f"{source}: local position {list(ned_m)} is not finite")
    if frame not in LOCAL_FRAMES:
        raise InvalidSampleError(f"origin frame {frame!r} is not one of {LOCAL_FRAMES}")
    n, e, d = ned_m
    if n == e == d == 0.0:  # the point is the origin
        return Origin(lat_deg, lon_deg, alt_m, source, frame)
    forward = _FORWARD[frame]
    lat, lon, alt = forward(lat_deg, lon_deg, alt_m, (-n, -e, -d))
    # -ned_m is along the point's axes, not the origin's (they differ by |ned_m| / R rad):
    # corrected until the origin maps ned_m onto the point (three rounds: micrometres)
    for _ in range(3):
        lat_p, lon_p, alt_p = forward(lat, lon, alt, (n, e, d))
        lat, lon, alt = (
            lat + (lat_deg - lat_p),
            lon + math.remainder(lon_deg - lon_p, 360.0),
            alt + (alt_m - alt_p),
        )
    return Origin(lat, math.remainder(lon, 360.0), alt, source, frame)


def shifted(origin: Origin, dlat_deg: float, dlon_deg: float, dalt_m: float) -> Origin:
    """``origin`` moved by a small amount (a few centimetres: ``dlat_deg``, ``dlon_deg``,
    ``dalt_m``), its second-order expansion kept with only its value moved (the
    gradients change by the shift over the earth's radius, about 1e-9)."""
    out = Origin(origin.lat_deg + dlat_deg, origin.lon_deg + dlon_deg, origin.alt_m + dalt_m,
                 origin.source, origin.frame)  # fmt: skip
    if origin.frame != "wgs84":  # (no expansion: the sphere's formulas are closed)
        return out
    f0, *rest = origin.model
    model = ((f0[0] + dlat_deg, f0[1] + dlon_deg, f0[2] + dalt_m), *rest)
    object.__setattr__(out, "_model", model)
    return out


@dataclass
class OriginMean:
    """The origin of a local frame placed by many points known both ways (the vehicle's
    GLOBAL_POSITION_INT, rounded to 1e-7 deg, about 1.1 cm, and its LOCAL_POSITION_NED at the
    same time): one pair puts the origin up to half a rounding step off, the same for every
    estimate of the flight; the mean over ``n`` pairs, as the vehicle moves, is about
    ``sqrt(n)`` times nearer (``docs/geolocation.md``, "The local frame's origin"). Each
    pair's point is placed by ``ref`` (the origin from the first pair, its expansion made
    once) and the gaps (deg, deg, m) between where it says the point is and where the pair
    says are averaged; :attr:`origin` is ``ref`` moved by their mean (:func:`shifted`)."""

    ref: Origin
    n: int = 1
    sums: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the sums of the squared gaps north and east (m^2), for :meth:`scatter_m`
    squares_m2: tuple[float, float] = (0.0, 0.0)

    def add(
        self, lat_deg: float, lon_deg: float, alt_m: float, ned_m: tuple[float, float, float]
    ) -> None:
        """One more pair: the point at ``lat_deg, lon_deg, alt_m`` (AMSL) is at ``ned_m``
        (m) in the local frame."""
        lat, lon, alt = to_geodetic(self.ref, ned_m)
        g0, g1 = lat_deg - lat, math.remainder(lon_deg - lon, 360.0)
        s0, s1, s2 = self.sums
        self.sums = (s0 + g0, s1 + g1, s2 + (alt_m - alt))
        k_n, k_e = self._m_per_deg()
        q0, q1 = self.squares_m2
        self.squares_m2 = (q0 + (g0 * k_n) ** 2, q1 + (g1 * k_e) ** 2)
        self.n += 1

    def _m_per_deg(self) -> tuple[float, float]:
        k = math.radians(MEAN_EARTH_RADIUS_M)
        return k, k * math.cos(math.radians(self.ref.lat_deg))

    def scatter_m(self) -> float:
        """The horizontal RMS (m) of the pairs' gaps about their mean: the rounding (a few
        millimetres) where the frame is the autopilot's, more the farther the pairs spread
        where it is not (:class:`FrameVote`)."""
        n = self.n
        k_n, k_e = self._m_per_deg()
        m0, m1 = self.sums[0] / n * k_n, self.sums[1] / n * k_e
        var = self.squares_m2[0] / n - m0 * m0 + self.squares_m2[1] / n - m1 * m1
        return math.sqrt(max(var, 0.0))

    @property
    def origin(self) -> Origin:
        """``ref`` moved by the mean gap of the pairs."""
        n = self.n
        s0, s1, s2 = self.sums
        return shifted(self.ref, s0 / n, s1 / n, s2 / n)


@dataclass
class FrameVote:
    """Which of :data:`LOCAL_FRAMES` the autopilot maps its local frame by, told by its own
    GLOBAL_POSITION_INT and LOCAL_POSITION_NED pairs: each frame places the origin from what
    placed it (:meth:`start`) and every pair after it (:class:`OriginMean`); the autopilot's
    frame leaves the rounding's few millimetres of scatter between the pairs, another 0.1-0.7 %
    of the distance they spread over (``docs/geolocation.md``, "Frames and altitudes").
    :meth:`choice` is the frame to use, and whether it is clear."""

    means: dict[str, OriginMean]

    @classmethod
    def start(
        cls, lat_deg: float, lon_deg: float, alt_m: float, ned_m: tuple[float, float, float],
        source: str,
    ) -> FrameVote:  # fmt: skip
        """A vote from the point that placed the origin (``source``; as :func:`origin_from`)."""
        return cls(
            {
                f: OriginMean(origin_from(lat_deg, lon_deg, alt_m, ned_m, source, f))
                for f in LOCAL_FRAMES
            }
        )

    def add(
        self, lat_deg: float, lon_deg: float, alt_m: float, ned_m: tuple[float, float, float]
    ) -> None:
        """One GLOBAL_POSITION_INT and LOCAL_POSITION_NED pair (as :meth:`OriginMean.add`)."""
        for mean in self.means.values():
            mean.add(lat_deg, lon_deg, alt_m, ned_m)

    def choice(self, current: str) -> tuple[str, bool]:
        """The frame to use now, ``current`` being the one in use, and whether the vote has
        decided, from :data:`FRAME_PAIRS` pairs on (before: ``current``, not decided).
        Decided: the least scattered, at most half the next one's, the next past the rounding
        (:data:`FRAME_GAP_M`). Not yet (a vehicle that has not moved far enough to tell them
        apart): the least scattered if ``current``'s scatter is past the rounding and at least
        twice the least, else ``current``."""
        if self.means[current].n < FRAME_PAIRS:
            return current, False
        scatter = {f: m.scatter_m() for f, m in self.means.items()}
        ranked = sorted((v, f) for f, v in scatter.items())
        (best, frame), (second, _) = ranked[0], ranked[1]
        if second >= FRAME_GAP_M and best <= 0.5 * second:
            return frame, True
        here = scatter[current]
        return (frame if here >= FRAME_GAP_M and best <= 0.5 * here else current), False


#: :class:`FrameVote` weighs the frames once it has this many pairs ...
FRAME_PAIRS = 30
#: ... and tells them apart where their scatter is past this (m): the rounding of a pair's
#: latitude and longitude to 1e-7 deg leaves about 4.5 mm.
FRAME_GAP_M = 0.01


def _exact(lat0: float, lon0: float, alt0: float, ned: tuple[float, ...]) -> tuple[float, ...]:
    import pymap3d  # when first needed: its import slows a replay's start-up

    lat, lon, alt = pymap3d.ned2geodetic(ned[0], ned[1], ned[2], lat0, lon0, alt0)
    return float(lat), float(lon), float(alt)


def _ardupilot(lat0: float, lon0: float, alt0: float, ned: tuple[float, ...]) -> tuple[float, ...]:
    """ArduPilot's ``Location::offset`` of the origin by ``ned`` (m), in degrees rather than
    its 1e-7 deg integers: north over the sphere's radius, east over the radius times the
    cosine (at least 0.01) of the latitude half-way."""
    k = 180.0 / (math.pi * ARDUPILOT_EARTH_RADIUS_M)
    dlat = ned[0] * k
    scale = max(math.cos(math.radians(lat0 + 0.5 * dlat)), 0.01)
    return lat0 + dlat, lon0 + ned[1] * k / scale, alt0 - ned[2]


def _px4(lat0: float, lon0: float, alt0: float, ned: tuple[float, ...]) -> tuple[float, ...]:
    """PX4's ``MapProjection::reproject`` of ``ned`` (m) from the origin: the azimuthal
    equidistant projection on its sphere."""
    x, y = ned[0] / PX4_EARTH_RADIUS_M, ned[1] / PX4_EARTH_RADIUS_M
    c = math.hypot(x, y)
    if c == 0.0:
        return lat0, lon0, alt0 - ned[2]
    phi0, lam0 = math.radians(lat0), math.radians(lon0)
    sin_c, cos_c = math.sin(c), math.cos(c)
    sin0, cos0 = math.sin(phi0), math.cos(phi0)
    lat = math.asin(max(-1.0, min(1.0, cos_c * sin0 + x * sin_c * cos0 / c)))
    lon = lam0 + math.atan2(y * sin_c, c * cos0 * cos_c - x * sin0 * sin_c)
    return math.degrees(lat), math.degrees(lon), alt0 - ned[2]


#: Each frame's conversion of a local point from the origin (exact).
_FORWARD = {"wgs84": _exact, "ardupilot": _ardupilot, "px4": _px4}


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
    r = MEAN_EARTH_RADIUS_M
    dn = math.radians(a[0] - b[0]) * r
    de = math.radians(math.remainder(a[1] - b[1], 360.0)) * r * math.cos(math.radians(b[0]))
    return max(math.hypot(dn, de), abs(a[2] - b[2]))


def to_geodetic(origin: Origin, ned_m: tuple[float, float, float]) -> tuple[float, float, float]:
    """``ned_m`` (m, in the frame of ``origin``) as (latitude deg, longitude deg, altitude m
    AMSL). An autopilot's sphere (``origin.frame`` ``"ardupilot"`` or ``"px4"``): its own
    formulas. WGS84: within :data:`LOCAL_RADIUS_M` of the origin and away from the poles (within
    :data:`LOCAL_MAX_LAT_DEG`), the second-order expansion of pymap3d's conversion around the origin
    (:func:`_quadratic`); else pymap3d's exact ``ned2geodetic``."""
    n, e, d = ned_m
    if origin.frame != "wgs84":  # an autopilot's sphere: closed formulas
        lat, lon, alt = _FORWARD[origin.frame](origin.lat_deg, origin.lon_deg, origin.alt_m, ned_m)
        return lat, math.remainder(lon, 360.0), alt
    if n * n + e * e > LOCAL_RADIUS_M * LOCAL_RADIUS_M or abs(origin.lat_deg) > LOCAL_MAX_LAT_DEG:
        lat, lon, alt = _exact(origin.lat_deg, origin.lon_deg, origin.alt_m, ned_m)
        return lat, math.remainder(lon, 360.0), alt
    f0, g0, g1, g2, h0, h1, h2 = origin.model
    q0, q1, q2, q3, q4, q5 = 0.5 * n * n, 0.5 * e * e, 0.5 * d * d, n * e, n * d, e * d
    out = []
    for f, g, h in ((f0[0], g0, h0), (f0[1], g1, h1), (f0[2], g2, h2)):
        # value, gradient, then the Hessian's terms summed in order (written out: faster
        # than a generator's sum)
        out.append(
            f + g[0] * n + g[1] * e + g[2] * d
            + (h[0] * q0 + h[1] * q1 + h[2] * q2 + h[3] * q3 + h[4] * q4 + h[5] * q5)
        )  # fmt: skip
    return out[0], math.remainder(out[1], 360.0), out[2]
