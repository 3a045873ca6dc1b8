"""The bearings' latency behind the line of sight, learnt online (pure).

A gimbal's controller trails a moving line of sight (a first-order lag of 0.1 s is a
delay of about 0.1 s), a camera's timestamp is taken after the exposure, a servo mount
moves late: the bearing at ``t`` is then the line of sight at ``t - tau``, ``y(t) =
x(t - tau) / |x(t - tau)|``, ``x(t - tau) ~ x(t) - tau (v + a)``. A filter told nothing of
it sees a bearing error that follows the line of sight's rate ``w = (I - y y^T)(v + a) / |x|``
(rad/s): correlated over seconds, which no white noise level and no constant bias explains
(the e2e case ``gimbal_lag``: 1.55x the bound, NEES 3; with the bias's random walk learnt,
25.9x, the error taken for a wandering bias).

:class:`LatencyLearner` regresses the filter's tangent innovation ``z = (I - yh yh^T) y``
(``yh`` the estimate's direction, not shifted) on ``w``: ``z ~ -tau w``, so ``tau = -sum z.w
/ sum |w|^2``, with an exponential forgetting of :data:`MEMORY_S` and a zero-mean prior of
:data:`PRIOR_S` (a ridge: ``sum |w|^2`` plus ``sigma^2 / PRIOR_S^2``), only from a converged
estimate and bearings within 3 sigma of it with the latency in use. The estimator then
brings each bearing forward by ``tau w`` (:func:`advance`; to first order the same as applying
it to the state moved back by ``tau (v + a)``, and a few float operations instead of moving
every filter of the bank: that cost 15 % per bearing).
A line of sight that hardly turns teaches nothing and the prior keeps ``tau`` near 0.
No I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

#: The forgetting time constant (s) of the regression.
MEMORY_S = 120.0
#: The prior's standard deviation (s) of the latency.
PRIOR_S = 0.05
#: A bearing further than this many sigma from the estimate teaches nothing.
GATE_SIGMA = 3.0


def los_rate(u: list[float], r_m: float, a_mps: list[float], v_mps: list[float]) -> list[float]:
    """The line of sight's rate (rad/s) along the unit direction ``u`` at the range ``r_m``
    (m > 0): ``w = (I - u u^T)(v + a) / r``, ``v_mps`` the paper's ``v``, ``a_mps`` the bias."""
    n = len(u)
    xd = [v_mps[j] + a_mps[j] for j in range(n)]
    along = sum(xd[j] * u[j] for j in range(n))
    return [(xd[j] - along * u[j]) / r_m for j in range(n)]


def advance(
    y: list[float], x_m: list[float], a_mps: list[float], v_mps: list[float], tau_s: float
) -> list[float]:
    """The bearing ``y`` (unit) that shows the line of sight ``tau_s`` late, brought forward
    to its own time along the estimate's line of sight rate: ``y + tau w``, re-normalised,
    ``w = (I - y y^T)(v + a) / |x|`` (to first order in ``tau``, the same as applying ``y`` to
    the state moved back by ``tau (v + a)``)."""
    r = math.sqrt(sum(c * c for c in x_m))
    if r <= 0.0:
        return y
    w = los_rate(y, r, a_mps, v_mps)
    out = [y[j] + tau_s * w[j] for j in range(len(y))]
    inv = 1.0 / math.sqrt(sum(c * c for c in out))
    return [c * inv for c in out]


class LatencyStateError(ValueError):
    """A saved latency state is malformed (the message names the field)."""


@dataclass
class LatencyLearner:
    """Learns the bearings' latency (s; positive: the bearing trails the line of sight).

    ``max_s``: the latency learnt stays within +-``max_s``."""

    max_s: float = 0.5
    s_zw: float = 0.0
    s_ww: float = 0.0
    tau_s: float = 0.0
    t_s: float | None = None
    #: time (s) of the first bearing learnt from
    t0_s: float | None = None

    def copy(self) -> LatencyLearner:
        return LatencyLearner(self.max_s, self.s_zw, self.s_ww, self.tau_s, self.t_s, self.t0_s)

    def learning_for_s(self, t_s: float) -> float:
        """How long (s) it has been learning at ``t_s`` (s): 0 before its first bearing."""
        return 0.0 if self.t0_s is None else max(t_s - self.t0_s, 0.0)

    def observe(
        self,
        t_s: float,
        x_m: list[float],
        a_mps: list[float],
        v_mps: list[float],
        y: list[float],
        sig2_rad2: float,
    ) -> None:
        """One bearing ``y`` (unit) at ``t_s`` (s, in time order) against a converged
        estimate ``x_m`` (m), ``a_mps`` (m/s) with the velocity ``v_mps`` (m/s, the paper's
        ``v``) and the bearing noise variance in use ``sig2_rad2`` (rad^2)."""
        n = len(x_m)
        r2 = sum(c * c for c in x_m)
        if r2 <= 0.0 or sig2_rad2 <= 0.0:
            return
        r = math.sqrt(r2)
        yh = [c / r for c in x_m]
        w = los_rate(yh, r, a_mps, v_mps)
        y_along = sum(y[j] * yh[j] for j in range(n))
        z = [y[j] - y_along * yh[j] for j in range(n)]
        tau = self.tau_s
        if sum((z[j] + tau * w[j]) ** 2 for j in range(n)) > GATE_SIGMA**2 * (n - 1) * sig2_rad2:
            return  # an outlier (beyond the latency in use) says nothing of the latency
        rho = 1.0 if self.t_s is None else math.exp(-max(t_s - self.t_s, 0.0) / MEMORY_S)
        self.t_s = t_s
        if self.t0_s is None:
            self.t0_s = t_s
        self.s_zw = rho * self.s_zw + sum(z[j] * w[j] for j in range(n))
        self.s_ww = rho * self.s_ww + sum(c * c for c in w)
        tau = -self.s_zw / (self.s_ww + sig2_rad2 / PRIOR_S**2)
        self.tau_s = max(-self.max_s, min(self.max_s, tau))

    def to_dict(self) -> dict[str, Any]:
        return {
            "s_zw": self.s_zw,
            "s_ww": self.s_ww,
            "tau_s": self.tau_s,
            "t_s": self.t_s,
            "t0_s": self.t0_s,
        }

    def restore(self, d: Any) -> None:
        """Restore what :meth:`to_dict` saved (``max_s`` from the constructor)."""
        try:
            s_zw, s_ww, tau = float(d["s_zw"]), float(d["s_ww"]), float(d["tau_s"])
            t = None if d["t_s"] is None else float(d["t_s"])
            t0_raw = d.get("t0_s", t)  # (absent from states saved before it: the latest)
            t0 = None if t0_raw is None else float(t0_raw)
        except (KeyError, TypeError, ValueError) as exc:
            raise LatencyStateError(f"latency state is malformed: {exc!r}") from exc
        for name, v in (("s_zw", s_zw), ("s_ww", s_ww), ("tau_s", tau), ("t_s", t), ("t0_s", t0)):
            if v is not None and not math.isfinite(v):
                raise LatencyStateError(f"latency state {name}={v!r} must be finite")
        if s_ww < 0.0 or abs(tau) > self.max_s:
            raise LatencyStateError(
                f"latency state s_ww={s_ww!r} must be >= 0 and tau_s={tau!r} within "
                f"+-{self.max_s} s"
            )
        self.s_zw, self.s_ww, self.tau_s, self.t_s, self.t0_s = s_zw, s_ww, tau, t, t0


@dataclass
class Settling:
    """Whether a learnt latency has settled: learning for at least ``after_s`` (s) and moved
    by less than ``step_s`` (s) over the latest window of ``window_s`` (s), checked once per
    window (windows from the first time seen). A latency still moving (an estimate
    converging, a gimbal's lag being learnt) leaves a bearing error correlated over seconds."""

    window_s: float = 20.0
    step_s: float = 0.003
    after_s: float = 30.0
    t_ref_s: float | None = None
    tau_ref_s: float = 0.0
    settled: bool = False

    def update(self, t_s: float, tau_s: float, learning_for_s: float) -> bool:
        """Account the latency ``tau_s`` (s) learnt for ``learning_for_s`` (s) at ``t_s``
        (s); returns whether it has settled."""
        if self.t_ref_s is None or t_s < self.t_ref_s:
            self.t_ref_s, self.tau_ref_s = t_s, tau_s
        elif t_s - self.t_ref_s >= self.window_s:
            self.settled = (
                learning_for_s >= self.after_s and abs(tau_s - self.tau_ref_s) < self.step_s
            )
            self.t_ref_s, self.tau_ref_s = t_s, tau_s
        return self.settled

    def copy(self) -> Settling:
        """A copy (``dataclasses.replace`` costs five times as much on the per-sample path)."""
        other = object.__new__(Settling)
        other.__dict__.update(self.__dict__)
        return other
