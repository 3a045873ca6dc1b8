"""Data, the Cramér-Rao bound and the metrics of the accuracy harness (batched over runs).

Arrays: ``R`` runs, ``T`` sample instants, dimension ``n``. Bearings and velocity are sampled
at the same instants (20 Hz by default); the noise models are the simulator's
(:func:`sim.stream.perturb_bearings`: isotropic Gaussian angular noise of ``sigma`` per
tangent direction; Gaussian noise on every component of ``v``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim import scenarios
from sim.scenarios import Scenario
from sim.stream import Noise, perturb_bearings, sample_times

SCENARIOS = ("paper", "orbit", "moving_target", "straight_pass", "planar")
#: Window of the steady-state metrics: the last ``STEADY_S`` seconds of a run.
STEADY_S = 100.0
#: A run "converged" once its position error stays below this fraction of the range.
CONVERGED_REL = 0.10
#: A run diverged if its final position error exceeds this fraction of the range.
DIVERGED_REL = 0.50
#: Smallest bearing noise an estimator is told (rad): exact bearings still get a small R.
SIGMA_FLOOR_RAD = math.radians(0.05)


@dataclass(frozen=True)
class Case:
    """One cell of the grid: a scenario and its noise."""

    scenario: str
    bearing_deg: float
    velocity_mps: float

    @property
    def label(self) -> str:
        return f"{self.scenario} {self.bearing_deg:g} deg {self.velocity_mps:g} m/s"

    def key(self) -> tuple[int, int, int]:
        """Integers naming the case in the random streams' seeds."""
        return (
            SCENARIOS.index(self.scenario) if self.scenario in SCENARIOS else 99,
            round(self.bearing_deg * 1000),
            round(self.velocity_mps * 1000),
        )


@dataclass
class Data:
    """Sampled runs of one case: truth ``x`` (T, n), bearings ``y`` (R, T, n), velocity
    ``v`` (R, T, n), range guesses ``r0`` (R,)."""

    case: Case
    scenario: Scenario
    t: np.ndarray
    x: np.ndarray
    a: np.ndarray
    y: np.ndarray
    v: np.ndarray
    r0: np.ndarray
    dt: float = field(default=0.05)

    @property
    def runs(self) -> int:
        return self.y.shape[0]

    @property
    def n(self) -> int:
        return self.x.shape[1]

    @property
    def sigma_rad(self) -> float:
        return math.radians(self.case.bearing_deg)

    def dx(self, k: int) -> np.ndarray:
        """Each run's integral of ``v`` from sample ``k - 1`` to ``k`` (trapezoid, the exact
        integral of the linearly interpolated velocity), (R, n)."""
        h = self.t[k] - self.t[k - 1]
        return 0.5 * h * (self.v[:, k - 1] + self.v[:, k])


def generate(
    case: Case,
    runs: int,
    *,
    seed: int = 0,
    rate_hz: float = 20.0,
    duration_s: float | None = None,
    range_factor: float = 1.0,
    random_init: bool = False,
    first_run: int = 0,
) -> Data:
    """Runs ``first_run .. first_run + runs - 1`` of ``case``. Run ``i`` has its own random
    stream (seeded by ``seed``, the case and ``i``), so a run is the same whatever ``runs``.

    The range guess is the true initial range times ``range_factor``, or with
    ``random_init`` times ``10 ** U(-1, 1)`` (drawn from the run's stream after its noise).
    """
    sc = scenarios.make(case.scenario)
    dur = sc.duration_s if duration_s is None else duration_s
    t = sample_times(rate_hz, dur, np.random.default_rng(0), Noise())
    x = sc.x(t)
    v_true = sc.v(t)
    y_true = x / np.linalg.norm(x, axis=1, keepdims=True)
    sig = math.radians(case.bearing_deg)
    r_true0 = float(np.linalg.norm(x[0]))
    ys = np.empty((runs, *x.shape))
    vs = np.empty((runs, *x.shape))
    r0 = np.full(runs, r_true0 * range_factor)
    for j in range(runs):
        rng = np.random.default_rng([seed, *case.key(), first_run + j])
        ys[j] = perturb_bearings(y_true, sig, rng)
        vs[j] = v_true
        if case.velocity_mps > 0.0:
            vs[j] += rng.normal(0.0, case.velocity_mps, x.shape)
        if random_init:
            r0[j] = r_true0 * 10.0 ** rng.uniform(-1.0, 1.0)
    return Data(case, sc, t, x, np.asarray(sc.a_mps, dtype=float), ys, vs, r0, 1.0 / rate_hz)


def crlb(
    t: np.ndarray,
    x: np.ndarray,
    sigma_rad: float,
    q_x: float = 0.0,
    prior_info: float = 1e-9,
    gm_std_mps: float = 0.0,
    gm_tau_s: float = math.inf,
    range_sigma_m: float = 0.0,
) -> np.ndarray:
    """Posterior Cramér-Rao bound of the position, ``sqrt(trace(J^-1)_xx)`` (m) at every
    sample (T,), for the state ``[x, a]`` with ``x' = v + a + w`` (``w`` white of intensity
    ``q_x`` m^2/s, the velocity's noise), ``a`` constant, and bearings with angular noise
    ``sigma_rad`` per tangent direction, from the information recursion

    ``J_k = (F J_{k-1}^-1 F^T + Q)^-1 + H_k^T H_k / sigma^2``, ``H_k = [E_k^T / r_k, 0]``

    along the true trajectory ``x`` (T, n); ``prior_info`` is a (negligible) prior
    information on every state component. The predicted information is computed without
    inverting ``J`` (``Q = G q G^T`` with ``G = [I, 0]^T``, Woodbury), so a nearly singular
    ``J`` early on is harmless.

    With ``gm_std_mps > 0`` the velocity error also has a first-order Gauss-Markov part
    (stationary standard deviation ``gm_std_mps`` per axis, correlation time ``gm_tau_s``),
    and the bound is :func:`crlb_gauss_markov`'s (the state augmented with it). With
    ``range_sigma_m > 0`` every bearing comes with a measured range of that noise: its
    information ``u u^T / sigma_r^2`` (``u = x / |x|``) is added to the bearing's.
    """
    if not sigma_rad > 0.0:
        raise ValueError("the bound needs a bearing noise > 0")
    if gm_std_mps > 0.0:
        return crlb_gauss_markov(t, x, sigma_rad, q_x, gm_std_mps, gm_tau_s, prior_info)
    n = x.shape[1]
    info = _bearing_info(x, sigma_rad)
    if range_sigma_m > 0.0:
        u = x / np.linalg.norm(x, axis=1)[:, None]
        info = info + u[:, :, None] * u[:, None, :] / range_sigma_m**2
    j = np.eye(2 * n) * prior_info
    out = np.empty(len(t))
    eye = np.eye(n)
    for k in range(len(t)):
        if k > 0:
            h = t[k] - t[k - 1]
            finv = np.eye(2 * n)
            finv[:n, n:] = -h * eye
            j = finv.T @ j @ finv
            q = q_x * h
            if q > 0.0:
                jg = j[:, :n]  # A G
                m = eye / q + j[:n, :n]
                j = j - jg @ np.linalg.solve(m, jg.T)
            j = 0.5 * (j + j.T)
        j[:n, :n] += info[k]
        cov = np.linalg.inv(j)
        out[k] = math.sqrt(max(np.trace(cov[:n, :n]), 0.0))
    return out


def _bearing_info(x: np.ndarray, sigma_rad: float) -> np.ndarray:
    """The information of a bearing on the position, ``H_k^T H_k / sigma^2`` (T, n, n)."""
    r = np.linalg.norm(x, axis=1)
    u = x / r[:, None]
    # E E^T over the tangent plane's orthonormal basis E is the projection I - u u^T
    proj = np.eye(x.shape[1]) - u[:, :, None] * u[:, None, :]
    return proj / (r[:, None, None] ** 2 * sigma_rad**2)


def gauss_markov_step(
    h_s: float, q_x: float, gm_std_mps: float, gm_tau_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The exact discretisation over ``h_s`` of one axis of ``[x, c, g]`` with
    ``x' = v + c + g + w`` (``w`` white, ``q_x`` m^2/s), ``c' = 0`` and the Gauss-Markov
    ``g' = -g / tau + u`` (``u`` white of intensity ``2 std^2 / tau``, so that ``g`` stays at
    ``std``): ``(F (3, 3), Q (3, 3))``."""
    h, tau = float(h_s), float(gm_tau_s)
    em1 = -math.expm1(-h / tau)  # 1 - exp(-h / tau), exact for small steps
    em2 = -math.expm1(-2.0 * h / tau)  # 1 - exp(-2 h / tau)
    qg = 2.0 * gm_std_mps**2 / tau
    # x's share of g over the step, tau (1 - e), and its noise: integrals of the kernel
    # tau (1 - exp(-u / tau)) (x) and exp(-u / tau) (g) over u in [0, h]
    u = h / tau
    if u < 1e-3:  # the series, free of the cancellation of h - 2 tau e1 + tau e2 / 2
        xx = qg * h**3 / 3.0 * (1.0 - 0.75 * u + 7.0 / 20.0 * u * u)
        xg = qg * h * h / 2.0 * (1.0 - u + 7.0 / 12.0 * u * u)
    else:
        xx = qg * tau * tau * (h - 2.0 * tau * em1 + 0.5 * tau * em2)
        xg = qg * tau * (tau * em1 - 0.5 * tau * em2)
    f = np.array([[1.0, h, tau * em1], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0 - em1]])
    q = np.array([[q_x * h + xx, 0.0, xg], [0.0, 0.0, 0.0], [xg, 0.0, gm_std_mps**2 * em2]])
    return f, q


def crlb_gauss_markov(
    t: np.ndarray,
    x: np.ndarray,
    sigma_rad: float,
    q_x: float,
    gm_std_mps: float,
    gm_tau_s: float,
    prior_info: float = 1e-9,
) -> np.ndarray:
    """The posterior Cramér-Rao bound of the position (Tichavsky, Muravchik and Nehorai 1998)
    when the velocity error is white (``q_x``) plus a constant ``c`` plus a first-order
    Gauss-Markov ``g`` (``gm_std_mps``, ``gm_tau_s``): the bias the estimator sees is
    ``a = c + g(t)``, no longer constant, and the bound of :func:`crlb` (``a`` constant) is
    out of reach. The state is ``[x, c, g]`` (3n), linear and Gaussian but for the bearings,
    so the recursion is the information filter along the truth:

    ``J_k = (F J_{k-1}^-1 F^T + Q)^-1 + H_k^T H_k / sigma^2``, ``H_k = [E_k^T / r_k, 0, 0]``

    with ``F``, ``Q`` of :func:`gauss_markov_step` per axis. The prior is ``prior_info``
    (negligible) on ``x`` and ``c`` and the stationary ``1 / gm_std^2`` on ``g`` (its law is
    known: a Bayesian bound). The prediction is ``(I + A Q)^-1 A`` with
    ``A = F^-T J F^-1`` (``A^-1 + Q = A^-1 (I + A Q)``): no inverse of ``J`` or ``Q``.
    """
    if not sigma_rad > 0.0:
        raise ValueError("the bound needs a bearing noise > 0")
    if not (gm_std_mps > 0.0 and gm_tau_s > 0.0):
        raise ValueError("the Gauss-Markov part needs a std > 0 and a time constant > 0")
    n = x.shape[1]
    d = 3 * n
    info = _bearing_info(x, sigma_rad)
    j = np.eye(d) * prior_info
    j[2 * n :, 2 * n :] = np.eye(n) / gm_std_mps**2
    out = np.empty(len(t))
    eye_d, eye_n = np.eye(d), np.eye(n)
    for k in range(len(t)):
        if k > 0:
            f1, q1 = gauss_markov_step(float(t[k] - t[k - 1]), q_x, gm_std_mps, gm_tau_s)
            finv, q = np.kron(np.linalg.inv(f1), eye_n), np.kron(q1, eye_n)
            a = finv.T @ j @ finv
            j = np.linalg.solve(eye_d + a @ q, a)
            j = 0.5 * (j + j.T)
        j[:n, :n] += info[k]
        cov = np.linalg.inv(j)
        out[k] = math.sqrt(max(np.trace(cov[:n, :n]), 0.0))
    return out


@dataclass
class Recorder:
    """Accumulates the metrics of ``R`` runs step by step (so no (R, T, 2n, 2n) history is
    kept): the relative position error at every step (R, T) and sums over the steady window
    (the last ``STEADY_S`` s)."""

    t: np.ndarray
    x: np.ndarray
    a: np.ndarray
    runs: int
    rel: np.ndarray = field(init=False)
    sq_pos: np.ndarray = field(init=False)
    sq_bias: np.ndarray = field(init=False)
    range_rel: np.ndarray = field(init=False)
    nees: np.ndarray = field(init=False)
    steps: int = 0
    has_cov: bool = True
    final_x: np.ndarray | None = None
    final_a: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.rel = np.full((self.runs, len(self.t)), np.nan)
        self.sq_pos = np.zeros(self.runs)
        self.sq_bias = np.zeros(self.runs)
        self.range_rel = np.zeros(self.runs)
        self.nees = np.zeros(self.runs)
        self.t_steady = self.t[-1] - STEADY_S
        self.r = np.linalg.norm(self.x, axis=1)

    def record(self, k: int, xh: np.ndarray, ah: np.ndarray, p: np.ndarray | None) -> None:
        """The estimates at sample ``k``: ``xh``, ``ah`` (R, n), covariance ``p`` (R, 2n, 2n)
        or ``None``."""
        n = xh.shape[1]
        err = xh - self.x[k]
        e2 = np.sum(err * err, axis=1)
        self.rel[:, k] = np.sqrt(e2) / self.r[k]
        self.final_x, self.final_a = xh, ah
        if self.t[k] < self.t_steady - 1e-9:
            return
        self.steps += 1
        self.sq_pos += e2
        db = ah - self.a
        self.sq_bias += np.sum(db * db, axis=1)
        self.range_rel += (np.linalg.norm(xh, axis=1) - self.r[k]) / self.r[k]
        if p is None:
            self.has_cov = False
        if self.has_cov and p is not None:
            with np.errstate(all="ignore"):
                sol = np.linalg.solve(p[:, :n, :n], err[:, :, None])[:, :, 0]
            self.nees += np.sum(err * sol, axis=1) / n


def time_to_stay_below(t: np.ndarray, rel: np.ndarray, level: float = CONVERGED_REL) -> np.ndarray:
    """Per run, the first time after which ``rel`` (R, T) stays below ``level`` to the end
    (``t[0]`` if always below, ``inf`` if the last sample is not below; NaN counts as above)."""
    above = ~(rel < level)
    last_above = np.where(
        above.any(axis=1), rel.shape[1] - 1 - np.argmax(above[:, ::-1], axis=1), -1
    )
    idx = last_above + 1
    out = np.full(rel.shape[0], np.inf)
    ok = idx < rel.shape[1]
    out[ok] = t[idx[ok]]
    return out


def summarise(rec: Recorder, bound: np.ndarray | None) -> dict[str, float]:
    """The metrics of one (case, estimator) from its recorder and the bound (T,) or None.

    Steady-state RMS values are over the runs whose estimates stayed finite (the others
    count as diverged); ``rms_converged`` only over the runs that did not diverge."""
    finite = np.isfinite(rec.sq_pos) & np.isfinite(rec.sq_bias) & np.isfinite(rec.range_rel)
    final = rec.rel[:, -1]
    diverged = ~finite | ~(final <= DIVERGED_REL)
    steps = max(rec.steps, 1)
    f = finite
    nf = max(int(f.sum()), 1)
    rms = math.sqrt(float(np.sum(rec.sq_pos[f])) / (nf * steps)) if f.any() else math.nan
    ok = ~diverged
    rms_ok = math.sqrt(float(np.mean(rec.sq_pos[ok])) / steps) if ok.any() else math.nan
    brms = math.sqrt(float(np.sum(rec.sq_bias[f])) / (nf * steps)) if f.any() else math.nan
    range_pct = 100.0 * rec.range_rel[f] / steps
    t10 = time_to_stay_below(rec.t, rec.rel)
    steady = rec.t >= rec.t_steady - 1e-9
    cr = math.sqrt(float(np.mean(bound[steady] ** 2))) if bound is not None else math.nan
    nees = math.nan
    if rec.has_cov and f.any():
        nees = float(np.mean(rec.nees[f])) / steps
    return {
        "runs": float(rec.runs),
        "t10_med": float(np.median(t10)),
        "t10_p90": float(np.quantile(t10, 0.9, method="higher")),
        "rms": rms,
        "rms_converged": rms_ok,
        "bias_rms": brms,
        "range_pct": float(np.mean(range_pct)) if f.any() else math.nan,
        "range_pct_se": float(np.std(range_pct, ddof=1) / math.sqrt(len(range_pct)))
        if len(range_pct) > 1
        else math.nan,
        "crlb": cr,
        "ratio": rms / cr if bound is not None else math.nan,
        "diverged": float(np.mean(diverged)),
        "nees": nees,
    }
