"""Excitation window and status rules."""

import numpy as np
import pytest

from mav_observer.errors import StateError
from mav_observer.monitor import ExcitationWindow, MonitorThresholds, StatusMemory, next_status
from mav_observer.samples import Status

TH = MonitorThresholds(
    max_bearing_age_s=1.0,
    max_velocity_age_s=1.0,
    window_s=10.0,
    window_full_s=9.5,
    excitation_min=0.01,
    converged_tol=0.02,
)


def _held(win: ExcitationWindow, t0: float, t1: float, y) -> None:
    """Account a bearing ``y`` (or none) held over ``[t0, t1]``."""
    if y is None:
        win.add_interval(t0, t1, None, 0.0)
    else:
        y = np.asarray(y, dtype=float)
        win.add_interval(t0, t1, (np.outer(y, y) * (t1 - t0)).ravel().tolist(), t1 - t0)


def _feed(win: ExcitationWindow, ys, t0: float, dt: float) -> float:
    t = t0
    for y in ys:
        _held(win, t, t + dt, y)
        t += dt
    return t


def test_constant_bearing_has_no_excitation() -> None:
    win = ExcitationWindow(3, 10.0, 20)
    _feed(win, [np.array([0.0, 0.0, 1.0])] * 400, 0.0, 0.05)
    assert win.excitation() == pytest.approx(0.0, abs=1e-12)
    assert win.covered_s() == pytest.approx(10.0, rel=0.06)


def test_bearing_sweeping_a_circle_gives_one_half() -> None:
    # y spins uniformly in the x-y plane: mean(Pi_y) = diag(1/2, 1/2, 1)
    win = ExcitationWindow(3, 10.0, 20)
    # one turn per 0.1 s (10 samples a turn), so any window holds whole turns to 1 %
    th = np.linspace(0.0, 800 * np.pi, 4000, endpoint=False)
    ys = [np.array([np.cos(a), np.sin(a), 0.0]) for a in th]
    _feed(win, ys, 0.0, 0.01)
    assert win.excitation() == pytest.approx(0.5, abs=5e-3)


def test_time_without_bearing_counts_as_no_excitation() -> None:
    win = ExcitationWindow(3, 10.0, 20)
    th = np.linspace(0.0, 10 * np.pi, 500, endpoint=False)
    t = _feed(win, [np.array([np.cos(a), np.sin(a), 0.0]) for a in th], 0.0, 0.01)
    full = win.excitation()
    _feed(win, [None] * 500, t, 0.01)
    assert win.excitation() == pytest.approx(full / 2.0, rel=0.02)


def test_window_forgets_old_data_and_stays_bounded() -> None:
    win = ExcitationWindow(3, 10.0, 20)
    th = np.linspace(0.0, 10 * np.pi, 1000, endpoint=False)
    t = _feed(win, [np.array([np.cos(a), np.sin(a), 0.0]) for a in th], 0.0, 0.01)
    assert win.excitation() > 0.4
    _feed(win, [np.array([1.0, 0.0, 0.0])] * 5000, t, 0.01)  # 50 s of a still bearing
    assert win.excitation() == pytest.approx(0.0, abs=1e-9)
    assert len(win.to_dict()["idx"]) <= 21


def test_long_interval_spans_buckets() -> None:
    win = ExcitationWindow(2, 10.0, 10)
    _held(win, 0.0, 60.0, [1.0, 0.0])
    assert win.covered_s() == pytest.approx(10.0, abs=1.0)
    assert win.excitation() == pytest.approx(0.0, abs=1e-12)


def test_correction_indicator_and_round_trip() -> None:
    win = ExcitationWindow(3, 10.0, 20)
    _held(win, 0.0, 5.0, [0.0, 0.0, 1.0])
    win.add_correction(5.0, np.array([0.3, 0.4, 0.0]), np.array([0.0, 0.0, 0.01]))
    assert win.correction_rel(10.0) == pytest.approx((0.5 + 5.0 * 0.01) / 10.0)
    again = ExcitationWindow.from_dict(3, win.to_dict())
    assert again.to_dict() == win.to_dict()
    assert again.correction_rel(10.0) == win.correction_rel(10.0)


def test_malformed_window_state_is_refused() -> None:
    d = ExcitationWindow(3, 10.0, 20).to_dict()
    d["idx"] = [1, 2]
    with pytest.raises(StateError, match="differ in length"):
        ExcitationWindow.from_dict(3, d)
    with pytest.raises(StateError, match="malformed"):
        ExcitationWindow.from_dict(3, {"window_s": 1.0})


def _status(mem: StatusMemory, **kw) -> StatusMemory:
    args = dict(
        t_s=100.0,
        started=True,
        bearing_age_s=0.0,
        velocity_age_s=0.0,
        excitation=0.2,
        covered_s=10.0,
        correction_rel=0.001,
        th=TH,
    )
    args.update(kw)
    return next_status(mem, **args)


def test_status_stale_rules() -> None:
    m = StatusMemory(Status.CONVERGED, 0.0)
    assert _status(m, started=False).status is Status.STALE
    assert _status(m, bearing_age_s=1.5).status is Status.STALE
    assert _status(m, velocity_age_s=1.5).status is Status.STALE
    assert _status(m, bearing_age_s=None).status is Status.STALE
    assert _status(m, bearing_age_s=1.0).status is Status.CONVERGED


def test_status_not_observable_with_hysteresis() -> None:
    m = StatusMemory(Status.CONVERGED, 0.0)
    low = _status(m, excitation=0.005)
    assert low.status is Status.NOT_OBSERVABLE and low.observable_since_s is None
    # not yet full window: no verdict on observability
    assert _status(StatusMemory(), excitation=0.0, covered_s=5.0).status is Status.CONVERGING
    # leaving needs twice the threshold
    assert _status(low, excitation=0.015).status is Status.NOT_OBSERVABLE
    back = _status(low, excitation=0.025, t_s=200.0)
    assert back.status is Status.CONVERGING and back.observable_since_s == 200.0


def test_status_converged_needs_a_window_of_observability_and_small_corrections() -> None:
    m = _status(StatusMemory(Status.NOT_OBSERVABLE, None), t_s=50.0, excitation=0.3)
    assert m.status is Status.CONVERGING
    m = _status(m, t_s=55.0)
    assert m.status is Status.CONVERGING  # only 5 s of a 10 s window
    m = _status(m, t_s=60.0)
    assert m.status is Status.CONVERGED
    assert _status(m, t_s=61.0, correction_rel=0.03).status is Status.CONVERGED  # hysteresis
    assert _status(m, t_s=61.0, correction_rel=0.05).status is Status.CONVERGING


def test_status_converged_needs_the_estimator_settled() -> None:
    """What the estimator still learns (a gimbal's latency) holds ``converged`` back, and
    leaving it unsettled leaves ``converged``."""
    m = _status(StatusMemory(Status.CONVERGING, 0.0), t_s=60.0, settled=False)
    assert m.status is Status.CONVERGING and m.observable_since_s == 0.0
    m = _status(m, t_s=61.0, settled=True)
    assert m.status is Status.CONVERGED
    assert _status(m, t_s=62.0, settled=False).status is Status.CONVERGING
