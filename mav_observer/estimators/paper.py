"""The observer of Le Bras, Hamel, Mahony and Samson (2015), exact (:mod:`mav_observer.discrete`).

State ``(xh1, M, ahat)`` as lists of floats (``M`` flat, row-major); the estimate is
``xhat = M ahat + xh1``. It corrects continuously from the interpolated bearing: each
sub-step integrates the paper's equations closed-form with the inputs frozen at its midpoint,
``discrete.substep_count`` sub-steps per interval. With ``static_hold`` a sub-step whose
estimated relative velocity ``|v + ahat|`` is below ``hold_speed_mps`` and whose bearing agrees
with the estimate (within ``hold_innovation_deg``) is held instead of integrated (see
:mod:`mav_observer.observer`). No covariance.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from mav_observer import discrete
from mav_observer.config import ObserverConfig
from mav_observer.errors import StateError
from mav_observer.estimators.base import Inputs, Output
from mav_observer.samples import NoiseLevels
from mav_observer.streams import MIN_INTERVAL_S


class PaperEstimator:
    """The paper's observer (``estimator = "paper"``)."""

    name: ClassVar[str] = "paper"
    continuous: ClassVar[bool] = True

    def __init__(self, config: ObserverConfig) -> None:
        self.config = config
        self._k, self._ks = config.k_per_s, config.k_star_per_s
        self._biased = config.mode == "biased"
        self._hold = config.static_hold
        self._hold_speed2 = config.hold_speed_mps**2
        self._hold_cos = math.cos(math.radians(config.hold_innovation_deg))
        self._min_interval_s = MIN_INTERVAL_S if config.interpolation == "linear" else 0.0
        self.xh1, self.m, self.ahat = config.initial_state()
        self._started = False
        self._x: list[float] | None = None  # xhat, cached

    # -- the paper's state -----------------------------------------------------------
    @property
    def zs_mps(self) -> np.ndarray:
        """The paper's dual state ``zs`` (m/s)."""
        return np.array(discrete.zs_from_state(self.ahat, self.xh1, self.m))

    @property
    def xh1_m(self) -> np.ndarray:
        """The first filter ``xh1`` (m)."""
        return np.array(self.xh1)

    @property
    def m_s(self) -> np.ndarray:
        """The matrix ``M`` (s)."""
        n = self.config.n
        return np.array(self.m).reshape(n, n)

    # -- the interface ---------------------------------------------------------------
    @property
    def min_interval_s(self) -> float:
        return self._min_interval_s

    @property
    def started(self) -> bool:
        return self._started

    @property
    def settled(self) -> bool:
        return True  # it learns nothing beside its state

    def start(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        cfg = self.config
        if cfg.initial_range_m is not None:
            _, m, _ = cfg.initial_state()
            # xhat = M ahat + xh1 with ahat = 0
            self.xh1, self.m, self.ahat = [cfg.initial_range_m * c for c in y], m, [0.0] * cfg.n
            self._x = None
        self._started = True

    def copy(self) -> PaperEstimator:
        other = object.__new__(PaperEstimator)
        other.__dict__.update(self.__dict__)
        return other

    def substeps(self, span_s: float, corrected: bool) -> int:
        return discrete.substep_count(self._k, self._ks, span_s) if corrected else 1

    def predict(
        self, t_s: float, h_s: float, v_mps: list[float], y: list[float] | None, inputs: Inputs
    ) -> list[float]:
        xh1, m, ahat = self.xh1, self.m, self.ahat
        if self._hold and y is not None and self._static(v_mps, y):
            return [0.0] * len(v_mps)
        moved = [h_s * (p + q) for p, q in zip(v_mps, ahat, strict=True)]
        self.xh1, self.m, self.ahat = discrete.substep(
            xh1, m, ahat, y, v_mps, self._k, self._ks, h_s, estimate_bias=self._biased
        )
        self._x = None
        return moved

    def _static(self, v: list[float], y: list[float]) -> bool:
        """Static-geometry test: estimated relative velocity ``v + ahat`` at most the hold
        speed, and the bearing ``y`` within the hold angle of the estimate ``xhat``."""
        rel2 = 0.0
        for p, q in zip(v, self.ahat, strict=True):
            rel2 += (p + q) * (p + q)
        if rel2 > self._hold_speed2:
            return False
        xhat = discrete.estimate_from_state(self.ahat, self.xh1, self.m)
        r2 = discrete.dot(xhat, xhat)
        if r2 <= 0.0:
            return False
        return discrete.dot(xhat, y) >= self._hold_cos * math.sqrt(r2)

    def update(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        """Nothing: the paper's observer corrects continuously, in :meth:`predict`."""

    def output(self, inputs: Inputs) -> Output:
        if self._x is None:
            self._x = discrete.estimate_from_state(self.ahat, self.xh1, self.m)
        return Output(self._x, self.ahat, None)

    def position_cov(self, dt_s: float, inputs: Inputs) -> list[float] | None:
        return None

    def cond(self) -> float:
        return discrete.cond2(self.m, self.config.n)

    def nis(self) -> float | None:
        return None

    def noise(self, inputs: Inputs) -> NoiseLevels | None:
        return None

    @property
    def reacquisitions(self) -> int:
        return 0

    def observe_velocity(self, t_s: float, v_mps: list[float]) -> None:
        """Nothing: the paper's observer has no noise to learn."""

    def shift(self, dx_m: list[float]) -> None:
        self.xh1 = [p + q for p, q in zip(self.xh1, dx_m, strict=True)]
        self._x = None

    def to_dict(self) -> dict[str, Any]:
        n = self.config.n
        return {
            "xh1": list(self.xh1),
            "m": [self.m[i * n : (i + 1) * n] for i in range(n)],
            "ahat": list(self.ahat),
        }

    def restore(self, d: dict[str, Any], started: bool) -> None:
        n = self.config.n
        self.xh1 = _field_array(d, "xh1", (n,)).tolist()
        self.m = _field_array(d, "m", (n, n)).ravel().tolist()
        self.ahat = _field_array(d, "ahat", (n,)).tolist()
        self._started = started
        self._x = None


def _field_array(d: dict[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray:
    """The saved array ``d[key]``, checked: finite, of ``shape``."""
    if key not in d:
        raise StateError(f"observer state has no {key!r}")
    try:
        arr = np.array(d[key], dtype=float)
    except (TypeError, ValueError) as exc:
        raise StateError(f"observer state {key!r}={d[key]!r} is not numeric") from exc
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise StateError(
            f"observer state {key!r} must be finite with shape {shape}, got {d[key]!r}"
        )
    return arr
