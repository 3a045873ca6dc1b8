"""The end-to-end accuracy harness (bench/accuracy/e2e.py): emitter tlogs with the realism
knobs, replayed through the product's replay, scored against the truth and the CRLB. The
headline figures come from ``python -m bench.accuracy.e2e`` (16 seeds of 300 s per case);
here one short run per path shows the whole chain works and lands near the bound."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.accuracy import e2e  # noqa: E402

pytestmark = pytest.mark.slow  # whole flights, loopback services or the end-to-end harness


@pytest.mark.parametrize("case", ["gimbal_vehicle_fig8", "landing_target_weave"])
def test_a_short_end_to_end_run_lands_near_the_bound(case: str, tmp_path: Path) -> None:
    m = e2e.run_one(case, seed=3, duration_s=120.0, workdir=str(tmp_path))
    assert m["n"] > 500  # estimates scored over the last third
    # one 120 s run: its error is strongly correlated in time, so the bounds are loose
    assert 0.3 < m["ratio"] < 2.0, m
    assert 0.1 < m["nees_axis"] < 5.0, m
    assert m["t10_s"] < 30.0
    assert "attitude_extrapolated" not in m["events"]
    # on the map (the origin from GLOBAL_POSITION_INT paired with LOCAL_POSITION_NED): the
    # median horizontal error over the last third under 0.15 m, and target_h_std_m honest
    # (with the vehicle moved on by the velocity as measured, 2.2 m/s off: 0.13 m and 21 %).
    # Over the last third of one 120 s run the estimate is still settling: over seeds 0-7
    # 0.62-1.0 within twice the sigma (mean 0.90; 0.92 with the origin of one rounded pair,
    # up to 5 mm off, before the pairs were averaged); this seed 0.79
    assert m["geo_h_med_m"] < 0.15, m
    assert m["geo_h_within_2sd"] > 0.75, m
    # "after convergence" as the product declares it: from its first converged estimate on
    assert m["geo_conv_n"] > 100, m
    assert m["geo_h_within_2sd_conv"] > 0.8, m


def test_a_lagged_gimbal_is_not_called_converged_before_its_latency_is_learnt(
    tmp_path: Path,
) -> None:
    """A gimbal 0.1 s late, the default settings: the estimate is called converged only once
    the latency learnt has settled, and from then on twice ``target_h_std_m`` holds its
    errors (called converged before, it was 0.4 m off at a sigma of 0.05 m for 30 s: 80 %
    within over 8 seeds of 300 s)."""
    m = e2e.run_one("gimbal_lag", seed=0, duration_s=180.0, workdir=str(tmp_path), defaults=True)
    assert m["geo_conv_n"] > 500, m
    assert m["geo_h_within_2sd_conv"] > 0.9, m


def test_the_settings_file_of_a_case_is_what_the_product_reads(tmp_path: Path) -> None:
    from mav_observer.app import settings as st

    case = e2e.CASES["velocity_coloured"]
    f = tmp_path / "case.toml"
    f.write_text(e2e.settings_toml(case.settings, case.tracker))
    assert st.resolve(f).tracker_config() == e2e.tracker_config(case)


def test_on_a_1hz_position_stream_the_target_on_the_map_stays_within_its_sigma(
    tmp_path: Path,
) -> None:
    """LOCAL_POSITION_NED at 1 Hz: the vehicle's position between samples is moved on the way
    the estimate is predicted (the observer's trend), so the target's place on the map keeps
    the estimate's accuracy and sigma (moved on with the last velocity instead: 2.8 cm, 48 %
    within twice target_h_std_m over 8 seeds)."""
    m = e2e.run_one("velocity_1hz", seed=0, duration_s=120.0, workdir=str(tmp_path))
    assert m["geo_h_med_m"] < 0.05, m
    assert m["geo_h_within_2sd"] > 0.8, m
