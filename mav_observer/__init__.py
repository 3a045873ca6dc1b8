"""mav-observer: position and velocity-bias estimation from a bearing and a velocity.

The estimator is the observer of Le Bras, Hamel, Mahony and Samson (2015); see
``docs/observer.md``. The public core API:

* :class:`~mav_observer.observer.BiasObserver` and
  :class:`~mav_observer.observer.ObserverConfig`;
* the records :class:`~mav_observer.samples.VelocitySample`,
  :class:`~mav_observer.samples.BearingSample`, :class:`~mav_observer.samples.Estimate`
  and :class:`~mav_observer.samples.Status`;
* the errors in :mod:`mav_observer.errors`.
"""

from mav_observer.errors import ConfigError, InvalidSampleError, MavObserverError, StateError
from mav_observer.observer import BiasObserver, ObserverConfig
from mav_observer.samples import BearingSample, Estimate, Status, VelocitySample

__version__ = "0.1.0"

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
