"""The innovations' lag-1 correlation (mav_observer.whiteness)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.errors import ConfigError
from mav_observer.whiteness import MIN_PAIRS, WARN_LAG1, WARN_VAR_RATIO, InnovationCorrelation


def _feed(ic: InnovationCorrelation, e: np.ndarray, dt_s: float, t0_s: float = 0.0) -> None:
    for k, v in enumerate(e):
        ic.add(t0_s + k * dt_s, v.tolist())


def _ar1(rng: np.random.Generator, n: int, phi: float, sd: float = 0.01) -> np.ndarray:
    """``n`` tangent vectors (3 components, the third 0) of an AR(1) error, lag-1 ``phi``."""
    e = np.zeros((n, 3))
    w = rng.normal(0.0, sd * math.sqrt(1.0 - phi * phi), (n, 2))
    e[0, :2] = rng.normal(0.0, sd, 2)
    for k in range(1, n):
        e[k, :2] = phi * e[k - 1, :2] + w[k]
    return e


def test_white_errors_read_near_zero_and_their_size() -> None:
    rng = np.random.default_rng(1)
    ic = InnovationCorrelation(memory_s=60.0)
    z = np.zeros((3000, 3))
    z[:, :2] = rng.normal(0.0, 1.0, (3000, 2))  # as large as the noise in use
    _feed(ic, z, 0.1)
    c = ic.correlation()
    assert c is not None and abs(c.lag1) < 0.06 and not c.systematic
    assert c.var_ratio == pytest.approx(1.0, abs=0.15)
    assert c.pairs == pytest.approx(600.0, rel=0.05)  # 60 s of memory at 10 Hz


@pytest.mark.parametrize(
    ("phi", "sd", "systematic"),
    [(0.9, 1.0, True), (0.9, 0.1, False), (0.2, 1.0, False)],
)
def test_systematic_means_correlated_and_not_small(phi: float, sd: float, systematic: bool) -> None:
    """Correlated innovations as large as the noise in use are systematic errors; correlated
    ones far below it (noise-free bearings under the noise's floor) are covered by it."""
    ic = InnovationCorrelation()
    _feed(ic, _ar1(np.random.default_rng(5), 3000, phi, sd), 0.1)
    c = ic.correlation()
    assert c is not None
    assert (c.lag1 >= WARN_LAG1) == (phi > 0.5)
    assert (c.var_ratio >= WARN_VAR_RATIO) == (sd > 0.5)
    assert c.systematic is systematic


@pytest.mark.parametrize("phi", [0.5, 0.9, 0.98])
def test_an_ar1_error_reads_its_correlation_and_time(phi: float) -> None:
    rng = np.random.default_rng(2)
    ic = InnovationCorrelation(memory_s=600.0)
    _feed(ic, _ar1(rng, 20000, phi), 0.05)
    c = ic.correlation()
    assert c is not None and c.lag1 == pytest.approx(phi, abs=0.03)
    tau_s = -0.05 / math.log(phi)
    assert c.corr_time_s == pytest.approx(tau_s, rel=0.5)


def test_nothing_is_said_from_too_few_pairs_and_a_gap_is_not_a_pair() -> None:
    ic = InnovationCorrelation(memory_s=1e9)  # (no forgetting: the pairs counted whole)
    e = np.full((int(MIN_PAIRS), 3), 0.01)
    _feed(ic, e, 0.1)
    assert ic.correlation() is None  # MIN_PAIRS - 1 pairs
    ic.gap()
    ic.add(100.0, [0.01, 0.0, 0.0])  # after the gap: kept, not compared
    assert ic.correlation() is None
    ic.add(100.1, [0.01, 0.0, 0.0])
    ic.add(100.2, [0.01, 0.0, 0.0])  # 29 pairs (minus a hair of forgetting) + 2
    c = ic.correlation()
    assert c is not None and c.pairs == pytest.approx(MIN_PAIRS + 1.0)
    forgets = InnovationCorrelation(memory_s=10.0)
    _feed(forgets, np.full((100, 3), 0.01), 0.1)
    assert forgets.correlation() is not None
    forgets.add(200.0, [0.01, 0.0, 0.0])  # 190 s later: what was summed is forgotten
    forgets.add(200.1, [0.01, 0.0, 0.0])
    assert forgets.correlation() is None
    late = InnovationCorrelation()
    for k in range(100):  # bearings 3 s apart (a dropout each): never compared
        late.add(3.0 * k, [0.01, 0.0, 0.0])
    assert late.correlation() is None


def test_a_gross_error_is_left_out() -> None:
    rng = np.random.default_rng(3)
    e = rng.normal(0.0, 0.01, (2000, 3))
    clean = InnovationCorrelation()
    _feed(clean, e, 0.1)
    e[1000:1003] = 1.0  # three in a row, 100 times the noise: would read as correlated
    hit = InnovationCorrelation()
    _feed(hit, e, 0.1)
    assert abs(hit.correlation().lag1 - clean.correlation().lag1) < 0.02  # type: ignore[union-attr]
    ic = InnovationCorrelation()
    _feed(ic, e[:100], 0.1)
    ic.add(10.0, [math.nan, 0.0, 0.0])  # not finite: dropped, no pair
    assert abs(ic.correlation().lag1) < 0.3  # type: ignore[union-attr]


def test_a_copy_is_independent() -> None:
    rng = np.random.default_rng(4)
    ic = InnovationCorrelation()
    _feed(ic, rng.normal(0.0, 0.01, (200, 3)), 0.1)
    before = ic.correlation()
    other = ic.copy()
    _feed(other, np.full((500, 3), 0.02), 0.1, t0_s=20.0)  # constant: correlation 1
    assert other.correlation().lag1 > 0.9  # type: ignore[union-attr]
    assert ic.correlation() == before


@pytest.mark.parametrize("memory_s", [0.0, -1.0, math.inf, math.nan])
def test_a_bad_memory_is_refused_by_name(memory_s: float) -> None:
    with pytest.raises(ConfigError, match="memory_s must be finite and > 0"):
        InnovationCorrelation(memory_s=memory_s)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3), min_size=40, max_size=200),
    st.floats(0.01, 1.0),
)
def test_the_correlation_is_within_minus_one_and_one(vectors, dt_s: float) -> None:
    ic = InnovationCorrelation()
    for k, v in enumerate(vectors):
        ic.add(k * dt_s, v)
    c = ic.correlation()
    if c is not None:  # (all-zero vectors give none)
        assert -1.0 <= c.lag1 <= 1.0
        assert c.corr_time_s is None or c.corr_time_s > 0.0
