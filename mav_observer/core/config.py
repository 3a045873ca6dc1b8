"""The settings of one observer (:class:`ObserverConfig`), of the filter bank
(:class:`BankParams`), and the constants they derive from.

Pure: validation and derived settings only (no numba: reading the settings does not load
the compiled estimator).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from mav_observer.core.samples import MIN_DIM
from mav_observer.errors import ConfigError

#: The estimators ``ObserverConfig.estimator`` may name, the default first: the filter bank
#: (``docs/estimator.md``) and the paper's observer (``docs/observer.md``).
ESTIMATORS = ("riccati", "paper")


def estimator_names() -> tuple[str, ...]:
    """The estimators ``ObserverConfig.estimator`` may name, the default first."""
    return ESTIMATORS


MODES = ("biased", "bias_free")
#: Range guess (m) of the riccati estimator when ``initial_range_m`` is not set; its bank spans
#: ``range_span`` times either way.
DEFAULT_RANGE_GUESS_M = 20.0
INTERPOLATIONS = ("linear", "hold")


#: ``bearing_noise_deg = "auto"``: learn the noise online (the default).
AUTO = "auto"
#: The prior of a learnt bearing noise (deg, 1 sigma per direction). Too small a prior
#: costs more than too large a one (the first seconds' bearings, over-weighted, bias the
#: filters for good; docs/estimator.md, "The noise, learnt online").
BEARING_NOISE_PRIOR_DEG = 1.0
#: The least bearing noise learnt (deg): a bearing in NED carries the autopilot's attitude
#: error, rarely below 0.1 deg, whatever the sensor's own jitter. A servo mount's quantised,
#: slowly varying pointing error learnt from its tiny sample-to-sample jitter would make the
#: filter over-confident (docs/estimator.md, "The noise, learnt online").
BEARING_NOISE_FLOOR_DEG = 0.1
#: The prior of a learnt velocity noise (m/s per axis; :mod:`mav_observer.core.kernels.learners`).
VELOCITY_NOISE_PRIOR_MPS = 0.05
#: The largest bearing latency (s) told or learnt (:mod:`mav_observer.core.kernels.learners`).
MAX_BEARING_LATENCY_S = 0.5
#: The Huber threshold of a bearing: the 99.9 % quantile of the NIS (chi-square with
#: ``n - 1`` degrees of freedom), by dimension of the tangent space.
_CHI2_999 = {1: 10.828, 2: 13.816, 3: 16.266, 4: 18.467}


def outlier_nis(dof: int) -> float:
    """The NIS above which a bearing is down-weighted: the 99.9 % chi-square quantile with
    ``dof`` degrees of freedom (Wilson-Hilferty beyond 4)."""
    if dof in _CHI2_999:
        return _CHI2_999[dof]
    z = 3.090232  # the 99.9 % normal quantile
    c = 2.0 / (9.0 * dof)
    return dof * (1.0 - c + z * math.sqrt(c)) ** 3


def _positive(name: str, value: object, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ConfigError(f"{name} must be a number, got {value!r}")
    f = float(value)
    if not math.isfinite(f) or f < 0.0 or (f == 0.0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{name} must be a finite number {bound}, got {value!r}")
    return f


@dataclass(frozen=True)
class ObserverConfig:
    """Settings of one observer. Defaults suit a drone looking at a target tens of metres
    away with bearings at 5-50 Hz; ``docs/observer.md`` explains each.

    * ``n``: dimension (>= 2).
    * ``estimator``: ``"riccati"`` (default: near the Cramer-Rao bound, with an honest
      covariance; ``docs/accuracy.md``) or ``"paper"`` (the paper's observer, exact).
    * ``bearing_noise_deg``, ``velocity_noise_mps``, ``bias_walk_mps_per_sqrt_s``
      (riccati): standard deviation of the bearing noise per direction, of each velocity
      component, and the random walk of ``a`` (its standard deviation grows by this per
      square root of a second; 0 for a constant ``a``). Each ``"auto"`` or a number:
      ``"auto"`` (the default of all three) learns it online, a number is used as told
      (the bias walk learnt from 0 once the bearing latency has settled:
      ``docs/tuning.md``).
    * ``bearing_latency_s`` (riccati): how long (s) the bearings trail the line of sight
      (a gimbal's tracking lag, a timestamp taken late); ``"auto"`` (default) learns it
      online (:mod:`mav_observer.core.kernels.learners`), a number within +-0.5 s is used
      as told (0: none).
    * ``hypotheses``, ``range_span`` (riccati): the filter bank's initial ranges, spread
      ``range_span`` times either way around the range guess (``initial_range_m``, else
      :data:`DEFAULT_RANGE_GUESS_M`).
    * ``mode``: ``"biased"`` (the paper's Section 3 theorem: estimates ``x`` and ``a``) or
      ``"bias_free"`` (Lemma 3.1: ``a = 0`` assumed, ``xhat = xh1``).
    * ``k_per_s``, ``k_star_per_s`` (paper): the gains k and k* (1/s). The paper used 0.5 and 5 on a
      3 m scene; at drone scale those converge slowly or not at all, so 0.2 and 0.2 is the
      default (``docs/tuning.md``, "The paper's observer: gains").
    * ``interpolation``: ``"linear"`` or ``"hold"`` (see the module docstring).
    * ``max_bearing_age_s``, ``max_velocity_age_s``: beyond these a held sample is stale.
    * ``max_velocity_wait_s``: how long bearings wait for the velocity after them before the
      estimate moves on with the velocity held (its covariance growing with the gap): across a
      telemetry gap shorter than this the positions after the gap give its displacement.
    * ``window_s``, ``window_buckets``, ``excitation_min``, ``converged_tol``: the monitor
      (:mod:`mav_observer.core.kernels.monitor`).
    * ``xh1_0_m``, ``m_0_s``, ``zs_0_mps``: the initial state (defaults: zeros, identity,
      zeros, the paper's). ``m_0_s`` must be symmetric positive definite.
    * ``initial_range_m``: if set, the state is instead initialised at the first bearing
      ``y0`` as ``xhat = initial_range_m * y0``, ``ahat = 0``, ``M = m_0_s``.
    * ``static_hold``, ``hold_speed_mps``, ``hold_innovation_deg``: the static-geometry
      hold. While the estimated relative velocity ``|v + ahat|`` is at most
      ``hold_speed_mps`` and the bearing is within ``hold_innovation_deg`` of the estimate's
      direction, the observer holds its state instead of integrating (see the module
      docstring). Off in :meth:`paper`, which is the paper's observer unchanged.
    * ``max_buffer``: most samples of one stream kept waiting for the other.
    """

    n: int = 3
    estimator: str = "riccati"
    mode: str = "biased"
    bearing_noise_deg: float | str = "auto"
    velocity_noise_mps: float | str = "auto"
    bias_walk_mps_per_sqrt_s: float | str = "auto"
    bearing_latency_s: float | str = "auto"
    robust: bool = True
    hypotheses: int = 7
    range_span: float = 16.0
    k_per_s: float = 0.2
    k_star_per_s: float = 0.2
    interpolation: str = "linear"
    max_bearing_age_s: float = 2.0
    max_velocity_age_s: float = 2.0
    max_velocity_wait_s: float = 30.0
    window_s: float = 20.0
    window_buckets: int = 20
    excitation_min: float = 0.01
    converged_tol: float = 0.02
    xh1_0_m: tuple[float, ...] | None = None
    m_0_s: tuple[tuple[float, ...], ...] | None = None
    zs_0_mps: tuple[float, ...] | None = None
    initial_range_m: float | None = None
    static_hold: bool = True
    hold_speed_mps: float = 0.05
    hold_innovation_deg: float = 3.0
    max_buffer: int = 256

    def __post_init__(self) -> None:
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < MIN_DIM:
            raise ConfigError(f"n must be an integer >= {MIN_DIM}, got {self.n!r}")
        names = estimator_names()
        if self.estimator not in names:
            raise ConfigError(f"estimator must be one of {names}, got {self.estimator!r}")
        for name in ("bearing_noise_deg", "velocity_noise_mps", "bias_walk_mps_per_sqrt_s"):
            val = getattr(self, name)
            if isinstance(val, str) and val != AUTO:
                raise ConfigError(f'{name} must be "auto" or a number, got {val!r}')
        if self.bearing_noise_deg != AUTO:
            object.__setattr__(
                self, "bearing_noise_deg", _positive("bearing_noise_deg", self.bearing_noise_deg)
            )
        if not isinstance(self.robust, bool):
            raise ConfigError(f"robust must be true or false, got {self.robust!r}")
        for name in ("velocity_noise_mps", "bias_walk_mps_per_sqrt_s"):
            if getattr(self, name) == AUTO:
                continue
            object.__setattr__(self, name, _positive(name, getattr(self, name), allow_zero=True))
        lat = self.bearing_latency_s
        if isinstance(lat, str) and lat != AUTO:
            raise ConfigError(f'bearing_latency_s must be "auto" or a number, got {lat!r}')
        if lat != AUTO:
            if isinstance(lat, bool) or not isinstance(lat, (int, float)):
                raise ConfigError(f'bearing_latency_s must be "auto" or a number, got {lat!r}')
            if not (math.isfinite(lat) and abs(lat) <= MAX_BEARING_LATENCY_S):
                raise ConfigError(
                    f"bearing_latency_s must be within +-{MAX_BEARING_LATENCY_S} s, got {lat!r}"
                )
            object.__setattr__(self, "bearing_latency_s", float(lat))
        h = self.hypotheses
        if isinstance(h, bool) or not isinstance(h, int) or not 1 <= h <= 31:
            raise ConfigError(f"hypotheses must be an integer in [1, 31], got {h!r}")
        span = _positive("range_span", self.range_span)
        if span < 1.0:
            raise ConfigError(f"range_span must be >= 1, got {self.range_span!r}")
        object.__setattr__(self, "range_span", span)
        if self.mode not in MODES:
            raise ConfigError(f"mode must be one of {MODES}, got {self.mode!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise ConfigError(
                f"interpolation must be one of {INTERPOLATIONS}, got {self.interpolation!r}"
            )
        for name in ("k_per_s", "k_star_per_s", "max_bearing_age_s", "max_velocity_age_s",
                     "max_velocity_wait_s"):
            object.__setattr__(self, name, _positive(name, getattr(self, name)))
        object.__setattr__(self, "window_s", _positive("window_s", self.window_s))
        object.__setattr__(
            self,
            "excitation_min",
            _positive("excitation_min", self.excitation_min, allow_zero=True),
        )
        object.__setattr__(self, "converged_tol", _positive("converged_tol", self.converged_tol))
        if not isinstance(self.static_hold, bool):
            raise ConfigError(f"static_hold must be true or false, got {self.static_hold!r}")
        object.__setattr__(
            self,
            "hold_speed_mps",
            _positive("hold_speed_mps", self.hold_speed_mps, allow_zero=True),
        )
        hold_deg = _positive("hold_innovation_deg", self.hold_innovation_deg, allow_zero=True)
        if hold_deg > 90.0:
            raise ConfigError(f"hold_innovation_deg must be at most 90, got {hold_deg}")
        object.__setattr__(self, "hold_innovation_deg", hold_deg)
        for name in ("window_buckets", "max_buffer"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, int) or val < 2:
                raise ConfigError(f"{name} must be an integer >= 2, got {val!r}")
        if self.initial_range_m is not None:
            object.__setattr__(
                self, "initial_range_m", _positive("initial_range_m", self.initial_range_m)
            )
        n = self.n
        for name in ("xh1_0_m", "zs_0_mps"):
            val = getattr(self, name)
            if val is not None:
                arr = self._array(name, val, (n,))
                object.__setattr__(self, name, tuple(float(x) for x in arr))
        if self.m_0_s is not None:
            m = self._array("m_0_s", self.m_0_s, (n, n))
            if not np.allclose(m, m.T, rtol=1e-12, atol=1e-12):
                raise ConfigError(f"m_0_s must be symmetric, got {m.tolist()}")
            eig = np.linalg.eigvalsh(m)
            if eig[0] <= 0.0:
                raise ConfigError(
                    f"m_0_s must be positive definite, got {m.tolist()} "
                    f"(smallest eigenvalue {eig[0]:.6g})"
                )
            object.__setattr__(self, "m_0_s", tuple(tuple(float(x) for x in row) for row in m))

    @staticmethod
    def _array(name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
        try:
            arr = np.array(value, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{name}={value!r} is not numeric") from exc
        if arr.shape != shape:
            raise ConfigError(f"{name} must have shape {shape}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"{name}={arr.tolist()} contains a non-finite value")
        return arr

    @classmethod
    def paper(cls, **overrides: Any) -> ObserverConfig:
        """The paper's observer and Section 4 settings: k = 0.5, k* = 5, xh1 = 0, M = I,
        zs = 0, no static hold (the continuous equations, unchanged)."""
        return cls(
            **{
                "estimator": "paper",
                "k_per_s": 0.5,
                "k_star_per_s": 5.0,
                "static_hold": False,
                **overrides,
            }
        )

    def bank_params(self, velocity_noise_mps: float | None = None) -> BankParams:
        """The filter bank's settings; ``velocity_noise_mps`` sets its ``q_x`` per second of
        velocity interval (default: the setting, or its prior for ``"auto"``; the observer
        passes the one in use at every step)."""
        if velocity_noise_mps is None:
            velocity_noise_mps = (
                VELOCITY_NOISE_PRIOR_MPS
                if self.velocity_noise_mps == AUTO
                else float(self.velocity_noise_mps)
            )
        learn = self.bearing_noise_deg == AUTO
        prior_deg = BEARING_NOISE_PRIOR_DEG if learn else float(self.bearing_noise_deg)
        walk = self.bias_walk_mps_per_sqrt_s
        return BankParams(
            sigma_rad=math.radians(prior_deg),
            learn_noise=learn,
            noise_min_rad=math.radians(BEARING_NOISE_FLOOR_DEG),
            outlier_nis=outlier_nis(self.n - 1) if self.robust else math.inf,
            q_x=velocity_noise_mps**2,
            q_a=0.0 if walk == AUTO else float(walk) ** 2,
            learn_walk=walk == AUTO and self.mode == "biased",
            hypotheses=self.hypotheses,
            span=self.range_span,
            bias_std_mps=0.0 if self.mode == "bias_free" else 5.0,
        )

    @property
    def range_guess_m(self) -> float:
        """The riccati estimator's initial range guess (m)."""
        return DEFAULT_RANGE_GUESS_M if self.initial_range_m is None else self.initial_range_m

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form (tuples become lists)."""
        d = asdict(self)
        for key in ("xh1_0_m", "zs_0_mps"):
            if d[key] is not None:
                d[key] = list(d[key])
        if d["m_0_s"] is not None:
            d["m_0_s"] = [list(r) for r in d["m_0_s"]]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ObserverConfig:
        """Build from a dictionary; an unknown key is an error naming it."""
        if not isinstance(d, dict):
            raise ConfigError(f"observer configuration must be a table, got {type(d).__name__}")
        known = {f.name for f in fields(cls)}
        for key in d:
            if key not in known:
                raise ConfigError(f"unknown observer setting {key!r}; known: {sorted(known)}")
        return cls(**d)

    # -- derived ------------------------------------------------------------------
    def initial_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The paper's ``(xh1, M, ahat)`` from the configured initial ``(xh1, M, zs)``; in
        bias-free mode ``ahat = 0`` (``zs`` is not used)."""
        n = self.n
        xh1 = np.zeros(n) if self.xh1_0_m is None else np.array(self.xh1_0_m)
        m = np.eye(n) if self.m_0_s is None else np.array(self.m_0_s)
        if self.mode == "bias_free":
            return xh1, m, np.zeros(n)
        zs = np.zeros(n) if self.zs_0_mps is None else np.array(self.zs_0_mps)
        return xh1, m, zs - np.linalg.solve(m, xh1)


@dataclass(frozen=True)
class BankParams:
    """Settings of the filter bank (``docs/estimator.md``, ``docs/tuning.md``); the
    observer makes them from its :class:`ObserverConfig` (:meth:`ObserverConfig.bank_params`),
    the Monte Carlo harness directly.

    * ``sigma_rad``: bearing noise per tangent direction (rad; the prior when learnt).
    * ``q_x`` (m^2/s), ``q_a`` (m^2/s^3): process noise intensities of ``x'`` (the
      velocity's white noise) and of ``a'`` (the bias's random walk when told).
    * ``hypotheses``, ``span``: the initial ranges ``r0 * span**u`` for ``hypotheses`` values
      of ``u`` evenly spaced in [-1, 1], each with a standard deviation of ``range_rel_std``
      times its range along the bearing; ``bias_std_mps`` the prior of each component of
      ``a``.
    * ``prune``: a hypothesis whose weight falls below it is dropped; ``prune_early`` in
      the first ``prune_early_s`` of a run until its first re-seeding (before the vehicle's
      motion has told the ranges apart the weights say little).
    * ``merge_maha``: a hypothesis within this squared Mahalanobis distance of the heaviest
      (under the sum of their covariances) is merged into it, moments matched.
    * ``nis_gate``, ``nis_window_s``: a run whose innovations, averaged over the window,
      exceed ``nis_gate`` times their expected value is re-seeded from its Riccati
      observer (a re-acquisition).
    * ``outlier_nis``: the robust threshold on a bearing's NIS (``inf``: off): beyond it the
      bearing is down-weighted, counts in the innovation average as the threshold and in
      the hypotheses' likelihood with a bounded loss.
    * ``learn_noise``: learn the bearing noise online (an inverse-gamma posterior forgetting
      over ``noise_memory_s``, the prior weighing ``noise_prior_dof`` tangent directions,
      kept within ``[noise_min_rad, noise_max_rad]``).
    * ``learn_walk``: learn the bias's random walk online by likelihood against two probe
      filters a ``walk_factor`` apart (levels from ``walk_min`` to ``walk_max``, the jump
      from 0 to ``walk_jump``), moving a level when a probe leads by ``walk_up_nats`` (up),
      ``walk_down_nats`` (down) or ``walk_leave_nats`` (leaving 0), over ``walk_memory_s``,
      ``walk_warmup_s`` after a seeding once the bank is down to one filter.
    """

    sigma_rad: float
    q_x: float = 0.0
    q_a: float = 0.0
    hypotheses: int = 7
    span: float = 16.0
    range_rel_std: float = 0.4
    bias_std_mps: float = 5.0
    prune: float = 1e-4
    prune_early: float = 1e-9
    prune_early_s: float = 20.0
    merge_maha: float = 1.0
    nis_gate: float = 3.0
    nis_window_s: float = 5.0
    outlier_nis: float = math.inf
    learn_noise: bool = False
    noise_memory_s: float = 60.0
    noise_prior_dof: float = 20.0
    noise_min_rad: float = 1e-5
    noise_max_rad: float = 0.5
    learn_walk: bool = False
    walk_factor: float = 4.0
    walk_min: float = 1e-6
    walk_jump: float = 2.5e-4
    walk_max: float = 1.0
    walk_up_nats: float = 6.0
    walk_leave_nats: float = 15.0
    walk_down_nats: float = 2.0
    walk_memory_s: float = 60.0
    walk_warmup_s: float = 10.0

    def to_array(self) -> np.ndarray:
        """The settings as the bank's kernels read them (``layout.P_*``, in field order)."""
        return np.array([float(getattr(self, f.name)) for f in fields(self)])
