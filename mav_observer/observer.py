"""Estimators of position and velocity bias from a single direction, in R^n.

:class:`BiasObserver` turns separately arriving, irregularly timed velocity and bearing
samples into estimates of the relative position ``x`` and the constant velocity term ``a``
(see :mod:`mav_observer.samples` for the conventions). Two estimators share its sample
handling, monitor and persistence (``ObserverConfig.estimator``):

* ``riccati`` (default): a bank of extended Kalman filters supervised by a Riccati observer,
  with a covariance (:mod:`mav_observer.riccati`, ``docs/estimator.md``): predicted between
  sample times, updated at each bearing sample;
* ``paper``: the observer of Le Bras, Hamel, Mahony and Samson (2015), exact
  (:mod:`mav_observer.discrete`), integrated as described below.

Pure: no I/O, no clock; time is whatever the samples carry. The paper's maths runs on lists
of floats (see :mod:`mav_observer.discrete`), the riccati estimator's on numpy arrays.

How samples become inputs of the continuous equations
------------------------------------------------------
* Between two consecutive samples of a stream the input is **linearly interpolated**
  (a bearing is interpolated along the chord and re-normalised), as long as the two are at
  most the stream's maximum age apart; otherwise the earlier value is held.
  ``interpolation="hold"`` holds each sample from its time to the next instead (zero-order
  hold: simpler, markedly less accurate).
* After the latest sample of a stream its value is **held**: a bearing for at most
  ``max_bearing_age_s``, after which there is no correction term (the observer only
  predicts, ``xhat' = v + ahat``); a velocity indefinitely, the status saying ``stale`` once
  it is older than ``max_velocity_age_s``.
* The observer keeps a **committed state** at the latest time both streams cover (the data
  horizon), integrated with interpolated inputs. Estimates at later times (the time of a
  bearing whose velocity has not arrived yet, or :meth:`BiasObserver.predict`) are computed
  from it with held inputs and are never committed, so late-arriving samples still count.
* **Static-geometry hold** (``static_hold``, on by default, off in
  :meth:`ObserverConfig.paper`): when the observer's own estimate of the relative velocity
  ``v + ahat`` is below ``hold_speed_mps`` and the bearing agrees with the estimate's
  direction (within ``hold_innovation_deg``), the state is held instead of integrated.
  The bearing then only confirms the estimate: range and the bias along the line of sight
  are not observable, and integrating would turn any residual bias error into a range drift
  that grows without bound (and ``M`` with it). This is the observer's analogue of an
  inertial navigator's zero-velocity update; any motion or bearing change ends it at once.
* A stream that goes silent does not hold up the other: when the bearing is older than its
  maximum age, the horizon follows the velocity (and vice versa).

Each interval between breakpoints is integrated in ``discrete.substep_count`` sub-steps with
inputs frozen at the sub-step midpoints, closed-form for ``xh1`` and ``M``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from mav_observer import discrete, riccati
from mav_observer.errors import ConfigError, InvalidSampleError, StateError
from mav_observer.monitor import ExcitationWindow, MonitorThresholds, StatusMemory, next_status
from mav_observer.noise import NoiseStateError, VelocityNoise
from mav_observer.samples import (
    MIN_DIM,
    BearingSample,
    Estimate,
    NoiseLevels,
    Status,
    VelocitySample,
    _check_time,
    _frozen_vector,
)

MODES = ("biased", "bias_free")
#: ``riccati``: the default, a bank of extended Kalman filters on ``[x, a]`` supervised by a
#: Riccati observer (:mod:`mav_observer.riccati`); ``paper``: the paper's observer, exact.
ESTIMATORS = ("riccati", "paper")
#: Range guess (m) of the riccati estimator when ``initial_range_m`` is not set; its bank spans
#: ``range_span`` times either way.
DEFAULT_RANGE_GUESS_M = 20.0
#: Sample times closer than this to an interval end are not made breakpoints, and a
#: provisional estimate this close to the committed state is a pure prediction (s). With
#: linear interpolation the inputs are evaluated at each sub-step's midpoint from the samples
#: around it, so a breakpoint only matters for a kink of the interpolant: merging a sliver
#: of a few ms costs far less than the sub-step it would take (two streams a few ms apart is
#: the usual MAVLink case).
MIN_INTERVAL_S = 0.01
#: The excitation level describes the geometry over the monitor's window (seconds): it is
#: evaluated again at most this often (s of observer time), not for every estimate.
DIAGNOSTICS_PERIOD_S = 0.5
INTERPOLATIONS = ("linear", "hold")
#: The error (m/s, as a white velocity noise) of a velocity interval whose mean comes from
#: the vehicle's positions (``update_velocity_values``'s ``interval_mean_mps``): GNSS-aided
#: positions do not accumulate the velocity's noise (measured on the shared real logs with
#: injected bearings: a velocity noise of 0.05 m/s there cost 2x to 10x in error).
CHORD_NOISE_MPS = 0.01
#: Version of the dictionary written by :meth:`BiasObserver.to_dict`.
STATE_SCHEMA = 2


#: ``bearing_noise_deg = "auto"``: learn the noise online (the default).
AUTO = "auto"
#: The prior of a learnt bearing noise (deg, 1 sigma per direction). Too small a prior
#: costs more than too large a one (the first seconds' bearings, over-weighted, bias the
#: filters for good). Measured on the orbit, 32 runs from range guesses up to 10x off, RMS
#: over the last 100 s against the noise told: at 2 deg a 0.5 deg prior 1.45x, 1 deg 1.05x,
#: 2 deg 1.00x; at 0.2 deg 1.00x, 1.00x, 1.03x.
BEARING_NOISE_PRIOR_DEG = 1.0
#: The least bearing noise learnt (deg): a bearing in NED carries the autopilot's attitude
#: error, rarely below 0.1 deg, whatever the sensor's own jitter. A servo mount's quantised,
#: slowly varying pointing error learnt from its tiny sample-to-sample jitter (0.02 deg on
#: the shared SITL log) made the filter over-confident; with the floor the median error over
#: that log's last third is 1.07 m instead of 1.46 m.
BEARING_NOISE_FLOOR_DEG = 0.1
#: The prior of a learnt velocity noise (m/s per axis; :mod:`mav_observer.noise`).
VELOCITY_NOISE_PRIOR_MPS = 0.05
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
      square root of a second; 0 for a constant ``a``).
    * ``hypotheses``, ``range_span`` (riccati): the filter bank's initial ranges, spread
      ``range_span`` times either way around the range guess (``initial_range_m``, else
      :data:`DEFAULT_RANGE_GUESS_M`).
    * ``mode``: ``"biased"`` (the paper's Section 3 theorem: estimates ``x`` and ``a``) or
      ``"bias_free"`` (Lemma 3.1: ``a = 0`` assumed, ``xhat = xh1``).
    * ``k_per_s``, ``k_star_per_s`` (paper): the gains k and k* (1/s). The paper used 0.5 and 5 on a
      3 m scene; at drone scale those converge slowly or not at all, 0.2 and 0.2 is the
      measured default.
    * ``interpolation``: ``"linear"`` or ``"hold"`` (see the module docstring).
    * ``max_bearing_age_s``, ``max_velocity_age_s``: beyond these a held sample is stale.
    * ``window_s``, ``window_buckets``, ``excitation_min``, ``converged_tol``: the monitor
      (:mod:`mav_observer.monitor`).
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
    bias_walk_mps_per_sqrt_s: float | str = AUTO
    robust: bool = True
    hypotheses: int = 7
    range_span: float = 16.0
    k_per_s: float = 0.2
    k_star_per_s: float = 0.2
    interpolation: str = "linear"
    max_bearing_age_s: float = 2.0
    max_velocity_age_s: float = 2.0
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
        if self.estimator not in ESTIMATORS:
            raise ConfigError(f"estimator must be one of {ESTIMATORS}, got {self.estimator!r}")
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
        for name in ("k_per_s", "k_star_per_s", "max_bearing_age_s", "max_velocity_age_s"):
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

    def bank_params(
        self, velocity_dt_s: float, velocity_noise_mps: float | None = None
    ) -> riccati.BankParams:
        """The riccati estimator's settings; ``velocity_dt_s`` is the velocity's sample
        interval (s), which turns its noise into a process noise on ``x``;
        ``velocity_noise_mps`` the velocity noise in use (when learnt; default: the
        setting, or its prior for ``"auto"``)."""
        if velocity_noise_mps is None:
            velocity_noise_mps = (
                VELOCITY_NOISE_PRIOR_MPS
                if self.velocity_noise_mps == AUTO
                else float(self.velocity_noise_mps)
            )
        learn = self.bearing_noise_deg == AUTO
        prior_deg = BEARING_NOISE_PRIOR_DEG if learn else float(self.bearing_noise_deg)
        walk = self.bias_walk_mps_per_sqrt_s
        return riccati.BankParams(
            sigma_rad=math.radians(prior_deg),
            learn_noise=learn,
            noise_min_rad=math.radians(BEARING_NOISE_FLOOR_DEG),
            outlier_nis=outlier_nis(self.n - 1) if self.robust else math.inf,
            q_x=velocity_noise_mps**2 * velocity_dt_s,
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
    def initial_state(self) -> tuple[list[float], list[float], list[float]]:
        """``(xh1, M, ahat)`` from the configured initial ``(xh1, M, zs)`` (``M`` flat,
        row-major); in bias-free mode ``ahat = 0`` (``zs`` is not used)."""
        n = self.n
        xh1 = [0.0] * n if self.xh1_0_m is None else list(self.xh1_0_m)
        m = discrete.identity(n) if self.m_0_s is None else [v for row in self.m_0_s for v in row]
        if self.mode == "bias_free":
            return xh1, m, [0.0] * n
        zs = [0.0] * n if self.zs_0_mps is None else list(self.zs_0_mps)
        return xh1, m, discrete.ahat_from_paper_state(xh1, m, zs)

    def thresholds(self) -> MonitorThresholds:
        return MonitorThresholds(
            max_bearing_age_s=self.max_bearing_age_s,
            max_velocity_age_s=self.max_velocity_age_s,
            window_s=self.window_s,
            window_full_s=self.window_s * (self.window_buckets - 1) / self.window_buckets,
            excitation_min=self.excitation_min,
            converged_tol=self.converged_tol,
        )


_Sample = tuple[float, list[float]]


def _add_outer(acc: list[float], y: list[float], w: float) -> None:
    """``acc += w y y^T`` in place (flat, row-major)."""
    if len(y) == 3:
        y0, y1, y2 = y[0] * w, y[1] * w, y[2] * w
        acc[0] += y0 * y[0]
        acc[1] += y0 * y[1]
        acc[2] += y0 * y[2]
        acc[3] += y1 * y[0]
        acc[4] += y1 * y[1]
        acc[5] += y1 * y[2]
        acc[6] += y2 * y[0]
        acc[7] += y2 * y[1]
        acc[8] += y2 * y[2]
        return
    k = 0
    for p in y:
        for q in y:
            acc[k] += w * p * q
            k += 1


#: ("interval", t0_s, t1_s, integral of y y^T or None, valid_s) or
#: ("correction", t_s, dx_m, da_mps)
_Record = tuple[Any, ...]


@dataclass
class _State:
    """Lists of floats; ``m`` flat row-major."""

    xh1: list[float]
    m: list[float]
    ahat: list[float]


class BiasObserver:
    """One observer: feed it :class:`VelocitySample` and :class:`BearingSample`, read
    :class:`Estimate`. A rejected sample raises :class:`InvalidSampleError` and leaves the
    observer exactly as it was."""

    def __init__(self, config: ObserverConfig | None = None) -> None:
        self.config = config if config is not None else ObserverConfig()
        cfg = self.config
        self._thresholds = cfg.thresholds()
        # per-step constants
        self._hold_speed2 = cfg.hold_speed_mps**2
        self._hold_cos = math.cos(math.radians(cfg.hold_innovation_deg))
        self._biased = cfg.mode == "biased"
        self._kalman = cfg.estimator == "riccati"
        self.reset()

    def reset(self) -> None:
        """Forget everything: back to the configured initial state, not started."""
        cfg = self.config
        xh1, m, ahat = cfg.initial_state()
        self._state = _State(xh1, m, ahat)
        self._t_c: float | None = None
        self._bearings: list[_Sample] = []
        self._velocities: list[_Sample] = []
        self._window = ExcitationWindow(cfg.n, cfg.window_s, cfg.window_buckets)
        self._memory = StatusMemory()
        self._estimate: Estimate | None = None
        self._diag: tuple[float, float] | None = None  # t_s, excitation
        self._cond: tuple[float | None, float] | None = None  # committed t_s, cond(M)
        self._xhat_c: list[float] | None = None  # xhat of the committed state
        # riccati: the filter bank, its estimate (x, a, P) at the committed time, the time of
        # the latest bearing applied, and the velocity's sample interval (s)
        self._bank: riccati.Bank | None = None
        self._kf_out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._kf_tb: float | None = None
        self._vel_dt = 0.05
        #: velocity sample time -> the mean velocity (m/s) over the interval that ends at it
        #: (see :meth:`update_velocity_values`)
        self._vel_mean: dict[float, list[float]] = {}
        self._counts = {"velocity": 0, "bearing": 0}
        #: the velocity's white noise, learnt from its samples (``velocity_noise_mps = "auto"``)
        self._vnoise = (
            VelocityNoise(prior_mps=VELOCITY_NOISE_PRIOR_MPS)
            if cfg.velocity_noise_mps == AUTO and self._kalman
            else None
        )

    # -- public properties ----------------------------------------------------------
    @property
    def started(self) -> bool:
        """True once both streams have delivered and integration has begun."""
        return self._t_c is not None

    @property
    def committed_t_s(self) -> float | None:
        """Time (s) of the committed state, the data horizon (``None`` before start)."""
        return self._t_c

    @property
    def estimate(self) -> Estimate | None:
        """The latest estimate produced (by a bearing update or :meth:`predict`)."""
        return self._estimate

    @property
    def a_mps(self) -> list[float]:
        """``ahat`` of the committed state (m/s), a copy."""
        if self._kalman:
            return self._kf_state()[1].tolist()
        return list(self._state.ahat)

    @property
    def covariance(self) -> np.ndarray | None:
        """Covariance of ``[xhat, ahat]`` at the committed time ((2n, 2n), m and m/s) of the
        riccati estimator; ``None`` for the paper's observer, which has none."""
        if not self._kalman:
            return None
        return self._kf_state()[2].copy()

    @property
    def status(self) -> Status:
        """The status of the latest estimate (``stale`` before any)."""
        return self._memory.status

    @property
    def counts(self) -> dict[str, int]:
        """Samples accepted per stream."""
        return dict(self._counts)

    @property
    def reacquisitions(self) -> int:
        """Times the riccati estimator started again from its Riccati observer because its
        bearings stopped agreeing with it (0 for the paper's observer)."""
        return 0 if self._bank is None else int(self._bank.reseeds[0])

    def noise(self) -> NoiseLevels | None:
        """The noise levels in use (learnt or told) and the robust update's counts, for the
        riccati estimator; ``None`` for the paper's observer."""
        if not self._kalman:
            return None
        cfg = self.config
        prm = self._bank_params()
        bank = self._bank
        if bank is None:
            var, bearings, outliers, reseeds = prm.sigma_rad**2, 0, 0, 0
        else:
            var = float(bank.noise_var_rad2(prm)[0])
            bearings, outliers = int(bank.bearings[0]), int(bank.outliers[0])
            reseeds = int(bank.reseeds[0])
        return NoiseLevels(
            bearing_noise_deg=math.degrees(math.sqrt(var)),
            bearing_noise_learnt=prm.learn_noise,
            velocity_noise_mps=self._velocity_noise_mps(),
            velocity_noise_learnt=cfg.velocity_noise_mps == AUTO,
            bearings=bearings,
            outliers=outliers,
            reacquisitions=reseeds,
        )

    def _velocity_noise_mps(self) -> float:
        """The white velocity noise in use (m/s per axis): learnt or told."""
        if self._vnoise is not None:
            return self._vnoise.sigma_mps
        return float(self.config.velocity_noise_mps)

    def _bank_params(self) -> riccati.BankParams:
        return self.config.bank_params(self._vel_dt, self._velocity_noise_mps())

    def _paper_only(self, name: str) -> None:
        if self._kalman:
            raise StateError(f"{name} belongs to the paper's observer, this one is riccati")

    @property
    def zs_mps(self) -> np.ndarray:
        """The paper's dual state ``zs`` of the committed state (m/s)."""
        self._paper_only("zs_mps")
        s = self._state
        return np.array(discrete.zs_from_state(s.ahat, s.xh1, s.m))

    @property
    def xh1_m(self) -> np.ndarray:
        """The first filter ``xh1`` of the committed state (m)."""
        self._paper_only("xh1_m")
        return np.array(self._state.xh1)

    @property
    def m_s(self) -> np.ndarray:
        """The matrix ``M`` of the committed state (s)."""
        self._paper_only("m_s")
        n = self.config.n
        return np.array(self._state.m).reshape(n, n)

    # -- input ----------------------------------------------------------------------
    def _check_dim(self, dim: int, name: str, t_s: float) -> None:
        if dim != self.config.n:
            raise InvalidSampleError(
                f"{name} at t_s={t_s} has dimension {dim}, the observer has n={self.config.n}"
            )

    def _accept(
        self, buf: list[_Sample], kind: str, t_s: float, vec: list[float], *, refuse_late: bool
    ) -> None:
        """Append a validated sample to its stream and advance; on failure, undo.
        ``refuse_late``: refuse a sample older than the committed state (bearings)."""
        if buf and t_s < buf[-1][0]:
            raise InvalidSampleError(
                f"{kind} t_s={t_s} is before the previous {kind} sample t_s={buf[-1][0]}: "
                "time went backwards"
            )
        if refuse_late and self._t_c is not None and t_s < self._t_c:
            raise InvalidSampleError(
                f"{kind} t_s={t_s} is older than the observer's committed time "
                f"t_s={self._t_c} (it arrived more than max_{kind}_age_s late)"
            )
        if kind == "velocity" and buf and t_s > buf[-1][0]:
            self._vel_dt = min(1.0, t_s - buf[-1][0])
        buf.append((t_s, vec))
        try:
            self._advance(lazy=not refuse_late)
        except Exception:
            buf.pop()
            raise
        self._counts[kind] += 1
        if kind == "velocity" and self._vnoise is not None:
            self._vnoise.update(t_s, vec)

    def update_velocity(self, sample: VelocitySample) -> None:
        """Accept a velocity sample (the paper's ``v``; for a vehicle minus its velocity)."""
        if not isinstance(sample, VelocitySample):
            raise InvalidSampleError(f"expected a VelocitySample, got {type(sample).__name__}")
        self._check_dim(sample.dim, "velocity v_mps", sample.t_s)
        self._accept(
            self._velocities, "velocity", sample.t_s, sample.v_mps.tolist(), refuse_late=False
        )

    def update_bearing(self, sample: BearingSample) -> Estimate:
        """Accept a bearing sample and return the estimate at its time."""
        if not isinstance(sample, BearingSample):
            raise InvalidSampleError(f"expected a BearingSample, got {type(sample).__name__}")
        self._check_dim(sample.dim, "bearing y", sample.t_s)
        self._accept(self._bearings, "bearing", sample.t_s, sample.y.tolist(), refuse_late=True)
        return self._estimate_at(sample.t_s)

    def update_velocity_values(
        self,
        t_s: float,
        v_mps: list[float],
        interval_mean_mps: list[float] | None = None,
    ) -> None:
        """:meth:`update_velocity` for a caller that already checked the sample (finite
        floats, the observer's dimension): no sample object is built.

        ``interval_mean_mps``: the mean of ``v`` (m/s, the paper's sign) over the interval
        from the previous velocity sample to this one, when it is known better than the
        average of the two samples (for a vehicle, from the change of its position: see
        ``docs/frames.md``, "Sparse velocity"). The velocity on that interval is then the
        linear interpolation of the two samples shifted by a constant so that its mean is
        that (the samples' shape, the positions' displacement: on a smooth turn the shape
        is far closer than a straight line, and the displacement is exact)."""
        buf = self._velocities
        self._accept(buf, "velocity", t_s, v_mps, refuse_late=False)
        if interval_mean_mps is not None and len(buf) >= 2 and buf[-2][0] < t_s:
            self._vel_mean[t_s] = list(interval_mean_mps)

    def update_bearing_values(self, t_s: float, y: list[float]) -> Estimate:
        """:meth:`update_bearing` for a caller that already checked the sample (finite
        floats, unit length, the observer's dimension)."""
        self._accept(self._bearings, "bearing", t_s, y, refuse_late=True)
        return self._estimate_at(t_s)

    def predict(self, t_s: float) -> Estimate:
        """Estimate at ``t_s`` from the data so far.

        Integrates what the samples received determine (up to the data horizon, as any later
        update would), then predicts the rest (``xhat' = v + ahat``, not committed). Once the
        latest bearing is older than ``max_bearing_age_s`` the status is ``stale``.
        """
        t = float(t_s)
        if not math.isfinite(t):
            raise InvalidSampleError(f"t_s={t_s!r} is not finite")
        if self._t_c is not None and t < self._t_c:
            raise InvalidSampleError(
                f"predict t_s={t} is before the observer's committed time t_s={self._t_c}"
            )
        self._advance()
        if self._t_c is not None and t < self._t_c:  # the data already reaches past t
            raise InvalidSampleError(
                f"predict t_s={t} is before the observer's committed time t_s={self._t_c}"
            )
        return self._estimate_at(t)

    # -- integration ----------------------------------------------------------------
    def _start_if_ready(self) -> None:
        if self._t_c is not None:
            return
        # before the start only the latest sample of each stream matters
        del self._bearings[:-1]
        del self._velocities[:-1]
        if not self._bearings or not self._velocities:
            return
        t0 = max(self._bearings[0][0], self._velocities[0][0])
        cfg = self.config
        if self._kalman:
            y0 = np.array([self._bearings[-1][1]])
            self._bank = riccati.bank_start(y0, np.array([cfg.range_guess_m]), self._bank_params())
            self._kf_out = None
            self._kf_tb = self._bearings[-1][0]
        elif cfg.initial_range_m is not None:
            y0 = self._bearings[-1][1]
            _, m, _ = cfg.initial_state()
            # xhat = M ahat + xh1 with ahat = 0
            self._state = _State([cfg.initial_range_m * c for c in y0], m, [0.0] * cfg.n)
            self._xhat_c = None
        self._t_c = t0
        self._trim()

    def _trim(self) -> None:
        """Drop samples no longer needed: keep the latest one at or before the committed time
        (the interpolation anchor) and everything after it; of the velocities, the one before
        the anchor too (a prediction continues the latest interval's trend)."""
        t_c = self._t_c
        if t_c is None:
            return
        for buf, extra in ((self._bearings, 0), (self._velocities, 1)):
            keep_from = 0
            for i, (t, _) in enumerate(buf):
                if t <= t_c:
                    keep_from = i
                else:
                    break
            keep_from = max(0, keep_from - extra)
            if keep_from:
                del buf[:keep_from]
        if self._vel_mean and self._velocities:
            first = self._velocities[0][0]
            for t in [t for t in self._vel_mean if t <= first]:
                del self._vel_mean[t]

    def _horizon(self) -> float:
        cfg = self.config
        tb = self._bearings[-1][0]
        tv = self._velocities[-1][0]
        if tv > tb + cfg.max_bearing_age_s:
            horizon = tv  # bearing stale: no future bearing can correct this stretch
        elif tb > tv + cfg.max_velocity_age_s:
            horizon = tb  # velocity stale: hold it
        else:
            horizon = min(tb, tv)
        if len(self._bearings) > cfg.max_buffer or len(self._velocities) > cfg.max_buffer:
            horizon = max(tb, tv)
        return horizon

    def _advance(self, *, lazy: bool = False) -> None:
        """Integrate the committed state up to the data horizon. Computes first, then
        commits: if the maths raised, nothing would have changed. ``lazy`` (a velocity
        sample): leave it to the next bearing unless the bearing is stale or a buffer full."""
        self._start_if_ready()
        if self._t_c is None:
            return
        if lazy:
            cfg = self.config
            stale = self._velocities[-1][0] > self._bearings[-1][0] + cfg.max_bearing_age_s
            if not stale and len(self._velocities) <= cfg.max_buffer:
                return
        horizon = self._horizon()
        if horizon > self._t_c:
            records: list[_Record] = []
            if self._kalman:
                self._bank, self._kf_tb = self._integrate_kf(self._t_c, horizon, records)
                self._kf_out = None
            else:
                self._state = self._integrate(self._state, self._t_c, horizon, records)
            self._t_c = horizon
            for rec in records:
                if rec[0] == "interval":
                    self._window.add_interval(rec[1], rec[2], rec[3], rec[4])
                elif rec[0] == "correction":
                    self._window.add_correction(rec[1], rec[2], rec[3])
                else:
                    self._xhat_c = rec[1]
            self._trim()

    @staticmethod
    def _bracket(buf: list[_Sample], t: float) -> tuple[_Sample | None, _Sample | None]:
        """The latest sample at or before ``t`` and the first one after it."""
        p = None
        for sample in buf:
            if sample[0] <= t:
                p = sample
            else:
                return p, sample
        return p, None

    def _bearing_at(self, t: float) -> list[float] | None:
        """The bearing in force at ``t`` (unit vector), or ``None`` when there is no usable one:
        interpolated between the samples around ``t`` when at most ``max_bearing_age_s`` apart,
        else the earlier one held for at most ``max_bearing_age_s``."""
        cfg = self.config
        p, q = self._bracket(self._bearings, t)
        if p is None:
            return None
        if q is not None and cfg.interpolation == "linear" and q[0] - p[0] <= cfg.max_bearing_age_s:
            y = self._lerp(p, q, t)
            if len(y) == 3:
                inv = 1.0 / math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
                return [y[0] * inv, y[1] * inv, y[2] * inv]
            inv = 1.0 / math.sqrt(discrete.dot(y, y))
            return [c * inv for c in y]
        if t <= p[0] + cfg.max_bearing_age_s:
            return p[1]
        return None

    def _velocity_at(self, t: float) -> list[float]:
        """The velocity at ``t``: interpolated as bearings are, else the latest one held (the
        first one held backwards before it)."""
        cfg = self.config
        p, q = self._bracket(self._velocities, t)
        if p is None:
            return (q if q is not None else self._velocities[0])[1]
        if q is not None:
            mean = self._vel_mean.get(q[0]) if self._vel_mean else None
            if mean is not None:  # the interval's mean is known (from the positions): the
                # samples' shape, shifted so that its integral is the positions' change
                v = self._lerp(p, q, t)
                a, b = p[1], q[1]
                return [v[j] + mean[j] - 0.5 * (a[j] + b[j]) for j in range(len(v))]
            if cfg.interpolation == "linear" and q[0] - p[0] <= cfg.max_velocity_age_s:
                return self._lerp(p, q, t)
        return p[1]

    def _predicted_displacement(self, t0: float, t1: float) -> list[float]:
        """The integral of ``v`` from ``t0`` to ``t1`` for a prediction (m): the known velocity
        (linear between samples: its midpoint) up to the latest sample; past it, held, or for
        a sparse stream (the latest interval's mean known from the positions: velocity
        samples up to seconds apart while the vehicle turns) its latest trend continued for at
        most one interval. Holding a 1 Hz velocity on a figure-8 put the estimates published
        just before the next sample 12 cm off, 8 times the bound (``velocity_1hz``)."""
        n = self.config.n
        tv = self._velocities[-1][0]
        if t1 <= tv or not self._vel_mean or tv not in self._vel_mean:
            h = t1 - t0
            v = self._velocity_at(t0 + 0.5 * h)
            return [h * v[j] for j in range(n)]
        out = [0.0] * n
        if t0 < tv:  # the known stretch
            h = tv - t0
            v = self._velocity_at(t0 + 0.5 * h)
            out = [h * v[j] for j in range(n)]
        tp, vp = self._velocities[-2]
        vl = self._velocities[-1][1]
        iv = tv - tp
        mean = self._vel_mean[tv]
        # the model at the latest sample (the samples' shape shifted to the positions' mean),
        # and its slope
        v_end = [vl[j] + mean[j] - 0.5 * (vp[j] + vl[j]) for j in range(n)]
        slope = [(vl[j] - vp[j]) / iv for j in range(n)]

        def integral(s: float) -> list[float]:  # of v_end + slope * min(s', iv), 0..s
            ramp = 0.5 * s * s if s <= iv else 0.5 * iv * iv + iv * (s - iv)
            return [s * v_end[j] + ramp * slope[j] for j in range(n)]

        a, b = integral(max(t0 - tv, 0.0)), integral(t1 - tv)
        return [out[j] + b[j] - a[j] for j in range(n)]

    def _chord_at(self, t: float) -> bool:
        """True if the velocity at ``t`` is an interval's mean from the positions."""
        _, q = self._bracket(self._velocities, t)
        return q is not None and q[0] in self._vel_mean

    @staticmethod
    def _lerp(p: _Sample, q: _Sample, t: float) -> list[float]:
        f = (t - p[0]) / (q[0] - p[0])
        a, b = p[1], q[1]
        if len(a) == 3:
            return [a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1]), a[2] + f * (b[2] - a[2])]
        return [x + f * (y - x) for x, y in zip(a, b, strict=True)]

    def _breakpoints(self, t0: float, t1: float) -> list[float]:
        """``t0``, the sample times and bearing expiries between, ``t1``; with linear
        interpolation, points closer than :data:`MIN_INTERVAL_S` to the previous one merge."""
        cfg = self.config
        inner = [t for t, _ in self._velocities if t0 < t < t1]
        age = cfg.max_bearing_age_s
        for t, _ in self._bearings:
            if t0 < t < t1:
                inner.append(t)
            if t0 < t + age < t1:
                inner.append(t + age)
        if not inner:
            return [t0, t1]
        inner.sort()
        gap = MIN_INTERVAL_S if cfg.interpolation == "linear" else 0.0
        pts = [t0]
        for t in inner:
            if t - pts[-1] >= gap and t1 - t >= gap:
                pts.append(t)
        pts.append(t1)
        return pts

    def _kf_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The riccati estimate ``(x (n,), a (n,), P (2n, 2n))`` at the committed time, or
        the configured guess before the start (cached between commits)."""
        if self._kf_out is None:
            if self._bank is None:
                n = self.config.n
                return np.zeros(n), np.zeros(n), np.full((2 * n, 2 * n), np.inf)
            x, a, p = riccati.bank_estimate(self._bank)
            self._kf_out = (x[0], a[0], p[0])
        return self._kf_out

    def _integrate_kf(
        self, t0: float, t1: float, records: list[_Record]
    ) -> tuple[riccati.Bank, float | None]:
        """The riccati estimator from ``t0`` to ``t1``: predict between the sample times
        (the velocity interpolated as for the paper's observer), update at each bearing
        sample in ``(t0, t1]``. Works on a copy; returns the new bank and the time of the
        latest bearing applied. Appends the monitor's records as :meth:`_integrate` does."""
        cfg = self.config
        n = cfg.n
        bank = riccati.copy_bank(self._bank)  # type: ignore[arg-type]
        prm = self._bank_params()
        # an interval whose displacement comes from the vehicle's positions has the
        # positions' small error, not the velocity's (see update_velocity_values)
        prm_chord = (
            replace(prm, q_x=min(prm.q_x, CHORD_NOISE_MPS**2 * self._vel_dt))
            if self._vel_mean
            else prm
        )
        bearings = {t: y for t, y in self._bearings if t0 < t <= t1}
        inner = {t for t, _ in self._velocities if t0 < t < t1}
        inner.update(t for t in bearings if t < t1)
        age = cfg.max_bearing_age_s
        inner.update(t + age for t, _ in self._bearings if t0 < t + age < t1)
        pts = [t0, *sorted(inner), t1]
        x_before, a_before, _ = self._kf_state()
        t_b = self._kf_tb
        vsum = [0.0] * n
        yy = [0.0] * (n * n)
        valid = 0.0
        for a, b in itertools.pairwise(pts):
            h = b - a
            if h <= 0.0:
                continue
            mid = 0.5 * (a + b)
            v = self._velocity_at(mid)
            for j in range(n):
                vsum[j] += h * v[j]
            chord = self._vel_mean and self._chord_at(mid)
            riccati.bank_predict(bank, np.array([v]) * h, h, prm_chord if chord else prm)
            y_mid = self._bearing_at(mid)
            if y_mid is not None:
                valid += h
                _add_outer(yy, y_mid, h)
            y = bearings.get(b)
            if y is not None:
                gap = b - t_b if t_b is not None else 0.0
                riccati.bank_update(bank, np.array([y]), gap, prm)
                t_b = b
        records.append(("interval", t0, t1, yy if valid > 0.0 else None, valid))
        x_after, a_after, _ = riccati.bank_estimate(bank)
        x_list = x_after[0].tolist()
        records.append(("xhat", x_list))
        if bearings:
            dt = t1 - t0
            dx = [x_list[j] - x_before[j] - vsum[j] - dt * a_before[j] for j in range(n)]
            da = (a_after[0] - a_before).tolist()
            records.append(("correction", t1, dx, da))
        return bank, t_b

    def _xhat_committed(self) -> list[float]:
        """``xhat`` of the committed state (cached between commits)."""
        if self._kalman:
            if self._xhat_c is None:
                self._xhat_c = self._kf_state()[0].tolist()
            return self._xhat_c
        if self._xhat_c is None:
            s = self._state
            self._xhat_c = discrete.estimate_from_state(s.ahat, s.xh1, s.m)
        return self._xhat_c

    def _integrate(
        self,
        state: _State,
        t0: float,
        t1: float,
        records: list[_Record] | None,
        *,
        predict_only: bool = False,
    ) -> _State:
        """Integrate from ``t0`` to ``t1`` and return the new state (the input is not
        modified). With ``records`` (committed steps), append what the monitor's window must
        account over ``[t0, t1]``: the integral of ``y y^T`` over the time with a usable
        bearing, that time, and the correction applied. ``predict_only``: no correction."""
        cfg = self.config
        k, ks = cfg.k_per_s, cfg.k_star_per_s
        biased = self._biased
        hold = cfg.static_hold
        hold_speed2, hold_cos = self._hold_speed2, self._hold_cos
        xh1, m, ahat = state.xh1, state.m, state.ahat
        n = cfg.n
        keep = records is not None
        if keep:
            x_before = (
                self._xhat_committed()
                if state is self._state
                else (discrete.estimate_from_state(ahat, xh1, m))
            )
            a_before = ahat
            pred = [0.0] * n
            yy = [0.0] * (n * n)
            valid = 0.0
            corrected_any = False
        for a, b in itertools.pairwise(self._breakpoints(t0, t1)):
            span = b - a
            y_mid = None if predict_only else self._bearing_at(0.5 * (a + b))
            corrected = y_mid is not None
            n_sub = discrete.substep_count(k, ks, span) if corrected else 1
            hs = span / n_sub
            for i in range(n_sub):
                tm = a + (i + 0.5) * hs
                v = self._velocity_at(tm)
                if not corrected:
                    y = None
                elif n_sub == 1:
                    y = y_mid
                else:
                    y = self._bearing_at(tm)
                held = (
                    hold
                    and y is not None
                    and self._static(xh1, m, ahat, y, v, hold_speed2, hold_cos)
                )
                if not held:
                    if keep:
                        for j in range(n):
                            pred[j] += hs * (v[j] + ahat[j])
                    xh1, m, ahat = discrete.substep(
                        xh1, m, ahat, y, v, k, ks, hs, estimate_bias=biased
                    )
                if keep and y is not None:
                    valid += hs
                    corrected_any = True
                    _add_outer(yy, y, hs)
        if keep:
            records.append(("interval", t0, t1, yy if valid > 0.0 else None, valid))  # type: ignore[union-attr]
            x_after = discrete.estimate_from_state(ahat, xh1, m)
            records.append(("xhat", x_after))  # type: ignore[union-attr]
            if corrected_any:
                dx = [x_after[j] - x_before[j] - pred[j] for j in range(n)]
                da = [ahat[j] - a_before[j] for j in range(n)]
                records.append(("correction", t1, dx, da))  # type: ignore[union-attr]
        return _State(xh1, m, ahat)

    @staticmethod
    def _static(
        xh1: list[float],
        m: list[float],
        ahat: list[float],
        y: list[float],
        v: list[float],
        speed2_max: float,
        cos_min: float,
    ) -> bool:
        """Static-geometry test: estimated relative velocity ``v + ahat`` at most the hold
        speed, and the bearing ``y`` within the hold angle of the estimate ``xhat``."""
        rel2 = 0.0
        for p, q in zip(v, ahat, strict=True):
            rel2 += (p + q) * (p + q)
        if rel2 > speed2_max:
            return False
        xhat = discrete.estimate_from_state(ahat, xh1, m)
        r2 = discrete.dot(xhat, xhat)
        if r2 <= 0.0:
            return False
        return discrete.dot(xhat, y) >= cos_min * math.sqrt(r2)

    # -- output ---------------------------------------------------------------------
    def _estimate_at(self, t: float) -> Estimate:
        cfg = self.config
        started = self._t_c is not None
        state = self._state
        xhat = self._xhat_committed()
        if self._kalman:
            _, a_kf, p_kf = self._kf_state()
            a_now = a_kf.tolist()
        else:
            a_now = state.ahat
        dt = 0.0
        if started and t > self._t_c:  # type: ignore[operator]
            # beyond the committed state: a prediction, xhat' = v + ahat (exact for the
            # linear velocity, never committed). The bearings since are applied when the
            # velocity around them is known, at the next commit.
            dt = t - self._t_c  # type: ignore[operator]
            d = self._predicted_displacement(self._t_c, t)  # type: ignore[arg-type]
            xhat = [xhat[j] + d[j] + dt * a_now[j] for j in range(cfg.n)]
        rng = math.sqrt(discrete.dot(xhat, xhat))
        b_age = t - self._bearings[-1][0] if self._bearings else None
        v_age = t - self._velocities[-1][0] if self._velocities else None
        if self._diag is None or not 0.0 <= t - self._diag[0] < DIAGNOSTICS_PERIOD_S:
            self._diag = (t, self._window.excitation())
        excitation = self._diag[1]
        if self._cond is None or self._cond[0] != self._t_c:  # of the committed state
            if self._kalman:  # of the position's covariance (1 before the start)
                c = 1.0
                if self._bank is not None:
                    ev = discrete.sym_eigvals(p_kf[: cfg.n, : cfg.n].ravel().tolist(), cfg.n)
                    c = ev[-1] / ev[0] if ev[0] > 0.0 else math.inf
            else:
                c = discrete.cond2(self._state.m, cfg.n)
            self._cond = (self._t_c, c)
        cond = self._cond[1]
        covered = self._window.covered_s()
        corr = self._window.correction_rel(rng)
        self._memory = next_status(
            self._memory,
            t_s=t,
            started=started,
            bearing_age_s=b_age,
            velocity_age_s=v_age,
            excitation=excitation,
            covered_s=covered,
            correction_rel=corr,
            th=self._thresholds,
        )
        corrected = started and b_age is not None and b_age <= cfg.max_bearing_age_s
        x_out = np.array(xhat)
        a_out = np.array(a_now)
        x_out.setflags(write=False)
        a_out.setflags(write=False)
        x_std = a_std = range_std = nis = None
        if self._kalman and started:
            nis = float(self._bank.nis_avg[0]) / (cfg.n - 1)  # type: ignore[union-attr]
            n = cfg.n
            pxx = p_kf[:n, :n]
            if dt > 0.0:  # the prediction's uncertainty grows with the bias's
                pxx = (
                    pxx
                    + dt * (p_kf[:n, n:] + p_kf[n:, :n])
                    + dt * dt * p_kf[n:, n:]
                    + (self._velocity_noise_mps() ** 2 * self._vel_dt * dt) * np.eye(n)
                )
            x_std = np.sqrt(np.maximum(np.diag(pxx), 0.0))
            a_std = np.sqrt(np.maximum(np.diag(p_kf[n:, n:]), 0.0))
            u = x_out / rng if rng > 0.0 else x_out
            range_std = float(math.sqrt(max(float(u @ pxx @ u), 0.0)))
            x_std.setflags(write=False)
            a_std.setflags(write=False)
        est = Estimate(
            t_s=t,
            x_m=x_out,
            a_mps=a_out,
            range_m=rng,
            excitation=excitation,
            cond_m=cond,
            status=self._memory.status,
            corrected=bool(corrected),
            bearing_age_s=b_age,
            velocity_age_s=v_age,
            correction_rel=corr,
            x_std_m=x_std,
            a_std_mps=a_std,
            range_std_m=range_std,
            nis=nis,
        )
        self._estimate = est
        return est

    def resume(self, t_s: float, dx_m: Sequence[float], v_mps: Sequence[float]) -> None:
        """Carry the observer across a gap in its data (a service restart) to ``t_s``.

        The estimate moves by ``dx_m`` (m), the change of ``x`` over the gap known from
        elsewhere: for a vehicle and a target that stays put in the autopilot's local frame,
        minus the vehicle's displacement in that frame (``ahat`` is not integrated over the
        gap: where the local position is GPS-true, ``a`` is the velocity's error, which
        does not move the target in that frame). The
        velocity ``v_mps`` (the paper's ``v``) holds from ``t_s``. The gains' matrix, the
        excitation window and the status carry over unchanged (shifted in time by the gap):
        what the observer had learnt stays learnt. Raises :class:`StateError` if the observer
        never started or ``t_s`` is before its committed time, :class:`InvalidSampleError` for
        a non-finite or wrong-sized argument.
        """
        if self._t_c is None:
            raise StateError("resume: the observer has not started, there is nothing to carry")
        t = _check_time(t_s)
        if t < self._t_c:
            raise StateError(f"resume t_s={t} is before the committed time t_s={self._t_c}")
        n = self.config.n
        dx = _frozen_vector("dx_m", dx_m, t).tolist()
        v = _frozen_vector("v_mps", v_mps, t).tolist()
        if len(dx) != n or len(v) != n:
            raise InvalidSampleError(f"resume: dx_m and v_mps must have dimension n={n}")
        gap = t - self._t_c
        if self._bank is not None:
            shift = np.array(dx)
            self._bank.x = self._bank.x + shift
            self._bank.xp = self._bank.xp + shift
            self._kf_out = None
        else:
            s = self._state
            s.xh1 = [s.xh1[j] + dx[j] for j in range(n)]
        self._t_c = t
        self._velocities = [(t, v)]
        self._vel_mean = {}
        del self._bearings[:-1]  # the last bearing, now too old to be used, keeps the horizon
        self._window.shift(gap)
        since = self._memory.observable_since_s
        self._memory = StatusMemory(self._memory.status, None if since is None else since + gap)
        self._xhat_c = None
        self._diag = None
        self._cond = None
        self._estimate = None

    # -- persistence ----------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The whole observer as a JSON-serialisable dictionary; :meth:`from_dict` restores
        it exactly (floats round-trip through JSON bit for bit)."""
        s = self._state
        n = self.config.n
        return {
            "schema": STATE_SCHEMA,
            "config": self.config.to_dict(),
            "t_c": self._t_c,
            "xh1": list(s.xh1),
            "m": [s.m[i * n : (i + 1) * n] for i in range(n)],
            "ahat": list(s.ahat),
            "bearings": [[t, list(y)] for t, y in self._bearings],
            "velocities": [[t, list(v)] for t, v in self._velocities],
            "window": self._window.to_dict(),
            "memory": {
                "status": str(self._memory.status),
                "observable_since_s": self._memory.observable_since_s,
            },
            "counts": dict(self._counts),
            "estimate": None if self._estimate is None else self._estimate.to_dict(),
            "excitation_cache": None if self._diag is None else list(self._diag),
            "velocity_noise": None if self._vnoise is None else self._vnoise.to_dict(),
            "kalman": None
            if self._bank is None
            else {
                "bank": {
                    f.name: getattr(self._bank, f.name).tolist() for f in fields(riccati.Bank)
                },
                "t_bearing": self._kf_tb,
                "velocity_dt": self._vel_dt,
            },
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BiasObserver:
        """Restore an observer saved by :meth:`to_dict`; a bad field is a :class:`StateError`
        naming it."""
        if not isinstance(d, dict):
            raise StateError(f"observer state must be a dictionary, got {type(d).__name__}")
        if d.get("schema") != STATE_SCHEMA:
            raise StateError(f"observer state schema {d.get('schema')!r} is not {STATE_SCHEMA}")
        try:
            config = ObserverConfig.from_dict(d["config"])
        except ConfigError as exc:
            raise StateError(f"config: {exc}") from exc
        except KeyError as exc:
            raise StateError("observer state has no 'config'") from exc
        obs = cls(config)
        n = config.n
        obs._xhat_c = None
        obs._state = _State(
            _field_array(d, "xh1", (n,)).tolist(),
            _field_array(d, "m", (n, n)).ravel().tolist(),
            _field_array(d, "ahat", (n,)).tolist(),
        )
        t_c = d.get("t_c")
        if t_c is not None:
            t_c = _field_float(d, "t_c")
        obs._t_c = t_c
        obs._bearings = _field_samples(d, "bearings", n, unit=True)
        obs._velocities = _field_samples(d, "velocities", n, unit=False)
        obs._window = ExcitationWindow.from_dict(n, _field(d, "window", dict))
        mem = _field(d, "memory", dict)
        try:
            status = Status(mem["status"])
            since = mem["observable_since_s"]
            since = None if since is None else float(since)
        except (KeyError, ValueError, TypeError) as exc:
            raise StateError(f"memory: {exc!r}") from exc
        obs._memory = StatusMemory(status, since)
        counts = _field(d, "counts", dict)
        obs._counts = {
            "velocity": int(counts.get("velocity", 0)),
            "bearing": int(counts.get("bearing", 0)),
        }
        est = d.get("estimate")
        if est is not None:
            obs._estimate = _estimate_from_dict(est)
        diag = d.get("excitation_cache")
        if diag is not None:
            try:
                t_d, e_d = (float(v) for v in diag)
            except (TypeError, ValueError) as exc:
                raise StateError(
                    f"observer state 'excitation_cache' is malformed: {diag!r}"
                ) from exc
            obs._diag = (t_d, e_d)
        vn = d.get("velocity_noise")
        if vn is not None and obs._vnoise is not None:
            try:
                obs._vnoise.restore(vn)
            except NoiseStateError as exc:
                raise StateError(str(exc)) from exc
        kal = d.get("kalman")
        if kal is not None:
            obs._bank, obs._kf_tb, obs._vel_dt = _bank_from_dict(kal, n)
        elif obs._kalman and t_c is not None:
            raise StateError("observer state of a started riccati estimator has no 'kalman'")
        return obs


def _bank_from_dict(k: Any, n: int) -> tuple[riccati.Bank, float | None, float]:
    """The riccati estimator's saved bank, checked: shapes, finite values, owners."""
    try:
        raw = k["bank"]
        # states saved before the noise was learnt lack its fields: the prior, nothing counted
        added = {"noise_alpha", "noise_beta", "outliers", "bearings", "inlier_avg"}
        arrays = {
            f.name: np.array(raw[f.name], dtype=float)
            for f in fields(riccati.Bank)
            if f.name in raw or f.name not in added | riccati.BANK_WALK_FIELDS
        }
        t_b = None if k["t_bearing"] is None else float(k["t_bearing"])
        vel_dt = float(k["velocity_dt"])
    except (KeyError, TypeError, ValueError) as exc:
        raise StateError(f"observer state 'kalman' is malformed: {exc!r}") from exc
    if not added <= arrays.keys():
        prior = math.radians(BEARING_NOISE_PRIOR_DEG) ** 2
        arrays["noise_alpha"] = np.array([1.0])
        arrays["noise_beta"] = np.array([prior])
        arrays["outliers"] = arrays["bearings"] = np.array([0.0])
        arrays["inlier_avg"] = np.array([1.0])
    f_count = arrays["x"].shape[0] if arrays["x"].ndim == 2 else -1
    for name, v in riccati.walk_defaults(1, n).items():  # saved before it was learnt
        arrays.setdefault(name, v)
    shapes = {
        "x": (f_count, n), "a": (f_count, n), "p": (f_count, 2 * n, 2 * n),
        "logw": (f_count,), "owner": (f_count,), "r0": (1,), "xp": (1, n), "ap": (1, n),
        "pp": (1, 2 * n, 2 * n), "nis_avg": (1,), "age_s": (1,), "reseeds": (1,),
        "noise_alpha": (1,), "noise_beta": (1,), "outliers": (1,), "bearings": (1,),
        "inlier_avg": (1,), **{f: v.shape for f, v in riccati.walk_defaults(1, n).items()},
    }  # fmt: skip
    for name, shape in shapes.items():
        arr = arrays[name]
        if f_count < 1 or arr.shape != shape or not np.all(np.isfinite(arr)):
            raise StateError(
                f"observer state 'kalman.bank.{name}' must be finite with shape {shape}"
            )
    if np.any(arrays["owner"] != 0) or not 0.0 < vel_dt <= 1.0:
        raise StateError("observer state 'kalman' has a foreign owner or a bad velocity_dt")
    arrays["owner"] = arrays["owner"].astype(int)
    for name in ("reseeds", "outliers", "bearings"):
        arrays[name] = arrays[name].astype(int)
    if arrays["noise_alpha"][0] <= 0.0 or arrays["noise_beta"][0] <= 0.0:
        raise StateError("observer state 'kalman.bank.noise_alpha/noise_beta' must be > 0")
    return riccati.Bank(**arrays), t_b, vel_dt


def _field(d: dict[str, Any], key: str, typ: type) -> Any:
    if key not in d:
        raise StateError(f"observer state has no {key!r}")
    if not isinstance(d[key], typ):
        raise StateError(f"observer state {key!r} must be a {typ.__name__}, got {d[key]!r}")
    return d[key]


def _field_float(d: dict[str, Any], key: str) -> float:
    val = d.get(key)
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
        raise StateError(f"observer state {key!r} must be a finite number, got {val!r}")
    return float(val)


def _field_array(d: dict[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray:
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


def _field_samples(d: dict[str, Any], key: str, n: int, *, unit: bool) -> list[_Sample]:
    raw = _field(d, key, list)
    out: list[_Sample] = []
    for item in raw:
        if not isinstance(item, Sequence) or len(item) != 2:
            raise StateError(f"observer state {key!r} holds a malformed sample {item!r}")
        try:
            s = BearingSample(item[0], item[1]) if unit else VelocitySample(item[0], item[1])
        except InvalidSampleError as exc:
            raise StateError(f"observer state {key!r}: {exc}") from exc
        vec = s.y if unit else s.v_mps  # type: ignore[union-attr]
        if vec.shape != (n,):
            raise StateError(f"observer state {key!r} holds a sample of dimension {vec.shape[0]}")
        # keep the stored bits exactly (a BearingSample could re-normalise)
        out.append((float(item[0]), [float(c) for c in item[1]]))
    return out


def _optional_array(v: Any) -> np.ndarray | None:
    if v is None:
        return None
    arr = np.array(v, dtype=float)
    arr.setflags(write=False)
    return arr


def _estimate_from_dict(e: Any) -> Estimate:
    try:
        return Estimate(
            t_s=float(e["t_s"]),
            x_m=np.array(e["x_m"], dtype=float),
            a_mps=np.array(e["a_mps"], dtype=float),
            range_m=float(e["range_m"]),
            excitation=float(e["excitation"]),
            cond_m=float(e["cond_m"]),
            status=Status(e["status"]),
            corrected=bool(e["corrected"]),
            bearing_age_s=None if e["bearing_age_s"] is None else float(e["bearing_age_s"]),
            velocity_age_s=None if e["velocity_age_s"] is None else float(e["velocity_age_s"]),
            correction_rel=float(e["correction_rel"]),
            x_std_m=_optional_array(e.get("x_std_m")),
            a_std_mps=_optional_array(e.get("a_std_mps")),
            range_std_m=None if e.get("range_std_m") is None else float(e["range_std_m"]),
            nis=None if e.get("nis") is None else float(e["nis"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise StateError(f"observer state 'estimate' is malformed: {exc!r}") from exc
