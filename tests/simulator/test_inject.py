"""sim.inject: a synthetic bearing stream added to real logs, checked against the logs
themselves, the reader's frame chain and the product's replay."""

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from mavmsg import TLOGS

from mav_observer.app import reference
from mav_observer.app import replay as rp
from mav_observer.core.batch_fit import displacement_at, fit_batch
from mav_observer.geo.frames import euler_to_dcm
from mav_observer.mavlink.dialect import MSG_ID
from mav_observer.mavlink.fastdecode import FastDecoder
from mav_observer.mavlink.tlog import TlogReader
from mav_observer.tracking import directions as adapters
from sim import inject as inj
from sim import truth as truth_file
from sim.__main__ import main as sim_main

BRUNO = TLOGS / "real_copter_bruno_mission_132614.tlog"
PHOENIX = TLOGS / "real_copter_phoenix_m2.tlog"
GIMBAL = MSG_ID["GIMBAL_DEVICE_ATTITUDE_STATUS"]
LPN = MSG_ID["LOCAL_POSITION_NED"]
VEL_ERROR = (1.0, -0.5, 0.2)
TARGET = (20.0, -150.0, 5.0)


def write(path: Path, result: inj.InjectResult) -> tuple[Path, Path]:
    path.write_bytes(b"".join(result.records))
    truth = path.with_suffix(".truth.jsonl")
    truth_file.write(truth, result.truth)
    return path, truth


def local_positions(path: Path) -> np.ndarray:
    """``(t_boot_s, x, y, z, vx, vy, vz)`` of every LOCAL_POSITION_NED, (N, 7)."""
    rows = [
        (m.time_boot_ms / 1000, m.x, m.y, m.z, m.vx, m.vy, m.vz) for _, m in TlogReader(path, {LPN})
    ]
    return np.array(rows)


@pytest.fixture(scope="module")
def bruno(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The Bruno mission (MAVLink 2, LOCAL_POSITION_NED and ATTITUDE at 1 Hz), noise-free
    gimbal bearings, a velocity error."""
    d = tmp_path_factory.mktemp("bruno")
    records = inj.split_records(BRUNO.read_bytes())
    cfg = inj.InjectConfig(target_ned_m=TARGET, noise_deg=0.0, vel_error_ned_mps=VEL_ERROR)
    result = inj.inject(records, cfg)
    path, truth = write(d / "bruno.tlog", result)
    return {"records": records, "result": result, "path": path, "truth": truth}


def test_bruno_replays_with_the_injected_gimbal(bruno: dict) -> None:
    res = bruno["result"]
    assert res.sysid == 10 and res.target == "gimbal" and res.injected > 1500
    assert res.rewritten_local_position == 464 and res.same_target_frames == 0
    s = rp.replay(str(bruno["path"]), keep_series=True)
    assert "10/gimbal" in s.targets
    assert s.used["GIMBAL_DEVICE_ATTITUDE_STATUS"] == res.injected
    # placed so that the autopilot clock never goes back, each stamp once
    assert "out_of_order" not in s.skipped and "duplicate" not in s.skipped
    truth = reference.read(bruno["truth"])
    errors = reference.errors(s.series["10/gimbal"], truth["10/gimbal"])
    assert len(errors["t_boot_s"]) > 1500


def test_truth_is_the_target_minus_the_interpolated_local_position(bruno: dict) -> None:
    lp = local_positions(BRUNO)
    truth = bruno["result"].truth
    t = np.array([d["t_boot_s"] for d in truth])
    assert np.all(np.diff(t) > 0)
    assert np.all(np.round(t * 1000).astype(int) % 100 == 0)  # on the 10 Hz grid
    assert t[0] >= lp[0, 0] and t[-1] <= lp[-1, 0]
    vehicle = np.column_stack([np.interp(t, lp[:, 0], lp[:, i]) for i in (1, 2, 3)])
    rel = np.array([d["rel_pos_ned_m"] for d in truth])
    assert np.allclose(rel, np.array(TARGET) - vehicle, atol=1e-9)
    assert np.allclose([d["vehicle_pos_ned_m"] for d in truth], vehicle, atol=1e-9)
    assert all(d["bias_ned_mps"] == list(VEL_ERROR) for d in truth)
    assert all(d["target"] == "gimbal" and d["sysid"] == 10 for d in truth)


def test_noise_free_bearings_decode_to_the_truth(bruno: dict) -> None:
    """Through the reader's own chain (gimbal_boresight with the vehicle yaw): within 0.05
    deg of the truth's direction. The vehicle yaw is the log's ATTITUDE yaw interpolated
    (unwrapped) between the samples around the bearing time, or the nearest one where they
    are more than ATTITUDE_INTERP_MAX_S apart (the tracker's rule); it is within 0.2 s of one."""
    by_ms = {round(d["t_boot_s"] * 1000): d for d in bruno["result"].truth}
    att = np.array(
        [(m.time_boot_ms / 1000, m.yaw) for _, m in TlogReader(BRUNO, {MSG_ID["ATTITUDE"]})]
    )
    worst = 0.0
    for _, m in TlogReader(bruno["path"], {GIMBAL}):
        d = by_ms[m.time_boot_ms]
        t = m.time_boot_ms / 1000
        j = int(np.searchsorted(att[:, 0], t, side="right"))
        (ta, ya), (tb, yb) = att[j - 1], att[j]
        assert min(t - ta, tb - t) <= 0.2 + 1e-9
        if tb - ta <= inj.ATTITUDE_INTERP_MAX_S:
            yaw = ya + (t - ta) / (tb - ta) * math.remainder(yb - ya, 2 * math.pi)
        else:
            yaw = ya if t - ta <= tb - t else yb
        assert math.remainder(d["attitude_rpy_rad"][2] - yaw, 2 * math.pi) == pytest.approx(
            0.0, abs=1e-9
        )
        b = adapters.gimbal_boresight(
            tuple(m.q), m.flags, m.failure_flags, vehicle_yaw=yaw, delta_yaw=m.delta_yaw
        )
        x = np.array(d["rel_pos_ned_m"])
        cos = float(np.dot(b, x) / (np.linalg.norm(b) * np.linalg.norm(x)))
        worst = max(worst, math.degrees(math.acos(min(1.0, cos))))
        assert m.flags & adapters.GIMBAL_YAW_IN_VEHICLE_FRAME
    assert worst < 0.05


def test_velocity_error_is_in_the_local_position_and_nothing_else_changed(bruno: dict) -> None:
    original = bruno["records"]
    out = inj.split_records(bruno["path"].read_bytes())
    injected = [r for r in out if r.msgid == GIMBAL]
    assert len(injected) == bruno["result"].injected
    assert all(r.frame[0] == 0xFD and r.source == (10, 1) for r in injected)
    kept = [r for r in out if r.msgid != GIMBAL]
    assert len(kept) == len(original)
    dec = FastDecoder(frozenset({LPN}))
    n_lpn = 0
    for a, b in zip(original, kept, strict=True):
        if a.msgid != LPN:
            assert a.data == b.data
            continue
        n_lpn += 1
        assert a.data[:8] == b.data[:8]  # tlog time
        assert a.frame[:7] == b.frame[:7]  # version, length, flags, seq, sysid, compid
        ma, mb = dec.decode(a.frame), dec.decode(b.frame)
        assert (ma.time_boot_ms, ma.x, ma.y, ma.z) == (mb.time_boot_ms, mb.x, mb.y, mb.z)
        dv = np.array([mb.vx - ma.vx, mb.vy - ma.vy, mb.vz - ma.vz])
        assert np.allclose(dv, VEL_ERROR, atol=1e-5)
    assert n_lpn == 464
    # the injected frames interleave: the log's times stay in order
    t = [r.t_us for r in out]
    assert all(b >= a for a, b in itertools.pairwise(t))


def test_the_velocity_error_is_a_with_a_plus_sign(bruno: dict) -> None:
    """The model: u_meas = u_true + e, x' = -u_true = v + e, so a = +e. A batch fit of the
    injected (noise-free) bearings with the displacement of the rewritten LOCAL_POSITION_NED
    (v = -u_meas, positions GPS-true) finds a = +VEL_ERROR (to the log's own velocity drift,
    about 0.01 m/s); without the error it finds about 0."""
    truth = bruno["result"].truth
    t = np.array([d["t_boot_s"] for d in truth])
    y = np.array([d["bearing_ned"] for d in truth])
    x = np.array([d["rel_pos_ned_m"] for d in truth])
    lp = local_positions(bruno["path"])
    d = displacement_at(t, lp[:, 0], lp[:, 4:7], lp[:, 1:4])
    fit = fit_batch(t, y, d)
    assert np.allclose(fit.a_ned_mps, VEL_ERROR, atol=0.03)
    assert np.linalg.norm(fit.x0_ned_m - x[0]) < 0.1
    lp0 = local_positions(BRUNO)
    fit0 = fit_batch(t, y, displacement_at(t, lp0[:, 0], lp0[:, 4:7], lp0[:, 1:4]))
    assert np.linalg.norm(fit0.a_ned_mps) < 0.03


def test_landing_target_decodes_to_the_truth(bruno: dict) -> None:
    records = bruno["records"]
    below = (20.0, -150.0, 40.0)  # 40 m below the origin: below the vehicle
    res = inj.inject(
        records, inj.InjectConfig(target_ned_m=below, bearing="landing_target", noise_deg=0.0)
    )
    assert res.target == "landing_target_0" and res.injected > 1000
    frames = [r.frame for r in inj.split_records(b"".join(res.records))]
    dec = FastDecoder(frozenset({MSG_ID["LANDING_TARGET"]}))
    msgs = [dec.decode(f) for f in frames if f and f[0] == 0xFD and f[7] == 149 and f[8] == 0]
    assert len(msgs) == res.injected
    for m, d in zip(msgs, res.truth, strict=True):
        assert m.time_usec == round(d["t_boot_s"] * 1000) * 1000
        los = adapters.landing_target_direction(
            frame=m.frame,
            angle_x=m.angle_x,
            angle_y=m.angle_y,
            position_valid=m.position_valid,
            x=m.x,
            y=m.y,
            z=m.z,
            vehicle_dcm=euler_to_dcm(*d["attitude_rpy_rad"]),
            vehicle_yaw=None,
        )
        x = np.array(d["rel_pos_ned_m"])
        cos = float(np.dot(los, x) / (np.linalg.norm(los) * np.linalg.norm(x)))
        assert math.degrees(math.acos(min(1.0, cos))) < 0.05


@pytest.fixture(scope="module")
def phoenix_slice(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 15,000 records (about 7 minutes) of the MAVLink 1 Phoenix flight."""
    path = tmp_path_factory.mktemp("phoenix") / "phoenix_slice.tlog"
    records = inj.split_records(PHOENIX.read_bytes())[:15000]
    path.write_bytes(b"".join(r.data for r in records))
    return path


@pytest.mark.slow
def test_phoenix_mavlink1_log_gets_mavlink2_bearings(phoenix_slice: Path, tmp_path: Path) -> None:
    out, truth = tmp_path / "out.tlog", tmp_path / "out.truth.jsonl"
    cfg = inj.InjectConfig(target_ned_m=None, vel_error_ned_mps=VEL_ERROR, seed=3)
    res = inj.inject_file(phoenix_slice, out, truth, cfg)
    assert res.sysid == 1 and res.injected > 2000
    t = res.target_ned_m
    assert t[2] > 0 and 2.0 <= res.range_m[0] < res.range_m[1] < 300.0
    recs = inj.split_records(out.read_bytes())
    versions = {r.msgid: r.frame[0] for r in recs if r.msgid in (GIMBAL, LPN)}
    assert versions == {GIMBAL: 0xFD, LPN: 0xFE}
    s = rp.replay(str(out), keep_series=True)
    assert "1/gimbal" in s.targets
    assert "out_of_order" not in s.skipped and "duplicate" not in s.skipped
    tr = reference.read(truth)
    assert len(reference.errors(s.series["1/gimbal"], tr["1/gimbal"])["t_boot_s"]) > 1000


def test_auto_target_is_under_the_middle_of_the_flight(bruno: dict) -> None:
    flight = inj.read_flight(bruno["records"])
    lp = local_positions(BRUNO)
    target = inj.auto_target(flight)
    assert target[0] == pytest.approx(np.median(lp[:, 1]))
    assert target[1] == pytest.approx(np.median(lp[:, 2]))
    assert target[2] == pytest.approx(lp[:, 3].max() + 2.0)


def test_damaged_logs_do_not_crash(tmp_path: Path) -> None:
    """The truncated log has no LOCAL_POSITION_NED: a clear error, no traceback. A slice of
    the Bruno mission with junk in the middle and a cut last record: the junk and the cut
    record are copied as they are, the rest is injected."""
    bad = TLOGS / "bad_truncated_lastrec_124019.tlog"
    data = bad.read_bytes()
    recs = inj.split_records(data)
    assert b"".join(r.data for r in recs) == data
    assert recs[-1].t_us is None  # the cut record
    with pytest.raises(inj.InjectError, match="no LOCAL_POSITION_NED"):
        inj.inject_file(bad, tmp_path / "o.tlog", tmp_path / "o.jsonl", inj.InjectConfig())
    rc = sim_main(
        [
            "inject",
            str(bad),
            "--target",
            "auto",
            "-o",
            str(tmp_path / "o.tlog"),
            "--truth",
            str(tmp_path / "o.jsonl"),
        ]
    )
    assert rc == 2

    good = inj.split_records(BRUNO.read_bytes())[:3000]
    junk = bytes(300) + b"\xfd\x09garbage" + bytes(range(256))
    cut = good[-1].data[:-5]
    damaged = b"".join(r.data for r in good[:1500]) + junk
    damaged += b"".join(r.data for r in good[1500:-1]) + cut
    src = tmp_path / "damaged.tlog"
    src.write_bytes(damaged)
    res = inj.inject_file(src, tmp_path / "d.tlog", tmp_path / "d.jsonl", inj.InjectConfig())
    assert res.damage_chunks == 2 and res.injected > 200
    out = (tmp_path / "d.tlog").read_bytes()
    assert junk in out and out.endswith(cut)
    s = rp.replay(str(tmp_path / "d.tlog"))
    assert "10/gimbal" in s.targets


def test_log_with_clock_epochs(tmp_path: Path) -> None:
    """A log a second writer damaged (zero-filled holes, the autopilot clock going back
    twice): three epochs, bearings only where LOCAL_POSITION_NED is (the first)."""
    res = inj.inject_file(
        TLOGS / "bad_zeroholes_tsback_132613.tlog",
        tmp_path / "z.tlog",
        tmp_path / "z.jsonl",
        inj.InjectConfig(target_ned_m=(0.0, -20.0, 2.0)),
    )
    assert res.epochs == 3 and res.damage_chunks == 2 and res.injected > 1000
    assert {d["epoch"] for d in res.truth} == {0}


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "slice.tlog"
    src.write_bytes(b"".join(r.data for r in inj.split_records(BRUNO.read_bytes())[:2000]))
    out, truth = tmp_path / "o.tlog", tmp_path / "o.jsonl"
    rc = sim_main(
        [
            "inject",
            str(src),
            "--target",
            "auto",
            "-o",
            str(out),
            "--truth",
            str(truth),
            "--vel-error",
            "0.5,0,0",
            "--rate-hz",
            "5",
            "--noise-deg",
            "0.2",
            "--seed",
            "1",
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "target auto: [" in text and "'gimbal' bearings" in text
    first = json.loads(truth.read_text().splitlines()[0])
    keys = ("t_unix_s", "t_boot_s", "sysid", "target", "rel_pos_ned_m", "bias_ned_mps")
    assert all(k in first for k in (*keys, "target_pos_ned_m", "vehicle_pos_ned_m"))
    assert first["bias_ned_mps"] == [0.5, 0.0, 0.0]
    assert round(first["t_boot_s"] * 1000) % 200 == 0


def test_config_checks() -> None:
    with pytest.raises(inj.InjectError, match="bearing"):
        inj.InjectConfig(bearing="mount")
    with pytest.raises(inj.InjectError, match="rate_hz"):
        inj.InjectConfig(rate_hz=0.0)
    with pytest.raises(inj.InjectError, match="vel_error_ned_mps"):
        inj.InjectConfig(vel_error_ned_mps=(1.0, math.nan, 0.0))
    assert inj.InjectConfig(gimbal_device_id=2).target_name == "gimbal2"
