"""Real flight logs with injected bearings, replayed by the product and scored against the
truth and the batch least-squares optimum (bench/accuracy/reallogs.py): the acceptance of the
end-to-end path on data this project did not make."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.accuracy import reallogs  # noqa: E402

LOGS = reallogs.shared_logs()


def test_the_shared_logs_with_local_position_are_all_there() -> None:
    names = {p.name for p in LOGS}
    assert {
        "real_copter_phoenix_m2.tlog",
        "real_copter_bruno_mission_132614.tlog",
        "gimbal_ardusub_bluerov_small.tlog",
        "ardupilot_sitl_servo_mount_roi.tlog",
        "bad_zeroholes_tsback_132613.tlog",
    } <= names


@pytest.mark.parametrize("log", LOGS, ids=[p.stem for p in LOGS])
def test_injected_bearings_on_a_real_log_never_blow_up(log: Path, tmp_path: Path) -> None:
    # default settings, a 0.5 deg gimbal at 10 Hz toward a point under the flight, and a
    # wind-like (2, -1, 0) m/s error on the log's velocity: position RMS over the last third
    # under 10 % of the range, and beside the offline optimum of the same data
    r = reallogs.run_log(log, seed=7, workdir=tmp_path)
    assert r["injected"] > 500
    assert r["estimates"] > 0.9 * r["injected"]
    assert r["product_rel_rms"] < 0.10, r
    assert r["batch_rel_rms"] < 0.15, r  # the optimum itself is sane
    assert "replay_error" not in r["events"]
