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
estimate and bearings within 3 sigma of it with the latency in use. That fit takes any
bearing error that happens to follow ``w`` for a while for a latency (a velocity bias
wandering over a minute, before the bias's walk is learnt, gave 0.1 s on a stream with none,
and a filter whose walk is then learnt absorbs the wrong latency's error rather than showing
it: measured, the innovations with 0 and 0.1 s differ by 0.3 % in mean square), so the
latency used (``tau_s``) is the fit only where it stands out of the scatter of its
:data:`BLOCK_S` blocks by :data:`SIGNIFICANCE_SIGMA` standard deviations (a sandwich variance
from the blocks' scores: a lag explains every block alike), shrunk by the rest. The estimator then
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
#: The regression's scatter is measured over blocks of this long (s) ...
BLOCK_S = 10.0
#: ... and the latency fitted is used only where it stands out of that scatter by this many
#: standard deviations, shrunk toward 0 by the rest (``tau (1 - k^2 var / tau^2)``).
SIGNIFICANCE_SIGMA = 2.0
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
    #: the latency fitted (s), before the significance shrink that makes ``tau_s``
    tau_fit_s: float = 0.0
    #: the block being gathered: its start (s) and its sums of ``z.w`` and ``|w|^2``
    b_t0_s: float | None = None
    b_zw: float = 0.0
    b_ww: float = 0.0
    #: the closed blocks' scatter (forgotten as the sums are): the sums of their ``z.w``
    #: squared, ``z.w`` times ``|w|^2``, ``|w|^2`` squared, and their number
    q_zz: float = 0.0
    q_zw: float = 0.0
    q_ww: float = 0.0
    n_b: float = 0.0

    def copy(self) -> LatencyLearner:
        other = object.__new__(LatencyLearner)
        other.__dict__.update(self.__dict__)
        return other

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
        if n == 3:  # unrolled (the per-bearing path): the same arithmetic
            x0, x1, x2 = x_m
            r2 = x0 * x0 + x1 * x1 + x2 * x2
            if r2 <= 0.0 or sig2_rad2 <= 0.0:
                return
            r = math.sqrt(r2)
            u0, u1, u2 = x0 / r, x1 / r, x2 / r
            d0, d1, d2 = v_mps[0] + a_mps[0], v_mps[1] + a_mps[1], v_mps[2] + a_mps[2]
            along = d0 * u0 + d1 * u1 + d2 * u2
            w = [(d0 - along * u0) / r, (d1 - along * u1) / r, (d2 - along * u2) / r]
            y_along = y[0] * u0 + y[1] * u1 + y[2] * u2
            z = [y[0] - y_along * u0, y[1] - y_along * u1, y[2] - y_along * u2]
            tau = self.tau_s
            e0, e1, e2 = z[0] + tau * w[0], z[1] + tau * w[1], z[2] + tau * w[2]
            if e0**2 + e1**2 + e2**2 > GATE_SIGMA**2 * (n - 1) * sig2_rad2:
                return  # an outlier (beyond the latency in use) says nothing of the latency
        else:
            r2 = sum(c * c for c in x_m)
            if r2 <= 0.0 or sig2_rad2 <= 0.0:
                return
            r = math.sqrt(r2)
            yh = [c / r for c in x_m]
            w = los_rate(yh, r, a_mps, v_mps)
            y_along = sum(y[j] * yh[j] for j in range(n))
            z = [y[j] - y_along * yh[j] for j in range(n)]
            tau = self.tau_s
            miss2 = sum((z[j] + tau * w[j]) ** 2 for j in range(n))
            if miss2 > GATE_SIGMA**2 * (n - 1) * sig2_rad2:
                return  # an outlier (beyond the latency in use) says nothing of the latency
        rho = 1.0 if self.t_s is None else math.exp(-max(t_s - self.t_s, 0.0) / MEMORY_S)
        self.t_s = t_s
        if self.t0_s is None:
            self.t0_s = t_s
        if n == 3:
            zw = z[0] * w[0] + z[1] * w[1] + z[2] * w[2]
            ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
        else:
            zw = sum(z[j] * w[j] for j in range(n))
            ww = sum(c * c for c in w)
        self.s_zw = rho * self.s_zw + zw
        self.s_ww = rho * self.s_ww + ww
        if self.b_t0_s is None or t_s < self.b_t0_s:
            self.b_t0_s, self.b_zw, self.b_ww = t_s, 0.0, 0.0
        elif t_s - self.b_t0_s >= BLOCK_S:  # the block closes: its score into the scatter
            f = math.exp(-(t_s - self.b_t0_s) / MEMORY_S)
            self.q_zz = f * self.q_zz + self.b_zw * self.b_zw
            self.q_zw = f * self.q_zw + self.b_zw * self.b_ww
            self.q_ww = f * self.q_ww + self.b_ww * self.b_ww
            self.n_b = f * self.n_b + 1.0
            self.b_t0_s, self.b_zw, self.b_ww = t_s, 0.0, 0.0
        self.b_zw += zw
        self.b_ww += ww
        tau = -self.s_zw / (self.s_ww + sig2_rad2 / PRIOR_S**2)
        self.tau_fit_s = tau
        self.tau_s = max(-self.max_s, min(self.max_s, self._significant(tau)))

    def _significant(self, tau: float) -> float:
        """The fitted latency ``tau`` (s) shrunk by its variance measured from the blocks'
        scatter (a sandwich estimate: the blocks' scores ``sum z.w + tau sum |w|^2`` are
        what the regression leaves; bearings' errors correlated over seconds, which a white
        noise level would call information, show there): 0 before two blocks."""
        if self.n_b < 1.5 or self.s_ww <= 0.0:
            return 0.0
        u2 = self.q_zz + 2.0 * tau * self.q_zw + tau * tau * self.q_ww
        var = max(u2, 0.0) / (self.s_ww * self.s_ww) * self.n_b / (self.n_b - 1.0)
        k2 = SIGNIFICANCE_SIGMA**2
        if tau * tau <= k2 * var:
            return 0.0
        return tau * (1.0 - k2 * var / (tau * tau))

    #: the fields saved besides ``tau_s`` and the times (0 when absent from an older state)
    _SUMS = ("s_zw", "s_ww", "tau_fit_s", "b_zw", "b_ww", "q_zz", "q_zw", "q_ww", "n_b")

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: getattr(self, k) for k in self._SUMS}
        out.update(tau_s=self.tau_s, t_s=self.t_s, t0_s=self.t0_s, b_t0_s=self.b_t0_s)
        return out

    def restore(self, d: Any) -> None:
        """Restore what :meth:`to_dict` saved (``max_s`` from the constructor)."""
        try:
            sums = {k: float(d[k]) if k in ("s_zw", "s_ww") else float(d.get(k, 0.0))
                    for k in self._SUMS}  # fmt: skip
            tau = float(d["tau_s"])
            t = None if d["t_s"] is None else float(d["t_s"])
            t0_raw = d.get("t0_s", t)  # (absent from states saved before it: the latest)
            t0 = None if t0_raw is None else float(t0_raw)
            b_raw = d.get("b_t0_s")
            b0 = None if b_raw is None else float(b_raw)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise LatencyStateError(f"latency state is malformed: {exc!r}") from exc
        for name, v in (*sums.items(), ("tau_s", tau), ("t_s", t), ("t0_s", t0), ("b_t0_s", b0)):
            if v is not None and not math.isfinite(v):
                raise LatencyStateError(f"latency state {name}={v!r} must be finite")
        if sums["s_ww"] < 0.0 or sums["n_b"] < 0.0 or abs(tau) > self.max_s:
            raise LatencyStateError(
                f"latency state s_ww={sums['s_ww']!r} and n_b={sums['n_b']!r} must be >= 0 "
                f"and tau_s={tau!r} within +-{self.max_s} s"
            )
        for k, v in sums.items():
            setattr(self, k, v)
        self.tau_s, self.t_s, self.t0_s, self.b_t0_s = tau, t, t0, b0


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
