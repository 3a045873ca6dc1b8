"""Drive an observer through a :class:`~sim.stream.Stream` and collect the results (pure)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mav_observer.core.observer import BiasObserver
from mav_observer.core.samples import BearingSample, Estimate
from sim.stream import Stream


@dataclass(frozen=True)
class RunResult:
    """Estimates at every bearing time with the truth there. Shapes (T,) and (T, n)."""

    t_s: np.ndarray
    xhat_m: np.ndarray
    ahat_mps: np.ndarray
    x_true_m: np.ndarray
    a_true_mps: np.ndarray
    status: np.ndarray
    excitation: np.ndarray
    cond_m: np.ndarray
    correction_rel: np.ndarray
    #: the estimator's range standard deviation (m), NaN where it gives none
    range_std_m: np.ndarray | None = None

    @property
    def pos_err_m(self) -> np.ndarray:
        return np.linalg.norm(self.xhat_m - self.x_true_m, axis=1)

    @property
    def bias_err_mps(self) -> np.ndarray:
        return np.linalg.norm(self.ahat_mps - self.a_true_mps, axis=1)

    @property
    def range_m(self) -> np.ndarray:
        return np.linalg.norm(self.x_true_m, axis=1)

    def time_to_stay_below(self, frac: float) -> float | None:
        """First time (s) after which the position error stays below ``frac`` of the range;
        ``None`` if it never does."""
        bad = np.nonzero(self.pos_err_m >= frac * self.range_m)[0]
        if len(bad) == 0:
            return float(self.t_s[0])
        if bad[-1] + 1 >= len(self.t_s):
            return None
        return float(self.t_s[bad[-1] + 1])

    def at(self, t_s: float) -> int:
        """Index of the last estimate at or before ``t_s``."""
        return int(np.searchsorted(self.t_s, t_s, side="right") - 1)


def run(observer: BiasObserver, stream: Stream) -> RunResult:
    """Feed every sample of ``stream`` to ``observer`` in time order."""
    ests: list[Estimate] = []
    for ev in stream.events():
        if isinstance(ev, BearingSample):
            ests.append(observer.update_bearing(ev))
        else:
            observer.update_velocity(ev)
    t = np.array([e.t_s for e in ests])
    truth_idx = np.searchsorted(stream.t_bearing_s, t)
    n = stream.scenario.n
    return RunResult(
        t_s=t,
        xhat_m=np.array([e.x_m for e in ests]).reshape(-1, n),
        ahat_mps=np.array([e.a_mps for e in ests]).reshape(-1, n),
        x_true_m=stream.x_true_m[truth_idx],
        a_true_mps=np.broadcast_to(stream.scenario.a_mps, (len(t), n)).copy(),
        status=np.array([str(e.status) for e in ests]),
        excitation=np.array([e.excitation for e in ests]),
        cond_m=np.array([e.cond_m for e in ests]),
        correction_rel=np.array([e.correction_rel for e in ests]),
        range_std_m=np.array([math.nan if e.range_std_m is None else e.range_std_m for e in ests]),
    )
