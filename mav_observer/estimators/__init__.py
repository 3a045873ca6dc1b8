"""The estimators of ``x`` and ``a`` behind :class:`~mav_observer.observer.BiasObserver`,
each one implementation of :class:`~mav_observer.estimators.base.Estimator`.

A new estimator is one module and one line of :data:`REGISTRY`.
"""

from __future__ import annotations

from collections.abc import Callable

from mav_observer.config import ObserverConfig
from mav_observer.estimators.base import Estimator, Inputs, Output
from mav_observer.estimators.paper import PaperEstimator
from mav_observer.estimators.riccati import RiccatiEstimator

#: ``ObserverConfig.estimator`` -> the estimator built from the configuration; the first is
#: the default.
REGISTRY: dict[str, Callable[[ObserverConfig], Estimator]] = {
    "riccati": RiccatiEstimator,
    "paper": PaperEstimator,
}

__all__ = ["REGISTRY", "Estimator", "Inputs", "Output", "PaperEstimator", "RiccatiEstimator"]
