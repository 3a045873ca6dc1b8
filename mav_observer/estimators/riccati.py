"""The default estimator: a bank of extended Kalman filters on ``[x, a]`` supervised by a
Riccati observer (the maths in :mod:`mav_observer.riccati`; ``docs/estimator.md``).

Predicted between the sample times with the interpolated velocity, updated at each bearing
sample (robustly, with the bearing noise learnt online unless told); the velocity's white
noise is learnt from its samples (:mod:`mav_observer.noise`) unless told. It carries a
covariance.
"""

from __future__ import annotations

import math
from dataclasses import fields, replace
from typing import Any, ClassVar

import numpy as np

from mav_observer import discrete, riccati, single
from mav_observer.config import (
    AUTO,
    BEARING_NOISE_PRIOR_DEG,
    MAX_BEARING_LATENCY_S,
    VELOCITY_NOISE_PRIOR_MPS,
    ObserverConfig,
)
from mav_observer.errors import StateError
from mav_observer.estimators.base import Inputs, Output
from mav_observer.latency import LatencyLearner, LatencyStateError, Settling, advance
from mav_observer.noise import NoiseStateError, VelocityNoise
from mav_observer.samples import NoiseLevels
from mav_observer.whiteness import InnovationCorrelation

#: The error (m/s, as a white velocity noise) of a velocity interval whose mean comes from
#: the vehicle's positions (``update_velocity_values``'s ``interval_mean_mps``): GNSS-aided
#: positions do not accumulate the velocity's noise (measured on the shared real logs with
#: injected bearings: a velocity noise of 0.05 m/s there cost 2x to 10x in error), and the
#: displacements of successive intervals telescope, so the error does not accumulate either
#: (0.01 m/s, a random walk of 1 cm per root second, cost 1.9x the bound on the e2e case
#: ``velocity_1hz``; 0.0003 m/s, 1.05x on the same seeds, and the same on the shared 1 Hz
#: logs).
CHORD_NOISE_MPS = 0.0003


#: The latency is learnt from a converged estimate only: this long after the bank's seeding
#: (s), with a position variance below :data:`LATENCY_CONVERGED_REL` squared times the
#: range squared.
LATENCY_AFTER_S = 30.0
LATENCY_CONVERGED_REL = 0.05
#: The bias's random walk (``bias_walk_mps_per_sqrt_s = "auto"``) waits for the latency, when
#: that is learnt too, in two phases. Off (no probe runs) until the latency has been learning
#: for this long (s): before, a gimbal's lag not yet accounted for looks like a wandering bias,
#: and a wandering bias moves the latency ...
WALK_AFTER_LATENCY_S = 30.0
#: ... but at most this long after the bank's seeding (s): an estimate that never converges
#: well enough to learn the latency from still learns the walk.
WALK_HOLD_MAX_S = 90.0
#: Then held (leaving its level upward takes ``BankParams.walk_hold_nats`` of lead) until the
#: latency has settled (:class:`~mav_observer.latency.Settling`): moved by less than
#: :data:`WALK_LATENCY_STEP_S` (s) over the latest :data:`WALK_LATENCY_WINDOW_S` (s). A latency
#: still moving (the lag being learnt) leaves a bearing error correlated over seconds, which
#: the probes take for a wandering bias; a bias that wanders as much as the e2e case
#: ``velocity_coloured`` (0.1 m/s Gauss-Markov) still clears the higher bar.
WALK_LATENCY_WINDOW_S = 20.0
WALK_LATENCY_STEP_S = 0.003


#: For :meth:`RiccatiEstimator.position_cov` in three dimensions: per entry ``(i, j)`` of the
#: position block, the flat 6x6 indices of ``P_xx``, ``P_xa``, ``P_ax``, ``P_aa`` and whether
#: it is on the diagonal
_POSITION_COV_3 = tuple(
    (6 * i + j, 6 * i + 3 + j, 18 + 6 * i + j, 21 + 6 * i + j, i == j)
    for i in range(3)
    for j in range(3)
)


class RiccatiEstimator:
    """The filter bank (``estimator = "riccati"``, the default)."""

    name: ClassVar[str] = "riccati"
    continuous: ClassVar[bool] = False

    def __init__(self, config: ObserverConfig) -> None:
        self.config = config
        #: the bank in other than three dimensions ...
        self.bank: riccati.Bank | None = None
        #: ... else in plain floats (:mod:`mav_observer.single`)
        self.one: single.Single | None = None
        #: time (s) of the latest bearing applied
        self.t_bearing_s: float | None = None
        #: the velocity's white noise, learnt from its samples (``velocity_noise_mps = "auto"``)
        self.vnoise = (
            VelocityNoise(prior_mps=VELOCITY_NOISE_PRIOR_MPS)
            if config.velocity_noise_mps == AUTO
            else None
        )
        self._out: Output | None = None  # the estimate, cached
        self._a_ref: list[float] | None = None  # the open-loop reference of a working copy
        self._prm: riccati.BankParams | None = None
        self._prm_held: riccati.BankParams | None = None
        self._prm_off: riccati.BankParams | None = None
        #: whether the latency learnt has settled (the walk's hold)
        self.settling = Settling(WALK_LATENCY_WINDOW_S, WALK_LATENCY_STEP_S, WALK_AFTER_LATENCY_S)
        #: the bearings' latency, learnt (``bearing_latency_s = "auto"``) or told
        self.latency = (
            LatencyLearner(max_s=MAX_BEARING_LATENCY_S)
            if config.bearing_latency_s == AUTO
            else None
        )
        #: whether the latency learnt has settled once (:attr:`settled`)
        self.latency_settled = self.latency is None
        #: the lag-1 correlation of the one filter's innovations (a diagnostic, not saved)
        self.whiteness = InnovationCorrelation()

    # -- settings in force -----------------------------------------------------------
    def velocity_noise_mps(self) -> float:
        """The white velocity noise in use (m/s per axis): learnt or told."""
        if self.vnoise is not None:
            return self.vnoise.sigma_mps
        return float(self.config.velocity_noise_mps)

    def params(self) -> riccati.BankParams:
        """The bank's settings (made once); their ``q_x`` is not the one in use (it moves
        with the velocity's sample interval and its noise, learnt at every sample):
        :meth:`q_x_m2ps` is."""
        if self._prm is None:
            self._prm = self.config.bank_params(1.0)
        return self._prm

    def q_x_m2ps(self, velocity_dt_s: float, *, chord: bool = False) -> float:
        """The process noise on ``x`` (m^2/s) from the velocity noise in use and its sample
        interval ``velocity_dt_s`` (s); ``chord``: for an interval whose displacement comes
        from the vehicle's positions, which have the positions' small error
        (:data:`CHORD_NOISE_MPS`), not the velocity's."""
        q_x = self.velocity_noise_mps() ** 2 * velocity_dt_s
        return min(q_x, CHORD_NOISE_MPS**2 * velocity_dt_s) if chord else q_x

    def bearing_latency_s(self) -> float:
        """The bearings' latency in use (s): learnt or told."""
        if self.latency is not None:
            return self.latency.tau_s
        return float(self.config.bearing_latency_s)

    # -- the interface ---------------------------------------------------------------
    @property
    def min_interval_s(self) -> float:
        return 0.0  # every bearing is applied at its own time

    @property
    def started(self) -> bool:
        return self.bank is not None or self.one is not None

    @property
    def settled(self) -> bool:
        """True once the latency learnt has settled (:class:`~mav_observer.latency.Settling`:
        learnt for 30 s and moved by under 3 ms over 20 s), or has not started learning 90 s
        after the bank's seeding (:data:`WALK_HOLD_MAX_S`: an estimate never certain enough to
        learn it from, within 5 % of its range, whose sigma is larger than a lag's error), and
        stays so; always with a latency told. Before, an estimate can look converged with a
        gimbal's lag in it: the e2e case ``gimbal_lag`` was 0.4 m off at a sigma of 0.05 m for
        its first 30 s "converged"."""
        return self.latency_settled

    def _set_bank(self, bank: riccati.Bank) -> None:
        """Hold ``bank``, as floats in three dimensions (:mod:`mav_observer.single`)."""
        if single.applies(bank):
            self.bank, self.one = None, single.from_bank(bank)
        else:
            self.bank, self.one = bank, None

    def _whole_bank(self) -> riccati.Bank | None:
        """The bank, whichever form it is held in (a new one for the floats)."""
        return single.to_bank(self.one) if self.one is not None else self.bank

    def start(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        prm = self.params()
        bank = riccati.bank_start(np.array([y]), np.array([self.config.range_guess_m]), prm)
        self._set_bank(bank)
        self.t_bearing_s = t_s
        self._out = None

    def copy(self) -> RiccatiEstimator:
        other = object.__new__(RiccatiEstimator)
        other.__dict__.update(self.__dict__)
        if self.bank is not None:
            other.bank = riccati.copy_bank(self.bank)
        if self.one is not None:
            other.one = self.one.copy()
        if self.latency is not None:
            other.latency = self.latency.copy()
        other.settling = self.settling.copy()
        other.whiteness = self.whiteness.copy()
        other._a_ref = self.output(None).a_mps  # type: ignore[arg-type]
        return other

    def substeps(self, span_s: float, corrected: bool) -> int:
        return 1

    def predict(
        self, t_s: float, h_s: float, v_mps: list[float], y: list[float] | None, inputs: Inputs
    ) -> list[float]:
        dt_s = inputs.velocity_dt_s
        prm = self.params()
        q_x = self.q_x_m2ps(dt_s, chord=inputs.chord_at(t_s))
        if self.one is not None:
            v0, v1, v2 = v_mps
            single.predict(self.one, [v0 * h_s, v1 * h_s, v2 * h_s], h_s, prm, q_x)
            self._out = None
            a_ref = self._a_ref if self._a_ref is not None else self.output(inputs).a_mps
            return [h_s * v0 + h_s * a_ref[0], h_s * v1 + h_s * a_ref[1], h_s * v2 + h_s * a_ref[2]]
        bank = self.bank
        riccati.bank_predict(bank, np.array([v_mps]) * h_s, h_s, prm, q_x)  # type: ignore[arg-type]
        self._out = None
        a_ref = self._a_ref if self._a_ref is not None else self.output(inputs).a_mps
        return [h_s * v_mps[j] + h_s * a_ref[j] for j in range(len(v_mps))]

    def update(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        gap = t_s - self.t_bearing_s if self.t_bearing_s is not None else 0.0
        prm = self.params()
        one, bank = self.one, self.bank
        age_s = one.age_s if one is not None else float(bank.age_s[0])  # type: ignore[union-attr]
        tau = self.bearing_latency_s()
        lat = self.latency
        if lat is not None:
            learning_s = lat.learning_for_s(t_s)
            settled = self.settling.update(t_s, lat.tau_s, learning_s)
            if settled or (learning_s == 0.0 and age_s >= WALK_HOLD_MAX_S):
                # (or never learning, the estimate too uncertain for a lag to show, 90 s on)
                self.latency_settled = True
            if prm.learn_walk:  # the walk waits for the latency (the module's constants)
                if learning_s < WALK_AFTER_LATENCY_S and age_s < WALK_HOLD_MAX_S:
                    if self._prm_off is None:
                        self._prm_off = replace(prm, walk_hold=True, walk_hold_nats=math.inf)
                    prm = self._prm_off
                elif not settled:
                    if self._prm_held is None:
                        self._prm_held = replace(prm, walk_hold=True)
                    prm = self._prm_held
        learns = lat is not None and age_s > LATENCY_AFTER_S
        if learns or tau != 0.0:  # (else nothing below is used: not computed)
            v = inputs.velocity_at(t_s)
            single_filter = one is not None and len(one.x) == 1
            if single_filter:  # the estimate is the filter's (read, not changed)
                x, a = one.x[0], one.a[0]  # type: ignore[union-attr]
            elif one is not None and not learns:
                x, a = one.mean()  # (the covariance is not needed: not made)
            else:
                out = self.output(inputs)
                x, a = out.x_m, out.a_mps
            if learns:
                if single_filter:
                    p1 = one.p[0]  # type: ignore[union-attr]
                    var_x = p1[0] + p1[7] + p1[14]
                else:
                    p = self.output(inputs).p
                    d = 2 * len(y)
                    var_x = sum((p[(d + 1) * j] for j in range(len(y))), 0.0)  # type: ignore[index]
                if var_x < LATENCY_CONVERGED_REL**2 * sum(c * c for c in x):
                    lat.observe(t_s, x, a, v, y, self._noise_var_rad2(prm))  # type: ignore[union-attr]
            if tau != 0.0:  # the line of sight tau earlier, brought to t_s
                y = advance(y, x, a, v, tau)
        if one is not None and len(one.x) == 1:  # the innovation of the one filter
            x0, x1, x2 = one.x[0]
            r = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            if r > 0.0:
                d0, d1, d2 = x0 / r, x1 / r, x2 / r
                c = y[0] * d0 + y[1] * d1 + y[2] * d2
                k = 1.0 / math.sqrt(one.noise_var_rad2(prm))  # in units of the noise in use
                z = ((y[0] - c * d0) * k, (y[1] - c * d1) * k, (y[2] - c * d2) * k)
                self.whiteness.add(t_s, z)
        else:
            self.whiteness.gap()
        if one is not None:
            if single.update(one, y, gap, prm):  # inconsistent: a re-acquisition
                bank = single.to_bank(one)
                riccati.reseed(bank, np.array([True]), np.array([y]), prm)
                self._set_bank(bank)
        else:
            riccati.bank_update(bank, np.array([y]), gap, prm)  # type: ignore[arg-type]
        self.t_bearing_s = t_s
        self._out = None

    def _noise_var_rad2(self, prm: riccati.BankParams) -> float:
        """The bearing noise variance in use (rad^2)."""
        if self.one is not None:
            return self.one.noise_var_rad2(prm)
        return float(self.bank.noise_var_rad2(prm)[0])  # type: ignore[union-attr]

    def output(self, inputs: Inputs | None) -> Output:
        if self._out is None:
            one = self.one
            if one is not None:
                self._out = Output(*one.estimate())
                return self._out
            if self.bank is None:
                n = self.config.n
                return Output([0.0] * n, [0.0] * n, [math.inf] * (4 * n * n))
            x, a, p = riccati.bank_estimate(self.bank)
            self._out = Output(x[0].tolist(), a[0].tolist(), p[0].ravel().tolist())
        return self._out

    def position_cov(self, dt_s: float, inputs: Inputs) -> list[float]:
        n = self.config.n
        f = self.output(inputs).p
        d = 2 * n
        if dt_s <= 0.0:
            if n == 3:
                return [f[0], f[1], f[2], f[6], f[7], f[8], f[12], f[13], f[14]]  # type: ignore[index]
            return [f[d * i + j] for i in range(n) for j in range(n)]  # type: ignore[index]
        # the prediction's uncertainty grows with the bias's (and the velocity noise's, but
        # for a sparse stream's, which is its trend's, the observer's)
        q = 0.0 if inputs.sparse else self.velocity_noise_mps() ** 2 * inputs.velocity_dt_s
        dd = dt_s * dt_s
        if n == 3:  # the same sums, their indices precomputed
            qd = q * dt_s
            return [
                f[i] + dt_s * (f[j] + f[k]) + dd * f[m] + (qd if diag else 0.0)  # type: ignore[index]
                for i, j, k, m, diag in _POSITION_COV_3
            ]
        return [
            f[d * i + j]  # type: ignore[index]
            + dt_s * (f[d * i + n + j] + f[d * (n + i) + j])  # type: ignore[index]
            + dd * f[d * (n + i) + n + j]  # type: ignore[index]
            + (q * dt_s if i == j else 0.0)
            for i in range(n)
            for j in range(n)
        ]

    def cond(self) -> float:
        if not self.started:
            return 1.0
        n = self.config.n
        f = self.output(None).p
        d = 2 * n
        if n == 3:
            pxx = [f[0], f[1], f[2], f[6], f[7], f[8], f[12], f[13], f[14]]  # type: ignore[index]
        else:
            pxx = [f[d * i + j] for i in range(n) for j in range(n)]  # type: ignore[index]
        ev = discrete.sym_eigvals(pxx, n)
        return ev[-1] / ev[0] if ev[0] > 0.0 else math.inf

    def nis(self) -> float | None:
        if self.one is not None:
            return self.one.nis_avg / (self.config.n - 1)
        if self.bank is None:
            return None
        return float(self.bank.nis_avg[0]) / (self.config.n - 1)

    def noise(self, inputs: Inputs) -> NoiseLevels | None:
        prm = self.params()
        bank, one = self.bank, self.one
        if one is not None:
            var, bearings, outliers = one.noise_var_rad2(prm), one.bearings, one.outliers
            reseeds, q_a = one.reseeds, one.bias_walk(prm)
        elif bank is None:
            var, bearings, outliers, reseeds = prm.sigma_rad**2, 0, 0, 0
            q_a = prm.q_a
        else:
            var = float(bank.noise_var_rad2(prm)[0])
            bearings, outliers = int(bank.bearings[0]), int(bank.outliers[0])
            reseeds = int(bank.reseeds[0])
            q_a = float(bank.bias_walk(prm)[0])
        return NoiseLevels(
            bearing_noise_deg=math.degrees(math.sqrt(var)),
            bearing_noise_learnt=prm.learn_noise,
            velocity_noise_mps=self.velocity_noise_mps(),
            velocity_noise_learnt=self.vnoise is not None,
            bearings=bearings,
            outliers=outliers,
            reacquisitions=reseeds,
            bearing_latency_s=self.bearing_latency_s(),
            bearing_latency_learnt=self.latency is not None,
            bias_walk_mps_per_sqrt_s=math.sqrt(q_a),
            bias_walk_learnt=prm.learn_walk,
            innovation_corr=self.whiteness.correlation(),
        )

    @property
    def reacquisitions(self) -> int:
        if self.one is not None:
            return self.one.reseeds
        return 0 if self.bank is None else int(self.bank.reseeds[0])

    def observe_velocity(self, t_s: float, v_mps: list[float]) -> None:
        if self.vnoise is not None:
            self.vnoise.update(t_s, v_mps)

    def shift(self, dx_m: list[float]) -> None:
        self._out = None
        if self.one is not None:
            self.one.shift(dx_m)
        if self.bank is None:
            return
        d = np.array(dx_m)
        self.bank.x = self.bank.x + d
        self.bank.xp = self.bank.xp + d
        self.bank.walk_x = self.bank.walk_x + d

    def to_dict(self) -> dict[str, Any]:
        bank = self._whole_bank()
        return {
            "velocity_noise": None if self.vnoise is None else self.vnoise.to_dict(),
            "bearing_latency": None if self.latency is None else self.latency.to_dict(),
            "latency_settled": self.latency_settled,
            "kalman": None
            if bank is None
            else {
                "bank": {f.name: getattr(bank, f.name).tolist() for f in fields(riccati.Bank)},
                "t_bearing": self.t_bearing_s,
            },
        }

    def restore(self, d: dict[str, Any], started: bool) -> None:
        vn = d.get("velocity_noise")
        if vn is not None and self.vnoise is not None:
            try:
                self.vnoise.restore(vn)
            except NoiseStateError as exc:
                raise StateError(str(exc)) from exc
        lat = d.get("bearing_latency")  # (absent from states saved before it was learnt)
        if lat is not None and self.latency is not None:
            try:
                self.latency.restore(lat)
            except LatencyStateError as exc:
                raise StateError(str(exc)) from exc
        # (absent from states saved before it: a started estimator kept its status as it was)
        done = d.get("latency_settled", started)
        if not isinstance(done, bool):
            raise StateError(
                f"observer state 'latency_settled' must be true or false, got {done!r}"
            )
        self.latency_settled = done or self.latency is None
        kal = d.get("kalman")
        if kal is not None:
            bank, self.t_bearing_s = _bank_from_dict(kal, self.config.n)
            self._set_bank(bank)
        elif started:
            raise StateError("observer state of a started riccati estimator has no 'kalman'")
        self._out = None


def _bank_from_dict(k: Any, n: int) -> tuple[riccati.Bank, float | None]:
    """The saved bank, checked: shapes, finite values, owners."""
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
    except (KeyError, TypeError, ValueError) as exc:
        raise StateError(f"observer state 'kalman' is malformed: {exc!r}") from exc
    if not added <= arrays.keys():
        prior = math.radians(BEARING_NOISE_PRIOR_DEG) ** 2
        arrays["noise_alpha"] = np.array([1.0])
        arrays["noise_beta"] = np.array([prior])
        arrays["outliers"] = arrays["bearings"] = np.array([0.0])
        arrays["inlier_avg"] = np.array([1.0])
    f_count = arrays["x"].shape[0] if arrays["x"].ndim == 2 else -1
    walk = riccati.walk_defaults(1, n)  # saved before the bias walk was learnt: none learnt
    for name, v in walk.items():
        arrays.setdefault(name, v)
    shapes = {
        "x": (f_count, n), "a": (f_count, n), "p": (f_count, 2 * n, 2 * n),
        "logw": (f_count,), "owner": (f_count,), "r0": (1,), "xp": (1, n), "ap": (1, n),
        "pp": (1, 2 * n, 2 * n), "nis_avg": (1,), "age_s": (1,), "reseeds": (1,),
        "noise_alpha": (1,), "noise_beta": (1,), "outliers": (1,), "bearings": (1,),
        "inlier_avg": (1,), **{name: v.shape for name, v in walk.items()},
    }  # fmt: skip
    for name, shape in shapes.items():
        arr = arrays[name]
        if f_count < 1 or arr.shape != shape or not np.all(np.isfinite(arr)):
            raise StateError(
                f"observer state 'kalman.bank.{name}' must be finite with shape {shape}"
            )
    if np.any(arrays["owner"] != 0):
        raise StateError("observer state 'kalman' has a foreign owner")
    arrays["owner"] = arrays["owner"].astype(int)
    for name in ("reseeds", "outliers", "bearings"):
        arrays[name] = arrays[name].astype(int)
    if arrays["noise_alpha"][0] <= 0.0 or arrays["noise_beta"][0] <= 0.0:
        raise StateError("observer state 'kalman.bank.noise_alpha/noise_beta' must be > 0")
    return riccati.Bank(**arrays), t_b
