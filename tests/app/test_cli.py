"""The command lines: ``mav-observer`` and ``python -m sim``, run as a user would."""

import subprocess
import sys
from pathlib import Path

import pytest

from mav_observer import __version__
from mav_observer.app.cli import main


def _run(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=timeout, check=False
    )


def test_version(capsys) -> None:
    assert main(["version"]) == 0
    assert capsys.readouterr().out.strip() == f"mav-observer {__version__}"


@pytest.mark.slow
def test_demo_runs_emitter_service_and_subscriber_to_a_verdict() -> None:
    """README's main job: the whole chain on loopback, ending by itself."""
    proc = _run("-m", "mav_observer", "demo", "--speed", "30")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("scenario orbit")
    verdict = next(ln for ln in lines if ln.startswith("verdict:"))
    assert verdict.startswith("verdict: CONVERGED")
    pct = float(verdict.split(" m (")[1].split(" %")[0])
    assert pct < 5.0
    rows = [ln for ln in lines if ln.strip() and ln.split()[0].replace(".", "").isdigit()]
    assert len(rows) >= 5
    assert lines[-1].startswith("service stopped: exit 0")


@pytest.mark.slow
def test_offline_demo_prints_convergence_and_a_verdict() -> None:
    proc = _run("-m", "sim", "demo", "--scenario", "orbit", "--duration", "120", "--every", "20")
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("scenario orbit")
    verdict = lines[-1]
    assert verdict.startswith("verdict: CONVERGED")
    err = float(verdict.split("final position error ")[1].split(" m")[0])
    assert err < 0.01
    rows = [ln for ln in lines if ln.strip() and ln.split()[0].replace(".", "").isdigit()]
    assert len(rows) >= 6


def test_run_prints_its_effective_settings_as_toml() -> None:
    import tomllib

    proc = _run(
        "-m", "mav_observer", "run", "--print-config", "--zenoh-mode", "router",
        "--estimator", "paper", "--k", "0.3",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = tomllib.loads(proc.stdout)
    assert doc["zenoh"]["mode"] == "router"
    assert doc["observer"]["k_per_s"] == 0.3
    assert doc["mavlink"]["url"] == "udpin:127.0.0.1:14550"


@pytest.mark.slow
def test_demo_verdict_is_honest_when_not_converged() -> None:
    proc = _run("-m", "sim", "demo", "--scenario", "straight_pass")
    assert proc.returncode == 2
    assert "NOT CONVERGED (not observable)" in proc.stdout.splitlines()[-1]


def test_demo_refuses_bad_options() -> None:
    proc = _run("-m", "sim", "demo", "--scenario", "nowhere")
    assert proc.returncode == 2
    assert "invalid choice: 'nowhere'" in proc.stderr


@pytest.mark.slow
def test_figures_command_writes_the_papers_six_figures(tmp_path: Path) -> None:
    proc = _run("-m", "sim", "figures", "--out", str(tmp_path), "--duration", "20", timeout=300)
    assert proc.returncode == 0, proc.stderr
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == [
        "fig1_trajectory.png",
        "fig2_error.png",
        "fig3_ahat.png",
        "fig4_trajectory_noisy.png",
        "fig5_error_noisy.png",
        "fig6_ahat_noisy.png",
        "fig7_gains_noise.png",
    ]
    for p in tmp_path.glob("*.png"):
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000
    assert "noise-free: final |x-xhat|" in proc.stdout
