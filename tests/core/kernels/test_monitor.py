"""The monitor (mav_observer/core/kernels/monitor.py): the excitation over its sliding
window, the correction indicator, and the status rules."""

from __future__ import annotations

import math

import kernel_calls as kc
import numpy as np
import pytest

from mav_observer.core.kernels.layout import CONVERGED, CONVERGING, NOT_OBSERVABLE, STALE

TH = {
    "max_bearing_age_s": 1.0,
    "max_velocity_age_s": 1.0,
    "window_s": 10.0,
    "window_full_s": 9.5,
    "excitation_min": 0.01,
    "converged_tol": 0.02,
}


def _feed(win: kc.Window, ys, t0: float, dt: float) -> float:
    t = t0
    for y in ys:
        win.held(t, t + dt, y)
        t += dt
    return t


def _circle(turns: float, samples: int) -> list[np.ndarray]:
    th = np.linspace(0.0, 2.0 * np.pi * turns, samples, endpoint=False)
    return [np.array([np.cos(a), np.sin(a), 0.0]) for a in th]


def test_a_constant_bearing_has_no_excitation() -> None:
    win = kc.Window(3, 10.0, 20)
    assert win.excitation() == 0.0 and win.covered_s() == 0.0  # (no data)
    _feed(win, [np.array([0.0, 0.0, 1.0])] * 400, 0.0, 0.05)
    assert win.excitation() == pytest.approx(0.0, abs=1e-12)
    assert win.covered_s() == pytest.approx(10.0, rel=0.06)


def test_a_bearing_sweeping_a_circle_gives_one_half() -> None:
    """``y`` spins uniformly in the x-y plane: the mean of ``Pi_y`` is diag(1/2, 1/2, 1)."""
    win = kc.Window(3, 10.0, 20)
    _feed(win, _circle(400, 4000), 0.0, 0.01)  # 10 samples a turn: whole turns to 1 %
    assert win.excitation() == pytest.approx(0.5, abs=5e-3)


def test_time_without_a_bearing_counts_as_no_excitation() -> None:
    win = kc.Window(3, 10.0, 20)
    t = _feed(win, _circle(5, 500), 0.0, 0.01)
    full = win.excitation()
    _feed(win, [None] * 500, t, 0.01)
    assert win.excitation() == pytest.approx(full / 2.0, rel=0.02)


def test_the_window_forgets_old_data_and_stays_bounded() -> None:
    win = kc.Window(3, 10.0, 20)
    t = _feed(win, _circle(5, 1000), 0.0, 0.01)
    assert win.excitation() > 0.4
    _feed(win, [np.array([1.0, 0.0, 0.0])] * 5000, t, 0.01)  # 50 s of a still bearing
    assert win.excitation() == pytest.approx(0.0, abs=1e-9)
    assert win.buckets_in_use <= 20
    assert win.covered_s() == pytest.approx(10.0, rel=0.06)


def test_a_long_interval_spans_buckets() -> None:
    win = kc.Window(2, 10.0, 10)
    win.held(0.0, 60.0, [1.0, 0.0])
    assert win.covered_s() == pytest.approx(10.0, abs=1.0)
    assert win.excitation() == pytest.approx(0.0, abs=1e-12)
    win.held(60.0, 65.0, [0.0, 1.0])  # half of it the other axis: mean Pi_y = I / 2
    assert win.excitation() == pytest.approx(0.5, abs=0.05)


def test_the_correction_indicator() -> None:
    """``(|sum dx| + covered * |sum da|) / range`` over the window."""
    win = kc.Window(3, 10.0, 20)
    win.held(0.0, 5.0, [0.0, 0.0, 1.0])
    win.add_correction(5.0, [0.3, 0.4, 0.0], [0.0, 0.0, 0.01])
    assert win.correction_rel(10.0) == pytest.approx((0.5 + 5.0 * 0.01) / 10.0)
    win.add_correction(5.0, [-0.3, -0.4, 0.0], [0.0, 0.0, -0.01])  # undone: nothing net
    assert win.correction_rel(10.0) == pytest.approx(0.0, abs=1e-15)
    win.add_correction(4.0, [1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    win.held(5.0, 40.0, [0.0, 0.0, 1.0])  # long gone from the window
    assert win.correction_rel(10.0) == pytest.approx(0.0, abs=1e-15)


def _status(status: int, since: float, **kw) -> tuple[int, float]:
    args = {
        "t": 100.0,
        "started": True,
        "b_age": 0.0,
        "v_age": 0.0,
        "exc": 0.2,
        "covered": 10.0,
        "corr": 0.001,
        "settled": True,
        **TH,
    }
    args.update(kw)
    t = args.pop("t")
    return kc.next_status(status, since, t, **args)


def test_status_stale_rules() -> None:
    """Not started, or a stream older than its maximum age (or none yet): stale."""
    m = (CONVERGED, 0.0)
    assert _status(*m, started=False)[0] == STALE
    assert _status(*m, b_age=1.5)[0] == STALE
    assert _status(*m, v_age=1.5)[0] == STALE
    assert _status(*m, b_age=math.nan)[0] == STALE
    assert _status(*m, v_age=math.nan)[0] == STALE
    assert math.isnan(_status(*m, b_age=1.5)[1])
    assert _status(*m, b_age=1.0) == (CONVERGED, 0.0)


def test_status_not_observable_with_hysteresis() -> None:
    low = _status(CONVERGED, 0.0, exc=0.005)
    assert low[0] == NOT_OBSERVABLE and math.isnan(low[1])
    # a window not yet full: no verdict on observability
    assert _status(STALE, math.nan, exc=0.0, covered=5.0)[0] == CONVERGING
    assert _status(*low, exc=0.015)[0] == NOT_OBSERVABLE  # leaving takes twice the threshold
    assert _status(*low, exc=0.025, t=200.0) == (CONVERGING, 200.0)


def test_status_converged_needs_a_window_of_observability_and_small_corrections() -> None:
    m = _status(NOT_OBSERVABLE, math.nan, t=50.0, exc=0.3)
    assert m == (CONVERGING, 50.0)
    m = _status(*m, t=55.0)
    assert m == (CONVERGING, 50.0)  # only 5 s of a 10 s window
    m = _status(*m, t=60.0)
    assert m == (CONVERGED, 50.0)
    assert _status(*m, t=61.0, corr=0.03)[0] == CONVERGED  # leaving takes twice the tolerance
    assert _status(*m, t=61.0, corr=0.05) == (CONVERGING, 50.0)
    assert _status(CONVERGING, 50.0, t=61.0, corr=0.03)[0] == CONVERGING


def test_status_converged_needs_the_estimator_settled() -> None:
    """What the estimator still learns (a gimbal's latency) holds ``converged`` back, and
    leaving it unsettled leaves ``converged``."""
    m = _status(CONVERGING, 0.0, t=60.0, settled=False)
    assert m == (CONVERGING, 0.0)
    m = _status(*m, t=61.0)
    assert m[0] == CONVERGED
    assert _status(*m, t=62.0, settled=False)[0] == CONVERGING


def test_status_converged_needs_its_own_sigma_small() -> None:
    """Still corrections, but a position sigma over 5 % of the range (a geometry that does
    not determine the range): converging; at 4 %: converged; once converged it holds to
    10 %."""
    assert _status(CONVERGING, 0.0, sd_rel=0.08)[0] == CONVERGING
    assert _status(CONVERGING, 0.0, sd_rel=0.04)[0] == CONVERGED
    assert _status(CONVERGED, 0.0, sd_rel=0.08)[0] == CONVERGED
    assert _status(CONVERGED, 0.0, sd_rel=0.12)[0] == CONVERGING


def test_a_measured_range_converges_on_the_sigma_alone_without_motion() -> None:
    """With a range measured with a recent bearing the position is observed without motion:
    no excitation, no window, still corrections, a latency not settled: converged once its
    sigma is within 5 % of the range (10 % to stay); a stale stream is still stale."""
    still = {"exc": 0.0, "covered": 10.0, "corr": 0.5, "settled": False, "ranged": True}
    assert _status(STALE, math.nan, t=0.1, sd_rel=0.02, **still) == (CONVERGED, 0.1)
    assert _status(CONVERGING, 0.0, sd_rel=0.08, **still)[0] == CONVERGING
    assert _status(CONVERGED, 0.0, sd_rel=0.08, **still)[0] == CONVERGED
    assert _status(CONVERGED, 0.0, sd_rel=0.02, b_age=5.0, **still)[0] == STALE
    assert _status(CONVERGED, 0.0, sd_rel=0.02, **{**still, "ranged": False})[0] == NOT_OBSERVABLE
