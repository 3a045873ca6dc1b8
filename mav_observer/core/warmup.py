"""Every compiled entry point run once on a throw-away observer, so that numba compiles (on
a machine's first run) or loads (from its cache) them all before the first sample counts."""

from __future__ import annotations

from types import ModuleType

import numpy as np

from mav_observer.core.config import ObserverConfig
from mav_observer.core.kernels import observer as kernels
from mav_observer.core.state import new_state


def warm() -> ModuleType:
    """Run each entry point of :mod:`mav_observer.core.kernels.observer` once (both
    estimators, live and committed); returns the module."""
    k = kernels
    for config, committed in ((ObserverConfig(), True), (ObserverConfig.paper(), False)):
        buf = new_state(config, committed).buf
        y = np.array([0.6, 0.0, 0.8])
        v = np.array([1.0, 0.0, 0.0])
        k.run(k.OP_VELOCITY, buf, 0.0, v, v)
        k.run(k.OP_BEARING_LIVE, buf, 0.05, y, y)
        k.run(k.OP_VELOCITY_MEAN, buf, 0.1, v, v)
        k.run(k.OP_PREDICT, buf, 0.2, v, v)
        k.run(k.OP_COMMIT_PENDING, buf, 0.2, v, v)
        k.run(k.OP_RESUME, buf, 0.3, v, v)
        k.run(k.OP_OUTPUT, buf, 0.0, v, v)
        k.run(k.OP_DISPLACEMENT, buf, 0.3, v, v)
    return kernels
