"""mav-observer: position and velocity-bias estimation from a bearing and a velocity.

The estimator is the observer of Le Bras, Hamel, Mahony and Samson (2015); see
``docs/observer.md``. The public core API:

* :class:`~mav_observer.core.observer.BiasObserver` and
  :class:`~mav_observer.core.config.ObserverConfig`;
* the records :class:`~mav_observer.core.samples.VelocitySample`,
  :class:`~mav_observer.core.samples.BearingSample`,
  :class:`~mav_observer.core.samples.Estimate` and :class:`~mav_observer.core.samples.Status`;
* the errors in :mod:`mav_observer.errors`.

Each name is imported when first used: ``import mav_observer`` loads neither numpy nor the
compiled estimator (numba), which ``--help`` or a listener do not need.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from mav_observer.errors import ConfigError, InvalidSampleError, MavObserverError, StateError

if TYPE_CHECKING:
    from mav_observer.core.config import ObserverConfig
    from mav_observer.core.observer import BiasObserver
    from mav_observer.core.samples import BearingSample, Estimate, Status, VelocitySample

__version__ = "0.1.0"

_LAZY = {
    "BiasObserver": "mav_observer.core.observer",
    "ObserverConfig": "mav_observer.core.config",
    "BearingSample": "mav_observer.core.samples",
    "Estimate": "mav_observer.core.samples",
    "Status": "mav_observer.core.samples",
    "VelocitySample": "mav_observer.core.samples",
}

__all__ = [
    "BearingSample",
    "BiasObserver",
    "ConfigError",
    "Estimate",
    "InvalidSampleError",
    "MavObserverError",
    "ObserverConfig",
    "StateError",
    "Status",
    "VelocitySample",
    "__version__",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'mav_observer' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
