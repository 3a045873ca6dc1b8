"""The offline optimum: a batch least-squares fit of ``x0`` and ``a`` over a whole log (pure:
numpy only, no I/O).

Model (``docs/observer.md``): ``x' = v + a`` with ``v = -u`` known, ``a`` constant, so at the
bearing times ``t_k``::

    x(t_k) = x0 + a (t_k - t_0) + D_k,        D_k = integral of v from t_0 to t_k

with six unknowns, ``x0 = x(t_0)`` and ``a``. The bearings are ``y_k = x(t_k) / |x(t_k)|``
plus noise. :func:`fit_batch`:

1. **Linear initialisation**: ``Pi_{y_k} (x0 + a (t_k - t_0)) = -Pi_{y_k} D_k``
   (``Pi_y = I - y y^T``) by least squares (:func:`linear_init`): exact for exact bearings,
   biased by noise (the noise enters the matrix).
2. **Gauss-Newton** on the angular residuals: for each bearing, the two components, in an
   orthonormal basis ``E_k`` of the plane orthogonal to ``y_k``, of ``x(t_k) / |x(t_k)|``
   (the sine of the angle between the two, in the direction it lies), divided by
   ``sigma_rad``. Optionally robust (Huber weights, iteratively reweighted). Steps that
   increase the cost are halved. It stops when a step is below ``tol`` (1e-9) relative to the
   solution (the ``a`` part measured by what it moves over the time span).

The covariance is the inverse of the Gauss-Newton normal matrix of the whitened residuals
(that is ``sigma^2 (J^T J)^-1``), or, with ``covariance_from="residuals"``, that scaled by the
residuals' variance per degree of freedom (when ``sigma_rad`` is not known well).

:func:`displacement_at` computes ``D_k`` from velocity samples (trapezoid rule), or, where the
positions are given, from the position's differences less their
mean drift from the integrated velocity (so that a constant velocity error stays in ``a``),
as the tracker does for LOCAL_POSITION_NED (``docs/frames.md``, "Velocity from the
positions").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mav_observer.errors import ConfigError, InvalidSampleError, MavObserverError

#: Velocity samples further apart than this (s) use the position's change (when given):
#: every interval, at any rate, as the tracker does.
SPARSE_VELOCITY_S = 0.0
#: An interval whose position change is further than ``RESET_GATE_M + RESET_GATE_MPS2 dt^2``
#: from the velocity's trapezoid (drift removed) is a position reset: the trapezoid is used.
RESET_GATE_M = 0.5
RESET_GATE_MPS2 = 5.0


class NotObservableError(MavObserverError, ValueError):
    """The data do not determine ``x0`` and ``a`` (too little motion across the line of
    sight, or too few bearings); the message says how badly."""


@dataclass(frozen=True, eq=False)
class BatchFit:
    """Result of :func:`fit_batch`. Units are in the names; the covariance is over
    ``(x0_ned_m, a_ned_mps)`` in that order (6 x 6)."""

    t0_s: float
    x0_ned_m: np.ndarray
    a_ned_mps: np.ndarray
    covariance: np.ndarray
    residual_rms_rad: float
    iterations: int
    converged: bool
    sigma_rad: float
    method: str
    t_s: np.ndarray
    displacement_ned_m: np.ndarray
    #: Huber weight of each bearing at the solution (all 1 without ``huber_k``)
    weights: np.ndarray

    @property
    def x0_std_m(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[:3])

    @property
    def a_std_mps(self) -> np.ndarray:
        return np.sqrt(np.diag(self.covariance)[3:])

    def rel_pos_at(self, t_s: np.ndarray | float | None = None) -> np.ndarray:
        """``x(t) = x0 + a (t - t_0) + D(t)`` (m): at the bearing times (``None``), or at
        times within their span, ``D`` interpolated linearly between bearing times (exact at
        them). Shape (T, 3), or (3,) for a scalar ``t_s``."""
        if t_s is None:
            t = self.t_s
            d = self.displacement_ned_m
        else:
            t = np.atleast_1d(np.asarray(t_s, dtype=float))
            if not np.all(np.isfinite(t)):
                raise InvalidSampleError(f"t_s must be finite, got {t_s!r}")
            lo, hi = self.t_s[0], self.t_s[-1]
            if t.size and (t.min() < lo or t.max() > hi):
                raise InvalidSampleError(
                    f"t_s must lie within the bearing times [{lo}, {hi}] s, got "
                    f"[{t.min()}, {t.max()}] s"
                )
            d = np.column_stack(
                [np.interp(t, self.t_s, self.displacement_ned_m[:, i]) for i in range(3)]
            )
        x = self.x0_ned_m[None, :] + np.outer(t - self.t0_s, self.a_ned_mps) + d
        return x[0] if t_s is not None and np.ndim(t_s) == 0 else x


# -- input checks -----------------------------------------------------------------------------


def _times(name: str, t: object, strict: bool = True) -> np.ndarray:
    arr = np.asarray(t, dtype=float)
    if arr.ndim != 1 or arr.size == 0:
        raise InvalidSampleError(f"{name} must be a non-empty 1-D array, got shape {arr.shape}")
    bad = np.nonzero(~np.isfinite(arr))[0]
    if bad.size:
        raise InvalidSampleError(f"{name}[{bad[0]}] is not finite: {arr[bad[0]]!r}")
    d = np.diff(arr)
    back = np.nonzero(d <= 0.0 if strict else d < 0.0)[0]
    if back.size:
        i = back[0]
        raise InvalidSampleError(
            f"{name} must be increasing: {name}[{i + 1}] = {arr[i + 1]!r} after "
            f"{name}[{i}] = {arr[i]!r}"
        )
    return arr


def _vectors(name: str, v: object, n: int) -> np.ndarray:
    arr = np.asarray(v, dtype=float)
    if arr.shape != (n, 3):
        raise InvalidSampleError(f"{name} must have shape ({n}, 3), got {arr.shape}")
    bad = np.nonzero(~np.all(np.isfinite(arr), axis=1))[0]
    if bad.size:
        raise InvalidSampleError(f"{name}[{bad[0]}] is not finite: {arr[bad[0]].tolist()}")
    return arr


def _bearings(y: object, n: int) -> np.ndarray:
    arr = _vectors("bearings", y, n)
    norms = np.linalg.norm(arr, axis=1)
    bad = np.nonzero(np.abs(norms - 1.0) > 1e-3)[0]
    if bad.size:
        raise InvalidSampleError(
            f"bearings[{bad[0]}] is not a unit vector: {arr[bad[0]].tolist()} "
            f"(norm {norms[bad[0]]:.6g})"
        )
    return arr / norms[:, None]


# -- the displacement -------------------------------------------------------------------------


def displacement_at(
    t_bearing: object,
    t_vel: object,
    vel_ned_mps: object,
    pos_ned_m: object | None = None,
) -> np.ndarray:
    """``D_k``: the integral of ``v = -u`` from ``t_bearing[0]`` to each ``t_bearing[k]``
    (m, (N, 3)), ``u`` the measured velocity ``vel_ned_mps`` at the strictly increasing
    ``t_vel``.

    Between velocity samples ``u`` is linear (the trapezoid rule; exact for a velocity linear
    in time, also at bearing times inside an interval). Outside the samples' span the nearest
    velocity is held. With ``pos_ned_m`` (positions at ``t_vel``), an interval longer than
    :data:`SPARSE_VELOCITY_S` uses the position's change ``dp`` less the mean drift: its
    displacement is ``-(dp - dbar dt)``, ``dbar`` being the sum over such intervals of
    ``dp - trapezoid(u)`` over the sum of their ``dt`` (a constant velocity error then stays
    in ``a``), except for intervals whose ``dp - trapezoid(u)`` is further than
    ``0.5 m + 5 m/s^2 dt^2`` from ``dbar dt`` (a position reset: the trapezoid is used, and
    they do not count in ``dbar``; a first ``dbar`` from the median drift rate decides which
    they are). Inside such an interval the trapezoid's shape is kept and the difference is
    spread linearly."""
    tb = _times("t_bearing", t_bearing, strict=False)
    tv = _times("t_vel", t_vel)
    u = _vectors("vel_ned_mps", vel_ned_mps, len(tv))
    p = None if pos_ned_m is None else _vectors("pos_ned_m", pos_ned_m, len(tv))
    # displacement of -u over each interval, and the interval's correction
    dt = np.diff(tv)
    trap = 0.5 * (u[:-1] + u[1:]) * dt[:, None]  # integral of u
    corr = np.zeros_like(trap)  # added to the integral of u over the interval
    if p is not None and len(tv) > 1:
        sparse = dt > SPARSE_VELOCITY_S
        if np.any(sparse):
            dp = np.diff(p, axis=0)
            resid = dp - trap
            rate0 = np.median(resid[sparse] / dt[sparse, None], axis=0)
            gate = RESET_GATE_M + RESET_GATE_MPS2 * dt**2
            off = np.linalg.norm(resid - rate0[None, :] * dt[:, None], axis=1)
            use = sparse & (off <= gate)
            if np.any(use):
                dbar = resid[use].sum(axis=0) / dt[use].sum()
                corr[use] = resid[use] - dbar[None, :] * dt[use, None]
    cum = np.vstack((np.zeros((1, 3)), np.cumsum(trap + corr, axis=0)))  # integral of u
    # integral of u from tv[0] to each bearing time
    j = np.clip(np.searchsorted(tv, tb, side="right") - 1, 0, max(len(tv) - 2, 0))
    if len(tv) == 1:
        integral = np.outer(tb - tv[0], u[0])
    else:
        h = np.clip(tb - tv[j], 0.0, dt[j])
        f = h / dt[j]
        ua, ub = u[j], u[j + 1]
        within = ua * h[:, None] + 0.5 * (ub - ua) * (h * f)[:, None] + corr[j] * f[:, None]
        integral = cum[j] + within
        before = tb < tv[0]
        after = tb > tv[-1]
        integral[before] = np.outer(tb[before] - tv[0], u[0])
        integral[after] = cum[-1] + np.outer(tb[after] - tv[-1], u[-1])
    return -(integral - integral[0])


# -- the fit ----------------------------------------------------------------------------------


def _tangent_bases(y: np.ndarray) -> np.ndarray:
    """Orthonormal bases ``(N, 2, 3)`` of the planes orthogonal to the unit rows of ``y``."""
    helper = np.where(np.abs(y[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(y, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(y, e1)
    return np.stack((e1, e2), axis=1)


def linear_init(t_s: object, bearings: object, displacement_ned_m: object) -> np.ndarray:
    """``(x0, a)`` (6,) from the pseudo-measurements ``Pi_{y_k} (x0 + a (t_k - t_0)) =
    -Pi_{y_k} D_k`` by least squares. Raises :class:`NotObservableError` if they do not
    determine it."""
    t = _times("t_s", t_s)
    y = _bearings(bearings, len(t))
    d = _vectors("displacement_ned_m", displacement_ned_m, len(t))
    return _linear(t - t[0], y, d)


def _linear(tau: np.ndarray, y: np.ndarray, d: np.ndarray) -> np.ndarray:
    n = len(tau)
    pi = np.eye(3)[None, :, :] - y[:, :, None] * y[:, None, :]  # (N, 3, 3)
    scale = max(float(tau[-1]), 1.0)
    a_mat = np.concatenate((pi, pi * (tau / scale)[:, None, None]), axis=2).reshape(3 * n, 6)
    b = -np.einsum("kij,kj->ki", pi, d).reshape(3 * n)
    sol, _, rank, sv = np.linalg.lstsq(a_mat, b, rcond=None)
    if rank < 6 or sv[-1] < 1e-10 * sv[0]:
        raise NotObservableError(
            f"the bearings do not determine x0 and a (rank {rank}, singular values "
            f"{sv[-1]:.3g} to {sv[0]:.3g}): too little motion across the line of sight"
        )
    sol[3:] /= scale
    return sol


def _residuals(
    theta: np.ndarray, tau: np.ndarray, d: np.ndarray, e: np.ndarray, sigma: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened residuals (N, 2), their Jacobian (N, 2, 6), and the cosines ``y . x/|x|``."""
    x = theta[None, :3] + tau[:, None] * theta[None, 3:] + d
    nrm = np.linalg.norm(x, axis=1)
    u = x / nrm[:, None]
    r = np.einsum("kij,kj->ki", e, u) / sigma
    # d(E u)/dx = E (I - u u^T) / |x|
    ex = (e - np.einsum("ki,kj->kij", np.einsum("kij,kj->ki", e, u), u)) / (nrm * sigma)[
        :, None, None
    ]
    jac = np.concatenate((ex, ex * tau[:, None, None]), axis=2)
    return r, jac, nrm


def fit_batch(
    t_s: object,
    bearings: object,
    displacement_ned_m: object,
    *,
    sigma_rad: float = math.radians(0.5),
    huber_k: float | None = None,
    max_iterations: int = 50,
    tol: float = 1e-9,
    covariance_from: str = "sigma",
) -> BatchFit:
    """Fit ``x0 = x(t_s[0])`` and ``a`` to the bearings ``(N, 3)`` (unit) at the strictly
    increasing ``t_s`` (s), given the displacements ``D_k`` (m, (N, 3), ``D_0 = 0``; see
    :func:`displacement_at`). ``sigma_rad``: the bearings' angular noise (1-sigma per
    tangent axis); ``huber_k``: Huber threshold in sigmas (``None``: plain least squares;
    1.345 is the usual choice); ``max_iterations`` 0: the linear initialisation alone (its
    covariance from the Gauss-Newton normal matrix at it). ``covariance_from``: ``"sigma"``
    or ``"residuals"`` (see the module docstring).

    Raises :class:`~mav_observer.errors.InvalidSampleError` for bad data,
    :class:`~mav_observer.errors.ConfigError` for bad options and :class:`NotObservableError`
    when the data do not determine the answer."""
    if not (isinstance(sigma_rad, (int, float)) and math.isfinite(sigma_rad) and sigma_rad > 0):
        raise ConfigError(f"sigma_rad must be a finite number > 0, got {sigma_rad!r}")
    if huber_k is not None and not (
        isinstance(huber_k, (int, float)) and math.isfinite(huber_k) and huber_k > 0
    ):
        raise ConfigError(f"huber_k must be None or a finite number > 0, got {huber_k!r}")
    if not (isinstance(max_iterations, int) and max_iterations >= 0):
        raise ConfigError(f"max_iterations must be an integer >= 0, got {max_iterations!r}")
    if not (isinstance(tol, (int, float)) and tol > 0):
        raise ConfigError(f"tol must be > 0, got {tol!r}")
    if covariance_from not in ("sigma", "residuals"):
        raise ConfigError(
            f"covariance_from must be 'sigma' or 'residuals', got {covariance_from!r}"
        )
    t = _times("t_s", t_s)
    n = len(t)
    if n < 3:
        raise InvalidSampleError(f"t_s: at least 3 bearings are needed for 6 unknowns, got {n}")
    y = _bearings(bearings, n)
    d = _vectors("displacement_ned_m", displacement_ned_m, n)
    tau = t - t[0]
    span = max(float(tau[-1]), 1e-9)
    e = _tangent_bases(y)
    sigma = float(sigma_rad)

    theta = _linear(tau, y, d)
    method = "linear"

    def cost_of(th: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        r, jac, _ = _residuals(th, tau, d, e, sigma)
        rho = np.linalg.norm(r, axis=1)
        if huber_k is None:
            return float(np.sum(rho * rho)), r, jac, np.ones(n)
        k = huber_k
        # Huber's loss (times 2) and its IRLS weights
        loss = np.where(rho <= k, rho * rho, 2.0 * k * rho - k * k)
        w = np.where(rho <= k, 1.0, k / np.maximum(rho, 1e-300))
        return float(np.sum(loss)), r, jac, w

    cost, r, jac, w = cost_of(theta)
    iterations = 0
    converged = max_iterations == 0
    while iterations < max_iterations:
        iterations += 1
        method = "gauss_newton"
        sw = np.sqrt(w)
        jw = (jac * sw[:, None, None]).reshape(2 * n, 6)
        rw = (r * sw[:, None]).reshape(2 * n)
        step = np.linalg.lstsq(jw, -rw, rcond=None)[0]
        size = np.linalg.norm(np.concatenate((step[:3], step[3:] * span)))
        ref = max(np.linalg.norm(theta[:3]), np.linalg.norm(theta[3:]) * span, 1e-12)
        alpha = 1.0
        for _ in range(30):
            trial = theta + alpha * step
            c_new, r_new, jac_new, w_new = cost_of(trial)
            if c_new <= cost * (1.0 + 1e-12) or alpha * size <= tol * ref:
                break
            alpha *= 0.5
        theta, cost, r, jac, w = trial, c_new, r_new, jac_new, w_new
        if alpha * size <= tol * ref:
            converged = True
            break
    sw = np.sqrt(w)
    jw = (jac * sw[:, None, None]).reshape(2 * n, 6)
    normal = jw.T @ jw
    scale = np.concatenate((np.ones(3), np.full(3, span)))
    ns = normal / np.outer(scale, scale)  # in (x0, a * span): comparable columns
    ev = np.linalg.eigvalsh(ns)
    if ev[0] <= 1e-12 * ev[-1]:
        raise NotObservableError(
            f"the bearings do not determine x0 and a (normal matrix condition "
            f"{ev[-1] / max(ev[0], 1e-300):.3g}): too little motion across the line of sight"
        )
    cov = np.linalg.inv(ns) / np.outer(scale, scale)
    cov = 0.5 * (cov + cov.T)
    chi2 = float(np.sum(r * r))
    if covariance_from == "residuals":
        cov = cov * (float(np.sum(w * np.sum(r * r, axis=1))) / max(2 * n - 6, 1))
    return BatchFit(
        t0_s=float(t[0]),
        x0_ned_m=theta[:3].copy(),
        a_ned_mps=theta[3:].copy(),
        covariance=cov,
        residual_rms_rad=math.sqrt(chi2 / (2 * n)) * sigma,
        iterations=iterations,
        converged=converged,
        sigma_rad=sigma,
        method=method,
        t_s=t.copy(),
        displacement_ned_m=d.copy(),
        weights=w,
    )


__all__ = [
    "BatchFit",
    "NotObservableError",
    "displacement_at",
    "fit_batch",
    "linear_init",
]
