"""The estimator interface: both estimators implement it, the observer drives any estimator of
the registry (a third one is one class and one registry line), steps run on copies."""

from __future__ import annotations

import json
from typing import Any, ClassVar

import numpy as np
import pytest

from mav_observer import (
    BearingSample,
    BiasObserver,
    ConfigError,
    ObserverConfig,
    StateError,
    VelocitySample,
)
from mav_observer.estimators import REGISTRY, Inputs, Output
from mav_observer.estimators.base import Estimator
from mav_observer.samples import NoiseLevels, Status
from sim import scenarios
from sim.stream import generate


class _NoInputs:
    """Inputs for a direct call: none needed by a prediction without a bearing."""

    velocity_dt_s = 0.05

    def chord_at(self, t: float) -> bool:
        return False


_METHODS = [
    "start",
    "copy",
    "substeps",
    "predict",
    "update",
    "output",
    "position_cov",
    "cond",
    "nis",
    "noise",
    "observe_velocity",
    "shift",
    "to_dict",
    "restore",
]


@pytest.mark.parametrize("name", list(REGISTRY))
def test_every_registered_estimator_implements_the_interface(name: str) -> None:
    est = REGISTRY[name](ObserverConfig(estimator=name))
    for method in _METHODS:
        assert callable(getattr(est, method)), method
    for attr in ("min_interval_s", "started", "settled", "reacquisitions", "name", "continuous"):
        getattr(est, attr)
    assert est.name == name
    assert not est.started


def _feed(obs: BiasObserver, duration_s: float = 20.0) -> None:
    for ev in generate(scenarios.orbit(duration_s=duration_s)).events():
        if isinstance(ev, BearingSample):
            obs.update_bearing(ev)
        else:
            obs.update_velocity(ev)


@pytest.mark.parametrize("name", list(REGISTRY))
def test_a_step_runs_on_a_copy_and_leaves_the_original_as_it_was(name: str) -> None:
    obs = BiasObserver(ObserverConfig(estimator=name))
    _feed(obs, 5.0)
    est = obs.estimator
    before = json.dumps(est.to_dict(), sort_keys=True)
    inputs = _NoInputs()
    out_before = est.output(inputs)  # type: ignore[arg-type]
    work = est.copy()
    work.predict(0.5, 1.0, [1.0, 2.0, 0.0], None, inputs)  # type: ignore[arg-type]
    assert work.output(inputs).x_m != out_before.x_m  # type: ignore[arg-type]
    assert json.dumps(est.to_dict(), sort_keys=True) == before
    assert est.output(inputs).x_m == out_before.x_m  # type: ignore[arg-type]


@pytest.mark.parametrize("name", list(REGISTRY))
def test_a_prediction_without_a_bearing_moves_x_by_v_plus_a(name: str) -> None:
    obs = BiasObserver(ObserverConfig(estimator=name))
    _feed(obs, 5.0)
    work = obs.estimator.copy()
    x0, a0 = work.output(_NoInputs()).x_m, work.output(_NoInputs()).a_mps  # type: ignore[arg-type]
    moved = work.predict(1.0, 2.0, [1.0, -0.5, 0.25], None, _NoInputs())  # type: ignore[arg-type]
    expect = [2.0 * (v + a) for v, a in zip([1.0, -0.5, 0.25], a0, strict=True)]
    assert moved == pytest.approx(expect, abs=1e-12)
    x1 = work.output(_NoInputs()).x_m  # type: ignore[arg-type]
    assert [p - q for p, q in zip(x1, x0, strict=True)] == pytest.approx(expect, abs=1e-9)


class DeadReckoning:
    """A third estimator for the test: ``x`` starts at 10 m along the first bearing and is
    dead-reckoned with ``v`` (``a = 0``), the bearings ignored."""

    name: ClassVar[str] = "dead_reckoning"
    continuous: ClassVar[bool] = False

    def __init__(self, config: ObserverConfig) -> None:
        self.n = config.n
        self.x: list[float] = [0.0] * config.n
        self._started = False

    min_interval_s = 0.0

    @property
    def started(self) -> bool:
        return self._started

    #: it learns nothing that could move its estimate later
    settled = True

    @property
    def reacquisitions(self) -> int:
        return 0

    def start(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        self.x = [10.0 * c for c in y]
        self._started = True

    def copy(self) -> DeadReckoning:
        other = DeadReckoning.__new__(DeadReckoning)
        other.__dict__.update(self.__dict__)
        return other

    def substeps(self, span_s: float, corrected: bool) -> int:
        return 1

    def predict(
        self, t_s: float, h_s: float, v_mps: list[float], y: list[float] | None, inputs: Inputs
    ) -> list[float]:
        moved = [h_s * v for v in v_mps]
        self.x = [p + q for p, q in zip(self.x, moved, strict=True)]
        return moved

    def update(self, t_s: float, y: list[float], inputs: Inputs) -> None:
        pass

    def output(self, inputs: Inputs) -> Output:
        return Output(list(self.x), [0.0] * self.n, None)

    def position_cov(self, dt_s: float, inputs: Inputs) -> np.ndarray | None:
        return None

    def cond(self) -> float:
        return 1.0

    def nis(self) -> float | None:
        return None

    def noise(self, inputs: Inputs) -> NoiseLevels | None:
        return None

    def observe_velocity(self, t_s: float, v_mps: list[float]) -> None:
        pass

    def shift(self, dx_m: list[float]) -> None:
        self.x = [p + q for p, q in zip(self.x, dx_m, strict=True)]

    def to_dict(self) -> dict[str, Any]:
        return {"dead_reckoning": {"x": list(self.x)}}

    def restore(self, d: dict[str, Any], started: bool) -> None:
        try:
            self.x = [float(c) for c in d["dead_reckoning"]["x"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise StateError(f"observer state 'dead_reckoning' is malformed: {exc!r}") from exc
        self._started = started


def test_a_third_estimator_is_one_class_and_one_registry_line(monkeypatch) -> None:
    with pytest.raises(ConfigError, match="estimator must be one of"):
        ObserverConfig(estimator="dead_reckoning")
    monkeypatch.setitem(REGISTRY, "dead_reckoning", DeadReckoning)
    _check: type[Estimator] = DeadReckoning  # type-checks against the protocol
    obs = BiasObserver(ObserverConfig(estimator="dead_reckoning"))
    obs.update_velocity(VelocitySample(0.0, [1.0, 0.0, 0.0]))
    first = obs.update_bearing(BearingSample(0.0, [0.0, 1.0, 0.0]))
    assert first.x_m.tolist() == [0.0, 10.0, 0.0]
    obs.update_velocity(VelocitySample(2.0, [1.0, 0.0, 0.0]))
    est = obs.update_bearing(BearingSample(2.0, [0.0, 1.0, 0.0]))
    assert est.x_m.tolist() == pytest.approx([2.0, 10.0, 0.0])  # the observer integrated v
    assert est.x_std_m is None and est.nis is None and obs.noise() is None
    assert obs.covariance is None and obs.reacquisitions == 0
    restored = BiasObserver.from_dict(json.loads(json.dumps(obs.to_dict())))
    assert restored.estimator.output(None).x_m == pytest.approx([2.0, 10.0, 0.0])  # type: ignore[arg-type]
    with pytest.raises(StateError, match="paper's observer, this one is dead_reckoning"):
        _ = obs.m_s


def test_the_first_estimate_after_the_start_is_the_estimators_not_a_stale_one() -> None:
    # a bearing before any velocity: an estimate before the start, then the start
    obs = BiasObserver(ObserverConfig(initial_range_m=20.0))
    before = obs.update_bearing(BearingSample(0.0, [0.6, 0.0, 0.8]))
    assert before.status.value == "stale" or not obs.started
    obs.update_velocity(VelocitySample(0.0, [0.0, 0.0, 0.0]))
    est = obs.predict(0.0)
    assert obs.started
    assert est.range_m == pytest.approx(20.0, rel=1e-6)
    assert est.x_m.tolist() == pytest.approx([12.0, 0.0, 16.0], rel=1e-6)


def test_with_its_latency_learnt_nothing_is_converged_before_the_latency_settles() -> None:
    """The riccati estimator with ``bearing_latency_s = "auto"`` is not ``settled`` until its
    latency has settled once, and no estimate is ``converged`` before; the flag is kept
    across a restart. Told a latency, it is settled from the start (and converges)."""
    obs = BiasObserver(ObserverConfig())
    _feed(obs, duration_s=50.0)
    assert not obs.estimator.settled
    assert obs.status is Status.CONVERGING
    told = BiasObserver(ObserverConfig(bearing_latency_s=0.0))
    assert told.estimator.settled
    _feed(told, duration_s=50.0)
    assert told.status is Status.CONVERGED  # (from 27 s on)
    later = BiasObserver(ObserverConfig())
    _feed(later, duration_s=90.0)
    assert later.estimator.settled and later.status is Status.CONVERGED  # (from 60 s on)
    d = json.loads(json.dumps(obs.to_dict()))
    assert d["latency_settled"] is False
    assert not BiasObserver.from_dict(d).estimator.settled
    d["latency_settled"] = True
    assert BiasObserver.from_dict(d).estimator.settled
    del d["latency_settled"]  # a state saved before the flag: a started estimator keeps its status
    assert BiasObserver.from_dict(d).estimator.settled
    d["latency_settled"] = "yes"
    with pytest.raises(StateError, match="latency_settled"):
        BiasObserver.from_dict(d)


def test_an_estimate_never_certain_enough_to_learn_its_latency_is_settled_90_s_on() -> None:
    """8 deg bearings at 2 Hz on a slow orbit: the estimate never comes within 5 % of its
    range, so its latency never starts learning; 90 s after the bank's (last) seeding the
    estimator counts as settled (a lag's error is within its sigma), so the status can still
    say converged once the corrections are small. Before that, it is not settled."""
    from sim.stream import Noise

    def run(duration_s: float) -> BiasObserver:
        obs = BiasObserver(ObserverConfig())
        sc = scenarios.orbit(radius_m=5.0, lap_s=200.0, duration_s=duration_s)
        stream = generate(sc, noise=Noise(bearing_sigma_deg=8.0), bearing_rate_hz=2.0)
        for ev in stream.events():
            if isinstance(ev, BearingSample):
                obs.update_bearing(ev)
            else:
                obs.update_velocity(ev)
        return obs

    early, late = run(60.0), run(200.0)
    assert early.estimator.latency.t0_s is None and not early.estimator.settled
    assert late.estimator.latency.t0_s is None and late.estimator.settled
