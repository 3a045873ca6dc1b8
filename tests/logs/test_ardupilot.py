"""DataFlash records as MAVLink messages (mav_observer/logs/ardupilot.py)."""

from __future__ import annotations

import math
from itertools import pairwise
from pathlib import Path

import pytest
from flightlogs import LOGS

from mav_observer.logs.formats import LogReader
from mav_observer.mavlink.tlog import TlogReader


def by_type(messages: list[tuple[float, object]]) -> dict[str, list[object]]:
    out: dict[str, list[object]] = {}
    for _, m in messages:
        out.setdefault(m.get_type(), []).append(m)  # type: ignore[attr-defined]
    return out


def test_the_converted_flight_gives_back_the_tlogs_messages(flight: dict[str, Path]) -> None:
    tl = by_type(list(TlogReader(flight["tlog"])))
    log = LogReader(flight["bin"], "dataflash")
    msgs = list(log)
    assert all(b[0] >= a[0] for a, b in pairwise(msgs))  # time order
    df = by_type(msgs)
    for a, b in zip(tl["LOCAL_POSITION_NED"], df["LOCAL_POSITION_NED"], strict=True):
        assert a.time_boot_ms == b.time_boot_ms
        assert (b.x, b.vx, b.vy) == pytest.approx((a.x, a.vx, a.vy), abs=1e-4)
    for a, b in zip(tl["ATTITUDE"], df["ATTITUDE"], strict=True):
        assert b.yaw == pytest.approx(math.remainder(a.yaw, 2 * math.pi), abs=2e-4)  # cdeg
    assert len(df["MOUNT_ORIENTATION"]) == len(tl["GIMBAL_DEVICE_ATTITUDE_STATUS"])
    assert log.stats.format == "DataFlash" and not log.stats.damage()


def test_mount_angles_by_column_name_across_layouts() -> None:
    """ArduSub 4.8 inserts a Mode column before the angles; the demanded angles are NaN
    (a servo mount), the measured ones are read."""
    log = LogReader(LOGS / "ardusub48_sitl_mnt_mode_first512k.bin", "dataflash")
    mounts = [m for _, m in log if m.get_type() == "MOUNT_ORIENTATION"]
    assert len(mounts) == 99
    assert all(math.isfinite(m.pitch) and math.isfinite(m.yaw_absolute) for m in mounts)
    assert any(m.pitch != 0.0 for m in mounts)


def test_an_old_log_reads_ekf2_and_says_what_it_lacks() -> None:
    log = LogReader(LOGS / "plane_nkf1_truncated64k_pymavlink.bin", "dataflash")
    kinds = by_type(list(log))
    assert len(kinds["LOCAL_POSITION_NED"]) == 24  # NKF1, no core column
    assert kinds["GPS_GLOBAL_ORIGIN"][0].latitude != 0
    assert any("no MNT record" in n for n in log.stats.notes)
    assert log.stats.truncated_tail


def test_precision_landing_measurements_become_landing_targets(tmp_path: Path) -> None:
    """PL: one LANDING_TARGET per new measurement (LastMeasMS) while the target is acquired,
    at the measurement's time, its mX, mY, mZ (cm) the line of sight relative to the vehicle
    in NED; a record before acquisition and a repeat of the last measurement are not."""
    from sim.logwriters import DataFlashWriter

    path = tmp_path / "pl.bin"
    with open(path, "wb") as fh:
        df = DataFlashWriter(fh)
        rows = [  # TimeUS, TAcq, mX, mY, mZ, LastMeasMS
            (1_000_000, 0, 0.0, 0.0, 0.0, 0),
            (1_010_000, 1, 300.0, -400.0, 1200.0, 1005),
            (1_012_500, 1, 300.0, -400.0, 1200.0, 1005),  # the same measurement, logged again
            (1_020_000, 1, 100.0, 0.0, 1000.0, 1018),
        ]
        for t, acq, mx, my, mz, last in rows:
            df.write("PL", (t, 1, acq, 13.0, 0.0, 0.0, 0.0, 0.0, mx, my, mz, last, 0, 1))
    log = LogReader(path, "dataflash")
    lts = [(t, m) for t, m in log if m.get_type() == "LANDING_TARGET"]
    assert [m.time_usec for _, m in lts] == [1_005_000, 1_018_000]
    m = lts[0][1]
    assert (m.frame, m.position_valid, m.target_num) == (7, 1, 0)
    assert (m.x, m.y, m.z) == pytest.approx((3.0, -4.0, 12.0))
    assert m.distance == 0  # the rangefinder's distance along it is not a measured range


def test_a_precision_landing_log_replays_to_its_target(tmp_path: Path) -> None:
    """An emitted flight with a body-frame LANDING_TARGET camera, written as a DataFlash log
    (PL from the LANDING_TARGETs), replays to the truth's target within its sigma."""
    import json

    import numpy as np

    from mav_observer.app.replay import replay
    from sim import emitter as em
    from sim import logwriters, scenarios

    cfg = em.EmitterConfig(bearing="landing_target", duration_s=60.0, seed=3,
                           bearing_noise_deg=0.5, attitude_hz=50.0, bearing_hz=20.0)  # fmt: skip
    tlog, truth = tmp_path / "lt.tlog", tmp_path / "lt.truth.jsonl"
    em.run(em.Emitter(scenarios.make("weave"), cfg), tlog=tlog, truth=truth)
    binlog = tmp_path / "lt.bin"
    logwriters.convert(tlog, binlog)
    out = tmp_path / "est.jsonl"
    summary = replay(str(binlog), output_jsonl=out)
    est = [json.loads(x) for x in out.read_text().splitlines()]
    assert est and all(r["target"] == "landing_target_0" for r in est)
    last = est[-1]
    true = [json.loads(x) for x in truth.read_text().splitlines()]
    t_true = np.array([d["t_boot_s"] for d in true])
    k = int(np.argmin(np.abs(t_true - last["t_boot_s"])))
    err = np.linalg.norm(np.array(last["rel_pos_ned_m"]) - true[k]["rel_pos_ned_m"])
    sd = np.linalg.norm(last["rel_pos_std_ned_m"])
    assert err <= 4.0 * sd and err < 0.05 * np.linalg.norm(true[k]["rel_pos_ned_m"]), (err, sd)
    assert summary.targets["1/landing_target_0"].estimates > 0.9 * len(true)
