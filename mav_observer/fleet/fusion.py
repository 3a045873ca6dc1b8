"""One target seen by several vehicles: the maximum-likelihood point of their rays
(``docs/fleet.md``).

The target is fixed on the earth. Each ray (:class:`~mav_observer.fleet.rays.Ray`) is a
vehicle position ``q_i`` and a measured unit line of sight ``u_i = (p - q_i)/|p - q_i| + n_i``,
``n_i`` isotropic in the plane across the line of sight, ``sigma_i`` per axis. The estimate
``p`` minimises the sum of the squared angles between each ``u_i`` and the direction to ``p``
(Gauss-Newton, Huber-weighted against gross errors), not the distances of ``p`` to the lines:
the linear triangulation is biased by about the Cramer-Rao bound itself at tens of metres.
Its covariance is the inverse of the Fisher information ``sum P_i / (r_i^2 sigma_i^2)``
(``P_i`` the projection across the line of sight), that is the joint Cramer-Rao bound at the
estimate, with each vehicle's noise scaled by what its residuals say.

The frame is WGS84's local north-east-down at the first ray's vehicle position (the anchor):
each ray's position goes to it through ECEF exactly and its line of sight is turned from the
vehicle's own north-east-down, so no spherical-earth shortcut puts vehicles metres apart a few
centimetres off. A ray with a measured range adds it as a measurement of ``|p - q_i|``.

A vehicle's rays stay in the estimate after it goes quiet (the target is fixed), and a ray
needs no clock shared with the other vehicles: its position and line of sight are of one
instant of its own vehicle. Each vehicle's velocity bias (true minus measured) is the slope
of its positions minus its integrated measured velocities on its own boot clock.

Pure: no I/O; the caller gives the receive time for staleness.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pymap3d

from mav_observer.fleet.rays import Ray

WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
#: Huber's threshold on a ray's angle to the estimate, in its sigmas; beyond ``REJECT_K`` a
#: ray is left out (a tracker locked on something else errs to one side, which Huber's
#: bounded pull would still add up), unless that would leave out over ``REJECT_MAX_SHARE``.
HUBER_K = 3.0
REJECT_K = 6.0
REJECT_MAX_SHARE = 0.3
#: Rays kept individually; beyond, the oldest third is folded into a Gaussian prior.
MAX_RAYS = 3000
#: Gauss-Newton iterations per update (warm-started: the estimate moves little per ray).
ITERATIONS = 3
#: A vehicle's bearing noise is learnt from this many of its rays on.
SCALE_MIN_RAYS = 30
#: The rays' spread of directions (smallest eigenvalue of the mean of ``I - u u^T``) from
#: which the first point is triangulated: about 2 deg of parallax.
MIN_SPREAD = 1.2e-3
STATUSES = ("waiting", "unobservable", "converging", "converged")


def _ecef(lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    s, c = math.sin(lat), math.cos(lat)
    n = WGS84_A_M / math.sqrt(1.0 - WGS84_E2 * s * s)
    return np.array(
        [
            (n + alt_m) * c * math.cos(lon),
            (n + alt_m) * c * math.sin(lon),
            (n * (1 - WGS84_E2) + alt_m) * s,
        ]
    )


def _ned_to_ecef(lat_deg: float, lon_deg: float) -> np.ndarray:
    """The rotation whose columns are north, east and down at a point, in ECEF."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]])


@dataclass
class VehicleTrack:
    """What the fusion knows of one contributing vehicle (its key ``sysid/target``)."""

    key: str
    rays: int = 0
    last_rx_s: float | None = None
    #: the bearing noise its rays show (rad, 1 sigma per axis), once learnt
    noise_rad: float | None = None
    clock: str = ""
    clock_offset_s: float | None = None
    # the velocity bias: a regression of (position - integrated velocity) on boot time
    _t0: float | None = None
    _prev: tuple[float, np.ndarray] | None = None
    _integral: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _sums: np.ndarray = field(default_factory=lambda: np.zeros((5, 3)))

    def add_motion(self, t_boot_s: float, q: np.ndarray, v: np.ndarray | None) -> None:
        if v is None:
            return
        if self._prev is not None and t_boot_s <= self._prev[0]:
            if t_boot_s < self._prev[0]:  # a reboot: its clock starts again
                self._t0, self._prev = None, None
                self._integral[:] = 0.0
                self._sums[:] = 0.0
            else:
                return
        if self._t0 is None:
            self._t0 = t_boot_s
        else:
            assert self._prev is not None
            self._integral += 0.5 * (t_boot_s - self._prev[0]) * (v + self._prev[1])
        self._prev = (t_boot_s, v)
        t = t_boot_s - self._t0
        r = q - self._integral
        s = self._sums
        s[0] += 1.0
        s[1] += t
        s[2] += t * t
        s[3] += r
        s[4] += t * r

    def velocity_bias(self) -> tuple[list[float], float] | None:
        """The velocity bias (true minus measured, m/s, NED) and the time span (s) it is
        measured over, or ``None`` before 10 rays with a velocity over 1 s."""
        n, st, stt = self._sums[0, 0], self._sums[1, 0], self._sums[2, 0]
        if n < 10:
            return None
        var_t = stt / n - (st / n) ** 2
        if var_t <= 1.0 / 12.0:  # under a 1 s span
            return None
        slope = (self._sums[4] / n - (st / n) * self._sums[3] / n) / var_t
        return [float(c) for c in slope], math.sqrt(12.0 * var_t)


@dataclass(frozen=True)
class FusedEstimate:
    """The fused target: its position in the anchor's NED frame (m) and on WGS84, the
    covariance (m^2, anchor NED), the status, and the vehicles behind it."""

    name: str
    status: str
    rays: int
    t_unix_s: float
    anchor: tuple[float, float, float]
    pos_ned_m: tuple[float, float, float] | None
    cov_ned_m2: tuple[tuple[float, ...], ...] | None
    geodetic: tuple[float, float, float] | None
    range_m: float | None
    vehicles: tuple[dict[str, Any], ...]
    outliers: int = 0

    @property
    def std_ned_m(self) -> tuple[float, float, float] | None:
        if self.cov_ned_m2 is None:
            return None
        c = self.cov_ned_m2
        return (math.sqrt(c[0][0]), math.sqrt(c[1][1]), math.sqrt(c[2][2]))

    def to_dict(self) -> dict[str, Any]:
        sd = self.std_ned_m
        geo = self.geodetic
        return {
            "schema": 1,
            "target": self.name,
            "status": self.status,
            "t_unix_s": self.t_unix_s,
            "lat_deg": None if geo is None else geo[0],
            "lon_deg": None if geo is None else geo[1],
            "alt_m": None if geo is None else geo[2],
            "horizontal_std_m": None if sd is None else math.hypot(sd[0], sd[1]),
            "vertical_std_m": None if sd is None else sd[2],
            "pos_ned_m": None if self.pos_ned_m is None else list(self.pos_ned_m),
            "pos_std_ned_m": None if sd is None else list(sd),
            "cov_ned_m2": None if self.cov_ned_m2 is None else [list(r) for r in self.cov_ned_m2],
            "anchor": {
                "lat_deg": self.anchor[0],
                "lon_deg": self.anchor[1],
                "alt_m": self.anchor[2],
            },
            "range_m": self.range_m,
            "rays": self.rays,
            "outliers": self.outliers,
            "vehicles": list(self.vehicles),
        }


class FusedTarget:
    """The fused estimate of one target from the rays of the vehicle targets ``keys``
    (``"sysid/target"``). ``converged_rel``: converged when the largest 1-sigma axis is
    under this share of the mean range; ``stale_after_s``: a vehicle with no ray for this long
    (receive clock) is listed as inactive."""

    def __init__(
        self,
        name: str,
        keys: tuple[str, ...] | list[str],
        *,
        converged_rel: float = 0.02,
        stale_after_s: float = 2.0,
        max_rays: int = MAX_RAYS,
    ) -> None:
        self.name = name
        self.keys = tuple(keys)
        self.converged_rel = converged_rel
        self.stale_after_s = stale_after_s
        self.max_rays = max_rays
        self.vehicles: dict[str, VehicleTrack] = {k: VehicleTrack(k) for k in self.keys}
        self._index = {k: i for i, k in enumerate(self.keys)}
        self._anchor: tuple[float, float, float] | None = None
        self._ecef0 = np.zeros(3)
        self._r0t = np.eye(3)
        cap = max_rays + 1
        self._q = np.zeros((cap, 3))
        self._u = np.zeros((cap, 3))
        self._var = np.zeros(cap)  # sigma^2 (rad^2), as told
        self._veh = np.zeros(cap, dtype=np.int64)
        self._rng = np.full(cap, np.nan)  # measured range (m) or NaN
        self._rvar = np.ones(cap)
        self._n = 0
        self._prior_h = np.zeros((3, 3))
        self._prior_p = np.zeros(3)
        self._prior_g = np.zeros(3)
        self._folded = 0
        self._p: np.ndarray | None = None
        self._cov: np.ndarray | None = None
        self._huber = np.ones(cap)
        self._t_unix = math.nan
        self.outliers = 0

    # -- input -----------------------------------------------------------------------------
    def add(self, ray: Ray, rx_s: float) -> bool:
        """Fuse one ray received at ``rx_s`` (any monotonic clock); ``False`` when its key is
        not one of this target's."""
        vi = self._index.get(ray.key)
        if vi is None:
            return False
        if self._anchor is None:
            self._anchor = (ray.lat_deg, ray.lon_deg, ray.alt_m)
            self._ecef0 = _ecef(*self._anchor)
            self._r0t = _ned_to_ecef(ray.lat_deg, ray.lon_deg).T
        r_v = self._r0t @ _ned_to_ecef(ray.lat_deg, ray.lon_deg)
        q = self._r0t @ (_ecef(ray.lat_deg, ray.lon_deg, ray.alt_m) - self._ecef0)
        u = r_v @ np.asarray(ray.los_ned)
        veh = self.vehicles[ray.key]
        veh.rays += 1
        veh.last_rx_s = rx_s
        veh.clock = ray.clock
        veh.clock_offset_s = ray.clock_offset_s
        v = None if ray.vel_ned_mps is None else r_v @ np.asarray(ray.vel_ned_mps)
        veh.add_motion(ray.t_boot_s, q, v)
        if self._n >= self.max_rays:
            self._fold(self.max_rays // 3)
        i = self._n
        self._q[i], self._u[i], self._var[i], self._veh[i] = (
            q,
            u / np.linalg.norm(u),
            ray.sigma_rad**2,
            vi,
        )
        if ray.range_m is not None:
            self._rng[i] = ray.range_m
            self._rvar[i] = (ray.range_std_m or 1.0) ** 2
        else:
            self._rng[i] = np.nan
        self._n += 1
        self._t_unix = ray.t_unix_s
        self._solve()
        return True

    # -- the estimate ----------------------------------------------------------------------
    def _weights(self) -> np.ndarray:
        """1/sigma^2 of each ray: its vehicle's learnt noise, else the noise it came with."""
        n = self._n
        learnt = np.array([self.vehicles[k].noise_rad or math.nan for k in self.keys]) ** 2
        var = learnt[self._veh[:n]]
        return 1.0 / np.where(np.isnan(var), self._var[:n], var)

    def _geometry(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Each ray's range to ``p``, unit line to it, its line of sight's component across
        that line (the angle's components) and the squared angle."""
        n = self._n
        d = p - self._q[:n]
        u = self._u[:n]
        r = np.sqrt(np.einsum("ij,ij->i", d, d))
        dh = d / r[:, None]
        ud = np.einsum("ij,ij->i", u, dh)
        e = u - ud[:, None] * dh
        return r, dh, e, np.einsum("ij,ij->i", e, e)

    def _normal(self, p: np.ndarray, *, robust: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self._n
        w = self._weights()
        r, dh, e, ang2 = self._geometry(p)
        m = np.sqrt(ang2 * w)
        if robust:
            hub = np.where(m > HUBER_K, HUBER_K / np.maximum(m, 1e-12), 1.0)
            far = m > REJECT_K
            if np.count_nonzero(far) <= REJECT_MAX_SHARE * n:  # else the estimate is what is off
                hub[far] = 0.0
            self._huber[:n] = hub
        wr = w * self._huber[:n] / (r * r)
        h = np.eye(3) * wr.sum() - np.einsum("i,ij,ik->jk", wr, dh, dh)
        g = np.einsum("i,ij->j", w * self._huber[:n] / r, e)
        has_r = ~np.isnan(self._rng[:n])
        if has_r.any():
            wrr = 1.0 / self._rvar[:n][has_r]
            dr = dh[has_r]
            h += np.einsum("i,ij,ik->jk", wrr, dr, dr)
            g += np.einsum("i,ij->j", wrr * (self._rng[:n][has_r] - r[has_r]), dr)
        h += self._prior_h
        g += self._prior_g + self._prior_h @ (self._prior_p - p)
        return h, g, ang2

    def _triangulate(self) -> np.ndarray | None:
        n = self._n
        q, u = self._q[:n], self._u[:n]
        has_r = ~np.isnan(self._rng[:n])
        if has_r.any():
            i = int(np.flatnonzero(has_r)[-1])
            return q[i] + self._rng[i] * u[i]
        a = np.eye(3) * n - np.einsum("ij,ik->jk", u, u)
        if n < 2 or np.linalg.eigvalsh(a)[0] / n < MIN_SPREAD:
            return None
        b = q.sum(axis=0) - np.einsum("ij,ik,ik->j", u, u, q)
        p = np.linalg.solve(a, b)
        ahead = np.einsum("ij,ij->i", p - q, u) > 0.0
        return p if ahead.mean() > 0.9 else None

    def _solve(self) -> None:
        if self._p is None:
            p0 = self._triangulate()
            if p0 is None:
                return
            self._p = p0
        p = self._p
        for _ in range(ITERATIONS):
            h, g, _m = self._normal(p, robust=True)
            try:
                dp = np.linalg.solve(h, g)
            except np.linalg.LinAlgError:
                return
            p = p + dp
            if float(dp @ dp) < 1e-8:
                break
        self._learn_noise(self._geometry(p)[3])  # the noise, then the information with it
        h, _g, ang2 = self._normal(p, robust=False)
        if (
            not np.all(np.isfinite(p))
            or np.einsum("ij,ij->i", p - self._q[: self._n], self._u[: self._n]).mean() <= 0.0
        ):
            self._p = None  # behind the vehicles: start again from a triangulation
            self._cov = None
            return
        self._p = p
        try:
            self._cov = np.linalg.inv(h)
        except np.linalg.LinAlgError:
            self._cov = None
        self.outliers = int(np.count_nonzero(ang2 * self._weights() > HUBER_K**2))

    def _learn_noise(self, ang2: np.ndarray) -> None:
        """Each vehicle's bearing noise from the median of its squared angles to the
        estimate (the chi-square of 2 degrees of freedom has its median at 2 ln 2): robust to
        outliers, and blind to what noise the vehicle's own estimator told early on."""
        n = self._n
        for k, vi in self._index.items():
            sel = ang2[self._veh[:n] == vi]
            if len(sel) >= SCALE_MIN_RAYS:
                var = float(np.median(sel)) / (2.0 * math.log(2.0))
                self.vehicles[k].noise_rad = math.sqrt(min(max(var, 1e-8), 0.01))

    def _fold(self, k: int) -> None:
        """The oldest ``k`` rays become a Gaussian prior: their cost's gradient and
        information at the estimate, so that memory and time stay bounded on a long run."""
        if self._p is not None:
            n_all, self._n = self._n, k
            h, g, _ang2 = self._normal(self._p, robust=True)  # with the prior so far
            self._n = n_all
            self._prior_h, self._prior_g, self._prior_p = h, g, self._p.copy()
        keep = slice(k, self._n)
        for arr in (self._q, self._u, self._var, self._veh, self._rng, self._rvar, self._huber):
            arr[: self._n - k] = arr[keep].copy()
        self._n -= k
        self._folded += k

    # -- output ----------------------------------------------------------------------------
    def estimate(self, rx_s: float) -> FusedEstimate:
        """The current estimate; ``rx_s`` on the clock given to :meth:`add` (for staleness)."""
        anchor = self._anchor or (math.nan, math.nan, math.nan)
        vehicles = []
        for k in self.keys:
            v = self.vehicles[k]
            if v.rays == 0:
                continue
            bias = v.velocity_bias()
            vehicles.append(
                {
                    "key": k,
                    "rays": v.rays,
                    "active": v.last_rx_s is not None and rx_s - v.last_rx_s <= self.stale_after_s,
                    "last_ray_age_s": None if v.last_rx_s is None else round(rx_s - v.last_rx_s, 3),
                    "noise_deg": None
                    if v.noise_rad is None
                    else round(math.degrees(v.noise_rad), 4),
                    "vel_bias_ned_mps": None if bias is None else [round(c, 3) for c in bias[0]],
                    "vel_bias_span_s": None if bias is None else round(bias[1], 1),
                    "clock": v.clock,
                    "clock_offset_s": v.clock_offset_s,
                }
            )
        total = self._n + self._folded
        pos = cov_rows = geo = rng = None
        if self._p is None or self._cov is None:
            status = "waiting" if total < 2 else "unobservable"
        else:
            p, cov = self._p, self._cov
            rng = float(np.mean(np.linalg.norm(p - self._q[: self._n], axis=1)[-50:]))
            big = math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))
            status = "converged" if big <= self.converged_rel * rng else "converging"
            if big > rng:
                status = "unobservable"
            ecef = self._ecef0 + self._r0t.T @ p
            lat, lon, alt = pymap3d.ecef2geodetic(float(ecef[0]), float(ecef[1]), float(ecef[2]))
            pos = (float(p[0]), float(p[1]), float(p[2]))
            cov_rows = tuple(tuple(float(c) for c in row) for row in cov)
            geo = (float(lat), float(lon), float(alt))
        return FusedEstimate(self.name, status, total, self._t_unix, anchor, pos, cov_rows, geo,
                             rng, tuple(vehicles), self.outliers)  # fmt: skip

    def to_anchor_ned(self, lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray:
        """A geodetic point in this target's anchor frame (for scoring against a truth)."""
        return self._r0t @ (_ecef(lat_deg, lon_deg, alt_m) - self._ecef0)
