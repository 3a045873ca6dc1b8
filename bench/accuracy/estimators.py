"""The estimators compared, behind one small batched interface.

Every estimator handles ``R`` runs at once (leading dimension ``R``)::

    est.start(t0, y0, v0, r0)   # first sample: y0, v0 (R, n), range guesses r0 (R,)
    est.step(t, h, dx, v, y)    # next sample, h s later: dx = integral of v (R, n)
    x, a, p = est.estimate()    # (R, n), (R, n), (R, 2n, 2n) or None

Batched (one call per step for all runs, the product's compiled kernels over the runs:
:mod:`.bankruns`): ``riccati`` (the product's filter bank), and the baselines ``ekf`` and
``plkf`` (one filter of the bank's each; they are not part of the product). Per run, through
the service's interface (``BiasObserver.update_velocity`` / ``update_bearing``): the paper's
observer with gains (0.5, 5) as ``paper`` and (0.2, 0.2) as ``observer02``, and with
``--per-sample`` the product's default estimator as ``riccati``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

from mav_observer.core.config import BankParams
from mav_observer.core.observer import (
    BEARING_NOISE_PRIOR_DEG,
    BiasObserver,
    ObserverConfig,
    outlier_nis,
)
from mav_observer.core.samples import BearingSample, VelocitySample

from .bankruns import BankRuns, FilterRuns, initial_covariance
from .core import SIGMA_FLOOR_RAD

BATCHED = ("riccati", "ekf", "plkf", "riccati_auto")
PER_RUN = ("paper", "observer02")
ALL = ("paper", "observer02", "ekf", "plkf", "riccati")
#: Not in the documentation grid, asked for by name: the default estimator with the bearing
#: noise learnt online from a 0.5 deg prior instead of told (``bearing_noise_deg = "auto"``).
EXTRA = ("riccati_auto",)
KNOWN = ALL + EXTRA
#: Estimators with a product configuration (can run through BiasObserver).
SERVICE_FORMS = ("paper", "observer02", "riccati")


class NotReadyError(RuntimeError):
    """The product does not offer what a per-sample path needs (yet)."""


class Estimator(Protocol):
    name: str

    def start(self, t0: float, y0: np.ndarray, v0: np.ndarray, r0: np.ndarray) -> None: ...

    def step(self, t: float, h: float, dx: np.ndarray, v: np.ndarray, y: np.ndarray) -> None: ...

    def estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]: ...


class Riccati:
    """The product default: the filter bank (EKF hypotheses in range plus a Riccati
    observer that re-seeds them), :mod:`mav_observer.core.kernels.bank`."""

    name = "riccati"

    def __init__(self, sigma_rad: float, q_x: float, n: int = 3, *, learn: bool = False) -> None:
        # the product's settings when told the noise (robust weighting of gross errors on);
        # learn: the bearing noise learnt from the product's prior instead
        sigma = math.radians(BEARING_NOISE_PRIOR_DEG) if learn else max(sigma_rad, SIGMA_FLOOR_RAD)
        self.prm = BankParams(
            sigma_rad=sigma, q_x=q_x, outlier_nis=outlier_nis(n - 1), learn_noise=learn
        )
        self.n = n
        if learn:
            self.name = "riccati_auto"

    def start(self, t0: float, y0: np.ndarray, v0: np.ndarray, r0: np.ndarray) -> None:
        # seeded at the first bearing, which is not applied again (as in BiasObserver)
        self.bank = BankRuns(self.prm, y0.shape[0], y0.shape[1])
        self.bank.start(y0, r0)

    def step(self, t: float, h: float, dx: np.ndarray, v: np.ndarray, y: np.ndarray) -> None:
        self.bank.step(dx, h, y)

    def estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        return self.bank.estimate()


class Kalman:
    """One Kalman filter per run on ``[x, a]``: ``ekf`` (tracking form, the estimated
    bearing; prior range std ``1.0 r0``) or ``plkf`` (pseudo-linear form with the constant
    weight range ``r0``; prior range std ``3 r0``). Bias prior std 5 m/s, no process noise
    but the velocity's."""

    def __init__(self, name: str, sigma_rad: float, q_x: float) -> None:
        if name not in ("ekf", "plkf"):
            raise ValueError(name)
        self.name = name
        self.sigma = max(sigma_rad, SIGMA_FLOOR_RAD)
        self.q_x = q_x
        self.tracking = name == "ekf"
        self.range_std = 1.0 if self.tracking else 3.0

    def start(self, t0: float, y0: np.ndarray, v0: np.ndarray, r0: np.ndarray) -> None:
        r0 = np.asarray(r0, dtype=float)
        p0 = initial_covariance(y0, r0, self.range_std * r0, 5.0, self.sigma)
        # the tracking form: r_w 0; the pseudo-linear one: the constant weight range r0
        r_w = np.zeros_like(r0) if self.tracking else r0
        self.f = FilterRuns(r0[:, None] * y0, p0, r_w, self.sigma, self.q_x)
        self.f.update(y0)

    def step(self, t: float, h: float, dx: np.ndarray, v: np.ndarray, y: np.ndarray) -> None:
        self.f.predict(dx, h)
        self.f.update(y)

    def estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        n = self.f.s.shape[1] // 2
        return self.f.s[:, :n], self.f.s[:, n:], self.f.p


def service_config(
    name: str, n: int, sigma_rad: float, velocity_sigma_mps: float, r0: float
) -> ObserverConfig:
    """The product configuration of estimator ``name`` for one run with range guess ``r0``.

    ``riccati`` is the product's default estimator; it is told the
    bearing noise (``bearing_noise_deg``, at least 0.05 deg) and the velocity noise
    (``velocity_noise_mps``)."""
    if name == "paper":
        return ObserverConfig.paper(n=n, initial_range_m=r0)
    if name == "observer02":
        return ObserverConfig.paper(n=n, k_per_s=0.2, k_star_per_s=0.2, initial_range_m=r0)
    if name != "riccati":
        raise NotReadyError(f"{name!r} has no product configuration (it lives only in bench/)")
    return ObserverConfig(
        n=n,
        estimator="riccati",
        initial_range_m=r0,
        bearing_noise_deg=math.degrees(max(sigma_rad, SIGMA_FLOOR_RAD)),
        velocity_noise_mps=velocity_sigma_mps,
    )


class Service:
    """Any product estimator through the service's interface, one ``BiasObserver`` per run:
    ``update_velocity(VelocitySample(t, v))`` then ``update_bearing(BearingSample(t, y))``
    at every sample. Slow (pure Python per sample): use few runs. The covariance is the
    observer's ``covariance`` property when it has one."""

    def __init__(self, name: str, sigma_rad: float, velocity_sigma_mps: float, n: int) -> None:
        self.name = name
        self._make: Callable[[float], ObserverConfig] = lambda r0: service_config(
            name, n, sigma_rad, velocity_sigma_mps, r0
        )
        self._make(1.0)  # fail early if the product is not ready

    def start(self, t0: float, y0: np.ndarray, v0: np.ndarray, r0: np.ndarray) -> None:
        self.obs = [BiasObserver(self._make(float(r))) for r in r0]
        self.x = np.zeros_like(y0)
        self.a = np.zeros_like(y0)
        n = y0.shape[1]
        self._has_cov = hasattr(BiasObserver, "covariance")
        self.p: np.ndarray | None = None
        if self._has_cov:
            self.p = np.full((len(r0), 2 * n, 2 * n), np.nan)
        self.step(t0, 0.0, np.zeros_like(y0), v0, y0)

    def step(self, t: float, h: float, dx: np.ndarray, v: np.ndarray, y: np.ndarray) -> None:
        for i, o in enumerate(self.obs):
            o.update_velocity(VelocitySample(t, v[i]))
            e = o.update_bearing(BearingSample(t, y[i]))
            self.x[i] = e.x_m
            self.a[i] = e.a_mps
            if self.p is not None:
                cov = o.covariance if self._has_cov else None
                self.p[i] = np.nan if cov is None else cov

    def estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        return self.x, self.a, self.p


def make(
    name: str,
    sigma_rad: float,
    velocity_sigma_mps: float,
    n: int,
    dt: float,
    *,
    per_sample: bool = False,
) -> Estimator:
    """Estimator ``name`` (see :data:`ALL`) for bearing noise ``sigma_rad``, velocity noise
    ``velocity_sigma_mps`` sampled every ``dt`` s (process noise ``q_x = sv^2 dt``);
    ``per_sample`` runs ``riccati`` through the service's interface (``paper`` and
    ``observer02`` always are)."""
    q_x = velocity_sigma_mps**2 * dt
    if name in PER_RUN or (per_sample and name == "riccati"):
        return Service(name, sigma_rad, velocity_sigma_mps, n)
    if per_sample:
        raise NotReadyError(f"{name!r} has no product form to drive per sample")
    if name == "riccati":
        return Riccati(sigma_rad, q_x, n)
    if name == "riccati_auto":
        return Riccati(sigma_rad, q_x, n, learn=True)
    if name in ("ekf", "plkf"):
        return Kalman(name, sigma_rad, q_x)
    raise ValueError(f"unknown estimator {name!r}; choose from {KNOWN}")
