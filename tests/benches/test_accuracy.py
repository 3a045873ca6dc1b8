"""The accuracy harness (bench/accuracy): its CRLB, its metrics, and that the batched riccati
path is the service's estimator."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.accuracy import cli, core, estimators, run  # noqa: E402
from sim import scenarios  # noqa: E402


def _truth(name: str, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
    sc = scenarios.make(name)
    t = np.arange(0.0, duration_s + 1e-9, 0.05)
    return t, sc.x(t)


def _measurement_info(x: np.ndarray, sigma: float) -> np.ndarray:
    """H_k^T H_k / sigma^2 on the position block (T, n, n)."""
    r = np.linalg.norm(x, axis=1)
    # an orthonormal basis of the plane orthogonal to each bearing, from an SVD (independent
    # of the harness's projection form)
    e = np.stack([np.linalg.svd(u[None, :])[2][1:].T for u in x / r[:, None]])
    return np.einsum("tij,tkj->tik", e, e) / (r[:, None, None] ** 2 * sigma**2)


def test_crlb_matches_the_batch_fisher_information() -> None:
    """Without process noise the recursion equals the batch information of the initial state
    ``J0 = prior + sum_k Phi_k^T H_k^T H_k Phi_k / sigma^2`` carried to time ``t_k``."""
    t, x = _truth("orbit", 10.0)
    sigma = math.radians(0.5)
    prior = 1e-9
    bound = core.crlb(t, x, sigma, 0.0, prior_info=prior)
    n = x.shape[1]
    info = _measurement_info(x, sigma)
    j0 = np.eye(2 * n) * prior
    for k in range(len(t)):
        phi = np.eye(2 * n)
        phi[:n, n:] = t[k] * np.eye(n)
        hx = np.zeros((2 * n, 2 * n))
        hx[:n, :n] = info[k]
        j0 += phi.T @ hx @ phi
        if k in (40, len(t) - 1):
            cov = phi @ np.linalg.inv(j0) @ phi.T
            assert bound[k] == pytest.approx(math.sqrt(np.trace(cov[:n, :n])), rel=1e-6)
    assert np.all(np.diff(bound[20:]) < 0.0)  # no process noise: information only grows


def test_crlb_with_velocity_noise_matches_the_covariance_recursion() -> None:
    """With process noise ``q_x`` the information form equals the Kalman covariance
    recursion along the truth: ``P = F P F^T + Q``, ``P = (P^-1 + H^T H / sigma^2)^-1``."""
    t, x = _truth("paper", 10.0)
    sigma, q_x, prior = math.radians(2.0), 0.05**2 * 0.05, 1e-2
    bound = core.crlb(t, x, sigma, q_x, prior_info=prior)
    n = x.shape[1]
    info = _measurement_info(x, sigma)
    p = np.eye(2 * n) / prior
    f = np.eye(2 * n)
    f[:n, n:] = 0.05 * np.eye(n)
    q = np.zeros((2 * n, 2 * n))
    q[:n, :n] = q_x * 0.05 * np.eye(n)
    for k in range(len(t)):
        if k > 0:
            p = f @ p @ f.T + q
        jm = np.linalg.inv(p)
        jm[:n, :n] += info[k]
        p = np.linalg.inv(jm)
        assert bound[k] == pytest.approx(math.sqrt(np.trace(p[:n, :n])), rel=1e-6)
    with pytest.raises(ValueError, match="noise"):
        core.crlb(t, x, 0.0)


def _gm_transition(s: float, tau: float) -> np.ndarray:
    """``expm(A s)`` of one axis of ``[x, c, g]``, ``x' = c + g``, ``g' = -g / tau``."""
    e = math.exp(-s / tau)
    return np.array([[1.0, s, tau * (1.0 - e)], [0.0, 1.0, 0.0], [0.0, 0.0, e]])


@pytest.mark.parametrize("h", [0.04, 0.1, 5.0])
def test_gauss_markov_step_is_the_integral_of_the_continuous_model(h: float) -> None:
    """``Q = int_0^h Phi(u) Qc Phi(u)^T du`` (Simpson on a fine grid) and ``F = Phi(h)``,
    both in the series branch (small steps) and the closed form."""
    q_x, std, tau = 0.05**2 * 0.1, 0.1, 60.0
    f, q = core.gauss_markov_step(h, q_x, std, tau)
    qc = np.diag([q_x, 0.0, 2.0 * std**2 / tau])
    u = np.linspace(0.0, h, 2001)
    vals = np.array([_gm_transition(s, tau) @ qc @ _gm_transition(s, tau).T for s in u])
    w = np.ones(len(u))
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    q_ref = np.einsum("k,kij->ij", w, vals) * (u[1] - u[0]) / 3.0
    np.testing.assert_allclose(f, _gm_transition(h, tau), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(q, q_ref, rtol=1e-7, atol=1e-18)


def test_crlb_with_a_gauss_markov_velocity_error_matches_the_covariance_recursion() -> None:
    """With a Gauss-Markov velocity error the bound is the Kalman covariance recursion of
    the augmented state ``[x, c, g]`` along the truth (the stationary prior on ``g``); it
    lies above the constant-bias bound, and a vanishing Gauss-Markov part gives that bound
    back (the other end-to-end cases keep theirs, :func:`crlb` unchanged for them)."""
    t, x = _truth("orbit", 20.0)
    sigma, q_x, prior = math.radians(0.5), 0.05**2 * 0.1, 1e-2
    std, tau = 0.1, 60.0
    bound = core.crlb(t, x, sigma, q_x, prior_info=prior, gm_std_mps=std, gm_tau_s=tau)
    n = x.shape[1]
    info = _measurement_info(x, sigma)
    p = np.eye(3 * n) / prior
    p[2 * n :, 2 * n :] = np.eye(n) * std**2
    h = 0.05
    f1 = _gm_transition(h, tau)
    f = np.kron(f1, np.eye(n))
    _, q1 = core.gauss_markov_step(h, q_x, std, tau)
    q = np.kron(q1, np.eye(n))
    for k in range(len(t)):
        if k > 0:
            p = f @ p @ f.T + q
        jm = np.linalg.inv(p)
        jm[:n, :n] += info[k]
        p = np.linalg.inv(jm)
        if k % 50 == 0 or k == len(t) - 1:
            assert bound[k] == pytest.approx(math.sqrt(np.trace(p[:n, :n])), rel=1e-6)
    white = core.crlb(t, x, sigma, q_x, prior_info=prior)
    assert np.all(bound[100:] > white[100:])
    tiny = core.crlb(t, x, sigma, q_x, prior_info=prior, gm_std_mps=1e-7, gm_tau_s=tau)
    np.testing.assert_allclose(tiny[100:], white[100:], rtol=1e-4)
    assert np.array_equal(core.crlb(t, x, sigma, q_x, prior, 0.0, tau), white)
    with pytest.raises(ValueError, match="Gauss-Markov"):
        core.crlb_gauss_markov(t, x, sigma, q_x, std, 0.0)


def test_the_end_to_end_bound_counts_the_gauss_markov_velocity_error() -> None:
    """velocity_coloured's bound has its Gauss-Markov part; every case without one keeps the
    constant-bias bound it had."""
    from bench.accuracy import e2e

    for name, case in e2e.CASES.items():
        noise = case.bound_noise(0.1)
        assert noise["sigma_rad"] == pytest.approx(math.radians(case.bound_bearing_deg))
        assert noise["q_x"] == pytest.approx(case.velocity_white_mps**2 * 0.1)
        if case.realism.get("velocity_gm_std_mps", 0.0) > 0.0:
            assert (noise["gm_std_mps"], noise["gm_tau_s"]) == (0.1, 60.0), name
        elif name in e2e.RANGED:  # a rangefinder on the gimbal: its information too
            assert set(noise) == {"sigma_rad", "q_x", "range_sigma_m"}, name
            assert noise["range_sigma_m"] == 0.3
        else:
            assert set(noise) == {"sigma_rad", "q_x"}, name
    assert "gm_std_mps" in e2e.CASES["velocity_coloured"].bound_noise(0.1)
    # Student-t noise of 3 degrees of freedom: twice the Gaussian's Fisher information per
    # axis, the bound that of Gaussian noise 1/sqrt(2) as large; every other case's own
    t3 = e2e.CASES["noise_student3"]
    assert t3.bearing_deg == 0.5
    assert t3.bound_bearing_deg == pytest.approx(0.5 / math.sqrt(2.0))
    assert e2e.CASES["noise_2deg"].bound_bearing_deg == e2e.CASES["noise_2deg"].bearing_deg


def test_time_to_stay_below_on_known_curves() -> None:
    t = np.arange(0.0, 10.0 + 1e-9, 0.5)
    rel = np.vstack(
        [
            np.exp(-t),  # below 0.1 from t > ln 10 = 2.30: first sample 2.5
            np.full_like(t, 0.05),  # always below: t[0]
            np.full_like(t, 0.2),  # never: inf
            np.where(t == 6.0, 0.3, 0.01),  # a late excursion: after it, 6.5
            np.where(t == 3.0, np.nan, 0.01),  # NaN counts as above: 3.5
            np.where(t == 10.0, 0.2, 0.01),  # above at the end: inf
        ]
    )
    out = core.time_to_stay_below(t, rel, 0.1)
    assert out.tolist() == [2.5, 0.0, math.inf, 6.5, 3.5, math.inf]


def test_summarise_on_a_synthetic_error() -> None:
    """A constant error gives its own RMS; the range error, NEES and divergence follow."""
    t = np.arange(0.0, 200.0 + 1e-9, 0.5)
    x = np.column_stack((np.full_like(t, 10.0), np.zeros_like(t), np.zeros_like(t)))
    a = np.array([1.0, 0.0, 0.0])
    runs = 3
    rec = core.Recorder(t, x, a, runs)
    err = np.array([[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [8.0, 0.0, 0.0]])  # run 2 diverged
    p = np.broadcast_to(np.eye(6) * 0.04, (runs, 6, 6))
    ah = np.tile(a + np.array([0.0, 0.1, 0.0]), (runs, 1))
    for k in range(len(t)):
        rec.record(k, x[k] + err, ah, p)
    m = core.summarise(rec, np.full(len(t), 0.1))
    steady = 100.0 / 0.5 + 1
    assert rec.steps == steady
    assert m["rms"] == pytest.approx(math.sqrt((0.01 + 0.04 + 64.0) / 3))
    assert m["rms_converged"] == pytest.approx(math.sqrt((0.01 + 0.04) / 2))
    assert m["bias_rms"] == pytest.approx(0.1)
    assert m["crlb"] == pytest.approx(0.1)
    assert m["ratio"] == pytest.approx(m["rms"] / 0.1)
    assert m["diverged"] == pytest.approx(1 / 3)
    assert m["t10_med"] == 0.0
    assert m["t10_p90"] == math.inf
    ranges = [1.0, 100.0 * (math.sqrt(100.04) - 10.0) / 10.0, 80.0]
    assert m["range_pct"] == pytest.approx(np.mean(ranges))
    assert m["range_pct_se"] == pytest.approx(np.std(ranges, ddof=1) / math.sqrt(3))
    assert m["nees"] == pytest.approx((0.01 + 0.04 + 64.0) / 0.04 / 3 / 3)


def test_runs_are_reproducible_and_independent_of_their_number() -> None:
    case = core.Case("planar", 2.0, 0.05)
    d3 = core.generate(case, 3, duration_s=5.0, random_init=True)
    d1 = core.generate(case, 1, duration_s=5.0, random_init=True, first_run=2)
    np.testing.assert_array_equal(d3.y[2], d1.y[0])
    np.testing.assert_array_equal(d3.v[2], d1.v[0])
    assert d3.r0[2] == d1.r0[0]
    assert not np.array_equal(d3.y[0], d3.y[1])
    np.testing.assert_allclose(np.linalg.norm(d3.y, axis=-1), 1.0)
    r_true = np.linalg.norm(d3.x[0])
    assert np.all((d3.r0 >= r_true / 10) & (d3.r0 <= r_true * 10))


@pytest.mark.slow
def test_batched_riccati_is_the_service_estimator() -> None:
    """The batched bank and ``BiasObserver(ObserverConfig(estimator='riccati'))`` driven
    sample by sample give the same estimates on a short noisy run."""
    case = core.Case("orbit", 2.0, 0.05)
    data = core.generate(case, 2, duration_s=10.0, range_factor=2.0)
    service = estimators.make("riccati", data.sigma_rad, 0.05, 3, data.dt, per_sample=True)
    batched = estimators.make("riccati", data.sigma_rad, 0.05, 3, data.dt)
    outs = []
    for est in (batched, service):
        rec = run.run_estimator(est, data)
        outs.append((est.estimate(), rec.rel))
    (x1, a1, p1), rel1 = outs[0]
    (x2, a2, p2), rel2 = outs[1]
    assert p1 is not None
    assert p2 is not None
    np.testing.assert_allclose(x2, x1, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(a2, a1, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(p2, p1, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(rel2, rel1, rtol=1e-7, atol=1e-9)


@pytest.mark.slow
def test_the_command_line_on_a_short_grid(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(
        [
            "--scenarios",
            "orbit,planar",
            "--bearing-noise",
            "0",
            "2",
            "--velocity-noise",
            "0",
            "--estimators",
            "ekf",
            "plkf",
            "--runs",
            "3",
            "--duration",
            "8",
            "--jobs",
            "1",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    rows = [line for line in out.splitlines() if line.startswith(("| orbit |", "| planar |"))]
    assert len(rows) == 8
    assert "| orbit | 0 | 0 | ekf | 3 |" in out
    zero_noise = [r for r in rows if "| 0 | 0 |" in r]
    assert all(r.split("|")[11].strip() == "-" for r in zero_noise)  # no CRLB
    assert "wall time" in out


def test_generated_blocks_survive_the_pages_regeneration(tmp_path: Path) -> None:
    from bench.accuracy import blocks

    page = tmp_path / "accuracy.md"
    page.write_text("# Accuracy\n\nintro\n\n## What is measured\n\ntext\n")
    blocks.put_block(page, "real-logs", "## Real\n\nrows 1")
    blocks.put_block(page, "end-to-end", "## E2E\n\nrows 2")
    blocks.put_block(page, "real-logs", "## Real\n\nrows 3")  # replaced, not added
    text = page.read_text()
    assert text.count("## Real") == 1 and "rows 3" in text and "rows 1" not in text
    assert text.index("## E2E") < text.index("## Real") < text.index("## What is measured")
    # the harness regenerates the page around them
    kept = blocks.blocks_of(text)
    fresh = blocks.with_blocks("# Accuracy\n\nnew intro\n\n## What is measured\n\nnew\n", kept)
    assert "rows 2" in fresh and "rows 3" in fresh and "new intro" in fresh
    # rewriting a block leaves the page as it was: no blank lines pile up
    blocks.put_block(page, "real-logs", "## Real\n\nrows 3")
    assert page.read_text() == text and "\n\n\n" not in text


def test_a_markdown_table_has_its_header_separator_and_rows() -> None:
    from bench.accuracy.report import markdown_table

    got = markdown_table(("a", "b c"), ["| 1 | 2 |", "| 3 | 4 |"])
    assert got.splitlines() == ["| a | b c |", "|---|---|", "| 1 | 2 |", "| 3 | 4 |"]


def test_a_measured_range_lowers_the_bound_and_makes_a_hover_bounded() -> None:
    """The bound with a range measured with each bearing: finite on a hovering vehicle (no
    motion), where bearings alone leave the range unbounded, and never above the bearings'."""
    from bench.accuracy import core

    t = np.arange(0.0, 60.0, 0.1)
    hover = np.tile([20.0, 10.0, 10.0], (len(t), 1))
    sigma = math.radians(0.5)
    with pytest.raises(np.linalg.LinAlgError):  # no motion: the range has no information
        core.crlb(t, hover, sigma)
    ranged = core.crlb(t, hover, sigma, range_sigma_m=0.3)
    assert ranged[-1] < 0.05  # about 3.5 cm after a minute of 0.3 m ranges and 0.5 deg
    fig8 = np.column_stack([20 + 10 * np.sin(0.2 * t), 10 * np.sin(0.4 * t), np.full(len(t), 10.0)])
    assert np.all(core.crlb(t, fig8, sigma, range_sigma_m=0.3) <= core.crlb(t, fig8, sigma))
