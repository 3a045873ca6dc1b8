"""One observer's state as the compiled core keeps it (mav_observer/core/state.py and
kernels/layout.py): the layout's blocks do not overlap, the settings reach the kernels in
order, a saved state restores exactly, a prediction leaves the committed state alone."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer import BiasObserver, ObserverConfig
from mav_observer.core import state as state_mod
from mav_observer.core.config import BankParams
from mav_observer.core.kernels import layout as L
from sim import scenarios
from sim.stream import Noise, generate

CONSTANTS = {k: v for k, v in vars(L).items() if k.isupper() and isinstance(v, int | float)}


def _named(prefix: str, *, exclude: tuple[str, ...] = ()) -> dict[str, int]:
    out = {k: v for k, v in CONSTANTS.items() if k.startswith(prefix) and k not in exclude}
    assert out, prefix
    return out


def _disjoint(blocks: dict[str, tuple[int, int]]) -> None:
    """The half-open ranges do not overlap."""
    spans = sorted((a, b, name) for name, (a, b) in blocks.items())
    for (a0, b0, n0), (a1, b1, n1) in itertools.pairwise(spans):
        assert a0 < b0 and a1 < b1, (n0, n1)
        assert b0 <= a1, f"{n0} [{a0}, {b0}) overlaps {n1} [{a1}, {b1})"


def _fits(prefix: str, count: int, *, widths: dict[str, int] | None = None, exclude=()) -> None:
    """Each index of the block (a few are runs of ``widths``) within ``[0, count)``, none
    sharing a slot."""
    widths = widths or {}
    named = _named(prefix, exclude=(f"{prefix}COUNT", *exclude))
    _disjoint({k: (v, v + widths.get(k, 1)) for k, v in named.items()})
    assert all(v >= 0 and v + widths.get(k, 1) <= count for k, v in named.items()), named


@pytest.mark.parametrize("hypotheses", [1, 7, 31])
def test_the_scalar_blocks_do_not_overlap(hypotheses: int) -> None:
    """``s``: the observer's scalars, then the blocks of its parts, each laid out by its own
    constants within its size, the hypotheses' log weights last to the end of the array."""
    _fits("Q_", L.Q_COUNT)
    _fits("B_", L.B_COUNT)
    _fits("L_", L.L_COUNT)
    _fits("T_", L.T_COUNT)
    _fits("V_", L.V_COUNT, widths={"V_T": 4})  # (the latest four samples' times)
    _fits("W_", L.W_COUNT)
    scalars = _named("S_")
    first = min(v for k, v in CONSTANTS.items() if k.startswith("OFF_"))
    _fits("S_", first)
    blocks = {
        "S": (0, max(scalars.values()) + 1),
        "OFF_Q": (L.OFF_Q, L.OFF_Q + L.Q_COUNT),
        "OFF_BS": (L.OFF_BS, L.OFF_BS + L.B_COUNT),
        "OFF_LAT": (L.OFF_LAT, L.OFF_LAT + L.L_COUNT),
        "OFF_SET": (L.OFF_SET, L.OFF_SET + L.T_COUNT),
        "OFF_WH": (L.OFF_WH, L.OFF_WH + L.W_COUNT),
        "OFF_VN": (L.OFF_VN, L.OFF_VN + L.V_COUNT),
        "OFF_LOGW": (L.OFF_LOGW, L.OFF_LOGW + hypotheses),
    }
    assert set(_named("OFF_")) == set(blocks) - {"S"}  # (every block is here)
    _disjoint(blocks)
    st_ = state_mod.new_state(ObserverConfig(hypotheses=hypotheses))
    assert st_.s.shape == (max(b for _, b in blocks.values()),)


def test_the_settings_and_the_other_arrays_blocks_do_not_overlap() -> None:
    """``cfg``: the observer's settings below the arrays' table, the table (an offset and
    three dimensions per array) below the bank's settings; ``vec``'s rows; ``out``'s
    columns; the sample buffers' and the window's columns; the statuses and return codes
    distinct."""
    _fits("O_", L.O_ARRAYS, exclude=("O_ARRAYS", "O_BANK"))
    assert L.O_ARRAYS + 4 * L.A_COUNT <= L.O_BANK
    _fits("A_", L.A_COUNT)
    _fits("P_", L.P_COUNT)
    _fits("R_", L.R_FIXED, widths={"R_VN": 4}, exclude=("R_FIXED", "R_M"))
    assert L.R_M == L.R_FIXED  # (M's n rows after the fixed ones)
    n = 3
    _fits("E_", L.E_FIXED + 4 * n, widths={"E_X": 4 * n}, exclude=("E_FIXED",))
    assert L.E_X == L.E_FIXED  # (x, a and their standard deviations after the fixed ones)
    _fits("VB_", 2 + 2 * n, widths={"VB_V": 2 * n})
    _fits("C_", 3 + n * n + 2 * n, widths={"C_YY": n * n + 2 * n})
    statuses = [L.STALE, L.NOT_OBSERVABLE, L.CONVERGING, L.CONVERGED]
    assert sorted(statuses) == list(range(4))
    errors = list(_named("ERR_").values())
    assert len(set(errors)) == len(errors) and max(errors) < 0
    assert L.KIND_BANK != L.KIND_PAPER


@pytest.mark.parametrize("estimator", ["riccati", "paper"])
def test_the_arrays_tile_one_buffer_as_the_table_says(estimator: str) -> None:
    """Each array a view of the buffer where its row of the table puts it, of its shape,
    none overlapping another, together the whole buffer."""
    cfg = ObserverConfig(estimator=estimator, hypotheses=5, window_buckets=8, max_buffer=16)
    st_ = state_mod.new_state(cfg)
    names = ("cfg", "s", "vec", "fs", "fp", "vbuf", "bbuf", "win", "out", "wk")
    assert len(names) == L.A_COUNT
    spans = {}
    for a, name in enumerate(names):
        arr = getattr(st_, name)
        o = L.O_ARRAYS + 4 * a
        at = int(st_.cfg[o])
        dims = tuple(int(d) for d in st_.cfg[o + 1 : o + 1 + arr.ndim])
        assert dims == arr.shape, name
        assert np.shares_memory(arr, st_.buf) and arr.flags.c_contiguous
        assert arr.__array_interface__["data"][0] == st_.buf[at:].__array_interface__["data"][0]
        spans[name] = (at, at + arr.size)
    _disjoint(spans)
    assert sum(b - a for a, b in spans.values()) == st_.buf.size
    assert st_.fs.shape == (5 + 3, 6) and st_.win.shape == (8 + 2, 3 + 9 + 6)
    assert st_.vbuf.shape == (19, 2 + 6) and st_.bbuf.shape == (19, 3 + 3)


def test_the_settings_reach_the_kernels_where_the_layout_says() -> None:
    cfg = ObserverConfig(
        n=4,
        estimator="paper",
        mode="bias_free",
        interpolation="hold",
        max_bearing_age_s=1.5,
        max_velocity_age_s=2.5,
        max_buffer=64,
        window_s=30.0,
        window_buckets=15,
        excitation_min=0.03,
        converged_tol=0.04,
        k_per_s=0.7,
        k_star_per_s=0.9,
        static_hold=False,
        initial_range_m=33.0,
        velocity_noise_mps=0.07,
        bearing_latency_s=0.02,
    )
    c = state_mod.config_array(cfg, committed=True)
    assert c[L.O_N] == 4 and c[L.O_KIND] == L.KIND_PAPER
    assert c[L.O_BIASED] == 0.0 and c[L.O_LINEAR] == 0.0 and c[L.O_STATIC_HOLD] == 0.0
    assert (c[L.O_MAX_BEARING_AGE_S], c[L.O_MAX_VELOCITY_AGE_S], c[L.O_MAX_BUFFER]) == (
        1.5,
        2.5,
        64,
    )
    assert (c[L.O_WINDOW_S], c[L.O_BUCKET_S], c[L.O_WINDOW_FULL_S]) == (30.0, 2.0, 28.0)
    assert (c[L.O_EXCITATION_MIN], c[L.O_CONVERGED_TOL]) == (0.03, 0.04)
    assert (c[L.O_K], c[L.O_K_STAR], c[L.O_INITIAL_RANGE_M]) == (0.7, 0.9, 33.0)
    assert (c[L.O_VELOCITY_NOISE_MPS], c[L.O_LATENCY_S], c[L.O_COMMITTED]) == (0.07, 0.02, 1.0)
    auto = state_mod.config_array(ObserverConfig(), committed=False)
    assert math.isnan(auto[L.O_VELOCITY_NOISE_MPS]) and math.isnan(auto[L.O_LATENCY_S])
    assert math.isnan(auto[L.O_INITIAL_RANGE_M]) and auto[L.O_KIND] == L.KIND_BANK
    np.testing.assert_array_equal(auto[L.O_BANK :], ObserverConfig().bank_params().to_array())


def test_bank_params_reach_the_kernels_in_the_order_of_the_p_indices() -> None:
    """``BankParams.to_array`` puts every field at its ``P_*`` index (``bias_std_mps`` at
    ``P_BIAS_STD``), one field per index."""
    names = [f.name for f in fields(BankParams)]
    assert len(names) == L.P_COUNT
    prm = BankParams(**{name: float(i + 1) for i, name in enumerate(names)})
    arr = prm.to_array()
    assert arr.shape == (L.P_COUNT,)
    for name in names:
        index = getattr(L, "P_" + name.upper().removesuffix("_MPS"))
        assert arr[index] == getattr(prm, name), name


def _arrays_equal(a, b) -> bool:
    return all(
        np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True)
        for k in ("cfg", *state_mod.SAVED)
    )


def _drive(obs: BiasObserver, events) -> None:
    for ev in events:
        if hasattr(ev, "y"):
            obs.add_bearing_values(ev.t_s, ev.y.tolist())
        else:
            obs.update_velocity_values(ev.t_s, ev.v_mps.tolist())


@pytest.mark.parametrize("estimator", ["riccati", "paper"])
def test_a_saved_state_restores_exactly_and_continues_bit_identically(estimator: str) -> None:
    """Saved mid-run through JSON: every array back bit for bit (NaN where NaN), and both
    observers fed the rest of the stream end bit-identical."""
    events = list(
        generate(
            scenarios.orbit(duration_s=40.0),
            noise=Noise(bearing_sigma_deg=1.0, velocity_sigma_mps=0.05),
        ).events()
    )
    cut = len(events) // 2
    obs = BiasObserver(ObserverConfig(estimator=estimator))
    _drive(obs, events[:cut])
    d = json.loads(json.dumps(obs.to_dict()))
    restored = BiasObserver.from_dict(d)
    assert _arrays_equal(obs._st, restored._st)
    assert np.isnan(restored._st.s[L.OFF_LAT + L.L_T0]) == np.isnan(obs._st.s[L.OFF_LAT + L.L_T0])
    _drive(obs, events[cut:])
    _drive(restored, events[cut:])
    assert _arrays_equal(obs._st, restored._st)
    assert np.array_equal(obs.x_m, restored.x_m)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 12))
def test_the_velocity_noise_saved_at_any_point_continues_the_same(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    a = BiasObserver()
    t = np.cumsum(rng.uniform(0.05, 0.15, n))
    for tk in t:
        a.update_velocity_values(float(tk), rng.normal(0.0, 0.1, 3).tolist())
    b = BiasObserver.from_dict(json.loads(json.dumps(a.to_dict())))
    more_t = float(t[-1] + 0.1) if n else 0.1
    more_v = rng.normal(0.0, 0.1, 3).tolist()
    a.update_velocity_values(more_t, more_v)
    b.update_velocity_values(more_t, more_v)
    va, vb = a.noise().velocity_noise_mps, b.noise().velocity_noise_mps  # type: ignore[union-attr]
    assert va == vb and math.isfinite(va)


@pytest.mark.parametrize("estimator", ["riccati", "paper"])
def test_a_prediction_leaves_the_committed_state_as_it_was(estimator: str) -> None:
    """An estimate predicted far ahead is not committed: the estimator's state, the streams
    and the window are as they were, and the observer goes on exactly as one that never
    predicted."""
    events = list(
        generate(scenarios.orbit(duration_s=20.0), noise=Noise(bearing_sigma_deg=1.0)).events()
    )
    cut = len(events) // 2
    obs, other = BiasObserver(ObserverConfig(estimator=estimator)), None
    _drive(obs, events[:cut])
    other = BiasObserver.from_dict(obs.to_dict())
    before = {k: getattr(obs._st, k).copy() for k in ("vec", "fs", "fp", "vbuf", "bbuf", "win")}
    x0 = obs.x_m
    t_c = obs.committed_t_s
    est = obs.predict(t_c + 30.0)
    assert est.t_s == t_c + 30.0 and not np.allclose(est.x_m, x0)
    assert obs.committed_t_s == t_c and obs.x_m == x0
    for k, arr in before.items():
        assert np.array_equal(getattr(obs._st, k), arr, equal_nan=True), k
    _drive(obs, events[cut:])
    _drive(other, events[cut:])
    assert obs.x_m == other.x_m and obs.a_mps == other.a_mps
