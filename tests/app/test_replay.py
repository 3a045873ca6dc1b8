"""Replay end to end: emitter tlogs for every bearing source, the real and damaged logs, the
command line and its files."""

import csv
import json
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mavmsg import TLOGS

from mav_observer.app import reference
from mav_observer.app import replay as rp
from mav_observer.app.cli import main
from mav_observer.core.observer import ObserverConfig
from mav_observer.tracking.tracker import TrackerConfig
from sim import fuzz, scenarios
from sim.emitter import BEARINGS, TARGET_OF, Emitter, EmitterConfig, run
from sim.live import free_port


@pytest.fixture(scope="module")
def emitted(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path]]:
    """Orbit scenario, 300 s, 0.5 deg bearing noise, for every bearing stream."""
    d = tmp_path_factory.mktemp("emitted")
    out = {}
    for b in BEARINGS:
        em = Emitter(
            scenarios.orbit(),
            EmitterConfig(bearing=b, duration_s=300.0, bearing_noise_deg=0.5, seed=11),
        )
        run(em, tlog=d / f"{b}.tlog", truth=d / f"{b}.jsonl")
        out[b] = (d / f"{b}.tlog", d / f"{b}.jsonl")
    return out


@pytest.mark.slow
@pytest.mark.parametrize("bearing", BEARINGS)
def test_every_source_converges_to_the_truth(emitted, bearing: str) -> None:
    """Acceptance: orbit, 0.5 deg noise, 300 s: over the last third, position error below 5 %
    of range and bias error below 0.1 m/s."""
    tl, truth_path = emitted[bearing]
    s = rp.replay(str(tl), keep_series=True)
    key = f"1/{TARGET_OF[bearing]}"
    truth = reference.read(truth_path)
    last = reference.last_third(reference.errors(s.series[key], truth[key]))
    assert last["samples"] > 900
    assert last["max_rel_pos_err"] < 0.05
    assert last["max_bias_err_mps"] < 0.1
    assert s.skipped == {} and s.damage == {}
    tgt = s.targets[key]
    assert tgt.final.estimate.status.value == "converged"
    # the target's position in the local frame: the emitter puts it at (40, 30, 0)
    assert np.allclose(tgt.final.target_pos_ned_m, (40.0, 30.0, 0.0), atol=0.05 * 18.0)
    # the emitter's bearing errors are white: the innovations say so (|lag-1| < 0.1)
    ic = tgt.noise.innovation_corr
    assert ic is not None and abs(ic.lag1) < 0.1 and ic.pairs > 30
    # (the target's own lines: the camera case's gimbal, pointed only roughly at the target
    # by design, is a second target whose bearing errors are systematic, and says so)
    own = s.text().split(f"target '{TARGET_OF[bearing]}' from ")[1].split("bearing source:")[0]
    assert "white, as the covariance assumes" in own and "WARNING" not in own


def test_real_simulator_flight_finds_the_region_of_interest(tmp_path: Path) -> None:
    """ArduCopter SITL with a servo mount pointed at an ROI 40 m north, 30 m east of home,
    default settings with the body-relative gimbal setting: the whole log's smoothed estimate
    within 2 m of it (1.6 m measured), the filter's final one within 1 m (0.6 m) and its median
    over the last third within 6 m (4.7 m: the servo's slow pointing errors make it re-acquire
    about ten times, docs/tuning.md)."""
    log = TLOGS / "ardupilot_sitl_servo_mount_roi.tlog"
    roi = np.array([40.0, 30.0, 0.01])  # home is at local (0, 0, 0.01)
    out = tmp_path / "body.jsonl"
    s = rp.replay(
        str(log), tracker_config=TrackerConfig(gimbal_angles="body"), output_jsonl=out, smooth=True
    )
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    t = np.array([r["t_boot_s"] for r in recs])
    # every record keeps its bearing's arrival (tlog) time, the first one's included
    assert all(1.7e9 < r["t_unix_s"] < 1.9e9 for r in recs)
    tp = np.array([r["target_pos_ned_m"] or [np.nan] * 3 for r in recs], dtype=float)
    third = t >= t[0] + 2.0 / 3.0 * (t[-1] - t[0])
    assert float(np.nanmedian(np.linalg.norm(tp[third] - roi, axis=1))) < 6.0
    assert float(np.linalg.norm(tp[-1] - roi)) < 1.0
    smoothed = np.array(s.smoothed_final["1/gimbal"][1])
    assert float(np.linalg.norm(smoothed - roi)) < 2.0
    # one per bearing from the first LOCAL_POSITION_NED on (1635), that of the bearing at its
    # very time included; live, that one is withheld (it arrives just before the velocity)
    assert s.targets["1/gimbal"].estimates == 1635
    live = rp.replay(str(log), tracker_config=TrackerConfig(gimbal_angles="body"), live=True)
    assert live.targets["1/gimbal"].estimates == 1634
    assert s.events["reacquired"] >= 1  # counted, and said
    # and timed: from each re-seeding to the next converged estimate (none here: to the end)
    nz = s.targets["1/gimbal"].noise
    assert nz is not None and nz.reacquisitions == s.events["reacquired"]
    assert 10.0 < nz.reacquiring_s <= t[-1] - t[0]


def test_the_sitl_servo_mounts_body_angles_are_found_with_the_default_settings(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The servo mount flags its roll and pitch as horizon-relative but sends body angles:
    with the default ``gimbal_angles = "auto"`` the tracker finds out once the vehicle
    manoeuvres (54 s into the log, 2 s into the first manoeuvre), says so, and reads them as
    body angles, the bearings read before left out of ``--smooth`` (1.3 m from the ROI);
    told ``flags`` it does not."""
    log = TLOGS / "ardupilot_sitl_servo_mount_roi.tlog"
    roi = np.array([40.0, 30.0, 0.01])
    with caplog.at_level("WARNING", logger="mav_observer.tracking.tracker"):
        s = rp.replay(str(log), smooth=True)
    assert s.events["gimbal_angles_body"] == 1
    assert s.gimbal_angles == {"1/1": "body"}
    assert "vehicle 1 gimbal 1 read as body-relative" in s.text()
    smoothed = s.smoothed_final["1/gimbal"][1]
    assert float(np.linalg.norm(np.array(smoothed) - roi)) < 2.0
    assert "gimbal_angles_flags" not in s.events
    said = [r.getMessage() for r in caplog.records if "body-relative" in r.getMessage()]
    assert len(said) == 1 and "from 54.3 s" in said[0], said
    told = rp.replay(str(log), tracker_config=TrackerConfig(gimbal_angles="flags"))
    assert "gimbal_angles_body" not in told.events


def test_the_sitl_servo_mounts_systematic_bearing_errors_are_flagged() -> None:
    """The servo mount's pointing errors wander over seconds (``docs/geolocation.md``): the
    innovations' lag-1 correlation says so (0.99 measured), in the summary's text as a
    warning and in its JSON, where the emitter's white bearings read below 0.1."""
    s = rp.replay(str(TLOGS / "ardupilot_sitl_servo_mount_roi.tlog"))
    ic = s.targets["1/gimbal"].noise.innovation_corr
    assert ic is not None and ic.lag1 > 0.8 and ic.corr_time_s > 1.0
    text = s.text()
    assert "WARNING: innovations from one bearing to the next: correlation" in text
    assert "target_h_std_m is likely too small" in text
    noise = s.to_dict()["targets"]["1/gimbal"]["noise"]
    assert noise["innovation_lag1"] == pytest.approx(ic.lag1, abs=1e-4)
    assert noise["innovation_corr_time_s"] == pytest.approx(ic.corr_time_s, abs=1e-4)


def test_damaged_logs_replay_to_the_end_with_the_damage_counted() -> None:
    holes = rp.replay(
        str(TLOGS / "bad_zeroholes_tsback_132613.tlog"),
        tracker_config=TrackerConfig(sources=("home",)),
    )
    assert holes.damage == {"resyncs": 2, "skipped_bytes": 4731, "time_backwards": 2}
    assert holes.targets["10/home"].estimates == 511  # every LOCAL_POSITION_NED, through the holes
    assert holes.events["autopilot_reboot"] == 2  # the second writer's older stretch
    rov = rp.replay(str(TLOGS / "gimbal_ardusub_bluerov_small.tlog"))
    # one per MOUNT_STATUS from the first velocity on: the one before it (its time is its
    # arrival's) is estimated live (792), not once committed (791)
    assert rov.skipped["bad_crc"] == 1 and rov.targets["1/mount_status"].estimates == 791
    with pytest.raises(rp.ReplayError) as err:
        rp.replay(str(TLOGS / "bad_truncated_lastrec_124019.tlog"))
    assert err.value.exit_code == 3
    assert err.value.summary.damage == {"skipped_bytes": 14, "truncated_tail": 1}


def test_the_home_point_of_a_real_flight(tmp_path: Path) -> None:
    """Validation on real data: a synthetic bearing to home (from HOME_POSITION) with the
    vehicle's real velocity; the observer finds home within a few metres."""
    s = rp.replay(
        str(TLOGS / "real_copter_phoenix_m2.tlog"),
        tracker_config=TrackerConfig(
            sources=("home",), observer=ObserverConfig(initial_range_m=50.0)
        ),
    )
    t = s.targets["1/home"]
    assert t.estimates > 900
    home_err = np.linalg.norm(
        np.array(t.final.target_pos_ned_m)
        - np.array(t.final.vehicle_pos_ned_m)
        - t.final.estimate.x_m
    )
    assert home_err < 1e-9  # consistency of the record
    assert t.final.estimate.range_m > 0


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mav_observer.app.cli", *args],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip


def test_no_bearing_gives_a_clear_nonzero_exit_listing_what_was_found() -> None:
    proc = _cli("replay", str(TLOGS / "real_copter_bruno_mission_132614.tlog"))
    assert proc.returncode == 3
    assert "no usable bearing stream" in proc.stderr
    assert "The log has: HEARTBEAT 489" in proc.stderr and "LOCAL_POSITION_NED 464" in proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "x.tlog: the file is empty"),
        (b"hello, this is not a tlog\n" * 50, "x.tlog: no messages found (tlog"),
    ],
)
def test_empty_and_foreign_files(tmp_path: Path, content: bytes, message: str) -> None:
    p = tmp_path / "x.tlog"
    p.write_bytes(content)
    proc = _cli("replay", str(p))
    assert proc.returncode == 3 and message in proc.stderr and "Traceback" not in proc.stderr


def test_missing_file_and_unwritable_output(tmp_path: Path) -> None:
    proc = _cli("replay", str(tmp_path / "nowhere.tlog"))
    assert proc.returncode == 1 and "no such file" in proc.stderr and "Traceback" not in proc.stderr
    proc = _cli(
        "replay",
        str(TLOGS / "gimbal_ardusub_bluerov_small.tlog"),
        "-o",
        str(tmp_path / "no/dir/x.jsonl"),
    )
    assert proc.returncode == 1 and "cannot write output" in proc.stderr


@pytest.mark.slow
def test_command_line_files_and_plot(emitted, tmp_path: Path) -> None:
    tl, truth = emitted["landing_target"]
    out, csv_path, plot, summ = (tmp_path / n for n in ("e.jsonl", "e.csv", "r.png", "s.json"))
    proc = _cli(
        "replay", str(tl), "-o", str(out), "--csv", str(csv_path), "--plot", str(plot),
        "--truth", str(truth), "--summary-json", str(summ),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    recs = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(recs) == 3000 and {r["schema"] for r in recs} == {1}
    assert {r["target"] for r in recs} == {"landing_target_0"}
    rows = list(csv.reader(csv_path.open()))
    assert len(rows) == 3001 and rows[0][0] == "t_unix_s"
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and plot.stat().st_size > 20_000
    doc = json.loads(summ.read_text())
    assert doc["truth_last_third"]["1/landing_target_0"]["max_rel_pos_err"] < 0.05
    lines = proc.stdout.splitlines()
    assert lines[0].startswith("source:") and any("enough excitation" in x for x in lines)
    assert any(x.startswith("against truth, 1/landing_target_0") for x in lines)


# -- damaged files: replay to the end, or a clear message; never a traceback ---------------


def _no_traceback(proc: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr[-2000:]
    assert proc.returncode in (0, 1, 3), (proc.returncode, proc.stderr[-2000:])


@pytest.mark.slow
@pytest.mark.parametrize("log", sorted(p.name for p in TLOGS.glob("*.tlog")))
def test_every_shared_log_replays_or_says_why(tmp_path: Path, log: str) -> None:
    proc = _cli("replay", str(TLOGS / log), "--output", str(tmp_path / "out.jsonl"))
    _no_traceback(proc)
    if proc.returncode:  # damaged or without a bearing stream: replayed as far as it goes
        assert proc.stderr.strip().splitlines()[-1], "a message saying why"
        assert "Skipped messages by reason" in proc.stderr


def _tlog_records(data: bytes) -> list[tuple[int, int]]:
    """(offset, length) of each record of an undamaged tlog: 8-byte time, then a frame."""
    out, i = [], 0
    while i + 10 < len(data):
        magic = data[i + 8]
        n = data[i + 9]
        flen = (12 + n + (13 if data[i + 10] & 1 else 0)) if magic == 0xFD else 8 + n
        out.append((i, 8 + flen))
        i += 8 + flen
    return out


@pytest.mark.slow
def test_damaged_copies_of_an_emitter_log(emitted, tmp_path: Path) -> None:
    """Zero holes, a cut tail, the fuzz test's 100,000 garbage frames spliced in as records
    (same seed), an empty file and a file that is not a tlog: each replays to its end or stops
    with a clear message."""
    src = emitted["gimbal"][0].read_bytes()
    rng = np.random.default_rng(5)
    holes = bytearray(src)
    for start in rng.integers(0, len(src) - 4096, 20):
        n = int(rng.integers(16, 4096))
        holes[start : start + n] = bytes(n)
    records = _tlog_records(src)
    spliced = bytearray()
    garbage = [f for _, f in fuzz.garbage(np.random.default_rng(2026), 100_000)]
    per = len(garbage) / len(records)
    g = 0
    for k, (off, length) in enumerate(records):
        rec = src[off : off + length]
        spliced += rec
        while g < (k + 1) * per:  # the same timestamp, a damaged frame
            spliced += rec[:8] + garbage[g]
            g += 1
    files = {
        "holes.tlog": bytes(holes),
        "cut.tlog": src[: records[len(records) // 2][0] + 20],  # inside a frame
        "spliced.tlog": bytes(spliced),
        "empty.tlog": b"",
        "notes.txt": b"these are not the bytes you are looking for\n" * 100,
    }
    results = {}
    for name, data in files.items():
        p = tmp_path / name
        p.write_bytes(data)
        results[name] = proc = _cli("replay", str(p), "--output", str(tmp_path / f"{name}.jsonl"))
        _no_traceback(proc)
    for name in ("holes.tlog", "cut.tlog", "spliced.tlog"):  # to the end, the damage reported
        assert results[name].returncode == 0, results[name].stderr[-2000:]
    assert "damage: " in results["holes.tlog"].stdout
    assert "truncated_tail 1" in results["cut.tlog"].stdout
    last = json.loads((tmp_path / "spliced.tlog.jsonl").read_text().splitlines()[-1])
    assert last["status"] == "converged", results["spliced.tlog"].stdout[-3000:]
    assert np.allclose(last["target_pos_ned_m"], (40.0, 30.0, 0.0), atol=0.05 * 18.0)
    for name in ("empty.tlog", "notes.txt"):
        assert results[name].returncode != 0
        assert results[name].stderr.strip(), name  # a message, not silence


@pytest.mark.slow
def test_a_full_disk_stops_the_replay_with_a_message(emitted) -> None:
    """Writing the estimates fails with ENOSPC (``/dev/full`` is a disk that is always full):
    a clear message and exit code 1, no traceback."""
    proc = _cli("replay", str(emitted["gimbal"][0]), "--output", "/dev/full")
    assert proc.returncode == 1
    assert "cannot write output: [Errno 28] No space left on device" in proc.stderr
    assert "Traceback" not in proc.stderr


# -- replay takes the service's settings ---------------------------------------------------


def _final(summary_json: Path) -> dict:
    return json.loads(summary_json.read_text())["targets"]["1/gimbal"]["final"]


@pytest.mark.slow
def test_replay_config_changes_what_it_should(emitted, tmp_path: Path) -> None:
    # the run's settings file: its [observer] and [tracker] tables change the replay; the
    # service-only tables are checked and ignored; a flag wins over the file
    tl, _ = emitted["gimbal"]
    plain = tmp_path / "plain.json"
    assert main(["replay", str(tl), "-q", "--summary-json", str(plain)]) == 0
    f = tmp_path / "svc.toml"
    f.write_text(
        '[observer]\nestimator = "paper"\nk_per_s = 0.3\n[zenoh]\nmode = "peer"\n'
        '[mavlink]\nurl = "udpin:127.0.0.1:14551"\n'
    )
    paper = tmp_path / "paper.json"
    assert main(["replay", str(tl), "-q", "--config", str(f), "--summary-json", str(paper)]) == 0
    assert _final(paper)["range_std_m"] is None  # the paper's observer: no covariance
    assert _final(plain)["range_std_m"] is not None
    assert _final(paper)["rel_pos_ned_m"] != _final(plain)["rel_pos_ned_m"]
    k5 = tmp_path / "k5.json"
    assert (
        main(["replay", str(tl), "-q", "--config", str(f), "--k", "0.5", "--summary-json", str(k5)])
        == 0
    )
    assert _final(k5)["rel_pos_ned_m"] != _final(paper)["rel_pos_ned_m"]
    # the noise told moves the default estimator's uncertainty
    noisy = tmp_path / "noisy.json"
    args = ["replay", str(tl), "-q", "--bearing-noise-deg", "2", "--summary-json", str(noisy)]
    assert main(args) == 0
    assert _final(noisy)["range_std_m"] > 1.2 * _final(plain)["range_std_m"]
    # the tracker table too: only this source (there is none of it in the log)
    f.write_text('[tracker]\nsources = ["landing_target"]\n')
    assert main(["replay", str(tl), "-q", "--config", str(f)]) == 3


def test_a_flag_for_the_other_estimator_is_a_clear_error(tmp_path: Path, capsys) -> None:
    tl = TLOGS / "ardupilot_sitl_servo_mount_roi.tlog"
    assert main(["replay", str(tl), "-q", "--k", "0.5"]) == 2
    err = capsys.readouterr().err
    assert "k_per_s applies to the 'paper' estimator only (this one is 'riccati')" in err
    assert "--estimator paper" in err
    f = tmp_path / "bad.toml"
    f.write_text("[observer]\nbearing_noise_deg = 1.0\nestimator = 'paper'\n")
    assert main(["replay", str(tl), "-q", "--config", str(f)]) == 2
    assert (
        "bad.toml: observer.bearing_noise_deg applies to the 'riccati'" in capsys.readouterr().err
    )
    f.write_text("[observer]\nbearing_noise = 1.0\n")
    assert main(["replay", str(tl), "-q", "--config", str(f)]) == 2
    assert "unknown setting observer.bearing_noise" in capsys.readouterr().err


def _send_live(port: int) -> threading.Thread:
    """The emitter flying the orbit for 40 s of scenario time, 20 times faster, to a udpin
    port on 127.0.0.1, starting 0.5 s from now (the replay's link opens first)."""
    em = Emitter(scenarios.orbit(), EmitterConfig(bearing="gimbal", duration_s=40.0, seed=2))

    def go() -> None:
        time.sleep(0.5)
        run(em, to=f"udpout:127.0.0.1:{port}", speed=20.0)

    th = threading.Thread(target=go, daemon=True)
    th.start()
    return th


@pytest.mark.slow
def test_replay_without_a_source_reads_the_settings_mavlink_link(tmp_path: Path, capsys) -> None:
    # no SOURCE: the [mavlink] url of the settings file, read live; its signing key applies
    port = free_port(socket.SOCK_DGRAM)
    f = tmp_path / "svc.toml"
    f.write_text(f'[mavlink]\nurl = "udpin:127.0.0.1:{port}"\n')
    out = tmp_path / "live.json"
    th = _send_live(port)
    assert main(["replay", "--config", str(f), "--duration", "3", "-q", "--summary-json",
                 str(out)]) == 0  # fmt: skip
    th.join(10.0)
    doc = json.loads(out.read_text())
    assert doc["source"] == f"udpin:127.0.0.1:{port}"
    assert doc["targets"]["1/gimbal"]["estimates"] > 100
    # with a signing key, the unsigned stream is refused and counted: nothing usable
    key = tmp_path / "key"
    key.write_text("a passphrase only we know")
    key.chmod(0o600)
    port = free_port(socket.SOCK_DGRAM)
    f.write_text(f'[mavlink]\nurl = "udpin:127.0.0.1:{port}"\nsigning_key_file = "{key}"\n')
    th = _send_live(port)
    assert main(["replay", "--config", str(f), "--duration", "3", "-q"]) == 3
    th.join(10.0)
    assert "unsigned" in capsys.readouterr().err
    # neither a SOURCE nor a settings file: a usage error, not a silent listen
    assert main(["replay", "-q"]) == 2
    assert "replay needs a SOURCE" in capsys.readouterr().err


@pytest.mark.slow
def test_smooth_writes_the_whole_logs_estimate_with_its_uncertainty(
    emitted, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """replay --smooth FILE on the emitted orbit: one smoothed record per bearing, within
    5 cm of the truth over the whole run (the filter starts 20 m off), honest standard
    deviations; the summary says where the target is and how sure."""
    tl, truth_path = emitted["gimbal"]
    out = tmp_path / "smoothed.jsonl"
    assert main(["replay", str(tl), "--smooth", str(out), "--summary-json",
                 str(tmp_path / "s.json")]) == 0  # fmt: skip
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    truth = reference.read(truth_path)["1/gimbal"]
    assert len(recs) > 2900 and {r["schema"] for r in recs} == {1}
    t_truth = np.array(truth["t_boot_s"])
    x_truth = np.array(truth["rel_pos_ned_m"])
    t = np.array([r["t_boot_s"] for r in recs])
    x = np.array([r["rel_pos_ned_m"] for r in recs])
    sd = np.array([r["rel_pos_std_ned_m"] for r in recs])
    xt = np.column_stack([np.interp(t, t_truth, x_truth[:, i]) for i in range(3)])
    err = x - xt
    assert float(np.sqrt(np.mean(np.sum(err**2, axis=1)))) < 0.05
    assert 0.2 < float(np.mean((err / sd) ** 2)) < 5.0
    assert np.allclose([r["target_pos_ned_m"] for r in recs][-1], (40.0, 30.0, 0.0), atol=0.1)
    text = capsys.readouterr().out
    assert "smoothed over the whole log (1 of 1 windows fitted)" in text
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["targets"]["1/gimbal"]["smoothed"]["1/gimbal"]["windows_fitted"] == 1
    assert summary["targets"]["1/gimbal"]["noise"]["bearing_noise_learnt"] is True


@pytest.mark.slow
def test_replay_live_publishes_what_the_service_would(tmp_path: Path) -> None:
    """``replay --live``: each bearing's estimate at its arrival, as the service publishes
    it; without, once committed (here the BlueROV log's first MOUNT_STATUS, before the first
    velocity, has a live estimate only). The flag's output is the API's ``live=True``."""
    log = str(TLOGS / "gimbal_ardusub_bluerov_small.tlog")
    counts = {}
    for flag in ("--live", None):
        out = tmp_path / f"{flag}.jsonl"
        proc = _cli("replay", log, "-q", "-o", str(out), *([flag] if flag else []))
        assert proc.returncode == 0, proc.stderr
        counts[flag] = len(out.read_text().splitlines())
    assert counts == {"--live": 792, None: 791}
    api = tmp_path / "api.jsonl"
    rp.replay(log, output_jsonl=api, live=True)
    assert api.read_text() == (tmp_path / "--live.jsonl").read_text()


@pytest.mark.parametrize("fmt", ["bin", "ulg"])
def test_a_dataflash_or_ulog_twin_replays_to_the_tlogs_estimate(tmp_path: Path, fmt: str) -> None:
    """The same flight as its tlog, an ArduPilot .bin and a PX4 .ulg (``sim convert``): the
    format is found from the content, and the final estimate is the tlog's."""
    from sim import logwriters

    sc = scenarios.make("orbit")
    cfg = EmitterConfig(bearing="gimbal", duration_s=60.0, seed=4, bearing_noise_deg=0.5)
    tlog = tmp_path / "f.tlog"
    run(Emitter(sc, cfg), tlog=tlog)
    twin = tmp_path / "f.log"  # a name that says nothing
    logwriters.convert(tlog, tmp_path / f"f.{fmt}")
    (tmp_path / f"f.{fmt}").rename(twin)
    a = rp.replay(str(tlog))
    b = rp.replay(str(twin))
    assert b.log_format == {"bin": "DataFlash", "ulg": "ULog"}[fmt]
    ta = next(iter(a.targets.values())).final
    tb = next(iter(b.targets.values())).final
    assert ta is not None and tb is not None
    rel_a = np.array(ta.estimate.x_m)
    rel_b = np.array(tb.estimate.x_m)
    assert np.linalg.norm(rel_b - rel_a) < 0.002 * np.linalg.norm(rel_a)


@pytest.mark.parametrize(
    ("damage", "says"),
    [
        ("truncated", "truncated_tail 1"),
        ("junk", "resyncs"),
        ("foreign", "neither a tlog, a DataFlash .bin, a ULog nor raw MAVLink"),
        ("formats_only", "no messages found (DataFlash"),
    ],
)
def test_a_damaged_dataflash_log_gives_a_clear_message_and_what_was_readable(
    tmp_path: Path, damage: str, says: str
) -> None:
    from sim import logwriters

    sc = scenarios.make("orbit")
    tlog = tmp_path / "f.tlog"
    run(Emitter(sc, EmitterConfig(bearing="gimbal", duration_s=30.0, seed=1)), tlog=tlog)
    good = tmp_path / "good.bin"
    logwriters.convert(tlog, good)
    data = good.read_bytes()
    bad = tmp_path / "bad.bin"
    if damage == "truncated":
        bad.write_bytes(data[:-5])
    elif damage == "junk":
        bad.write_bytes(data[:5000] + b"\x55" * 333 + data[5000:])
    elif damage == "foreign":
        bad.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(2000))
    else:
        fmt_only = b"".join(data[i : i + 89] for i in range(0, len(data), 89)
                            if data[i : i + 3] == b"\xa3\x95\x80")  # fmt: skip
        bad.write_bytes(fmt_only[:89])
    proc = _cli("replay", str(bad))
    out = proc.stdout + proc.stderr
    assert "Traceback" not in out and says in out and "bad.bin" in out
    assert proc.returncode == (0 if damage in ("truncated", "junk") else 3)


@pytest.mark.parametrize("fmt", ["tlog", "bin", "ulg"])
def test_a_gimbal_rangefinder_makes_a_hovering_flight_converge_in_every_format(
    tmp_path: Path, fmt: str
) -> None:
    """A hovering vehicle (no motion: bearings alone cannot tell the range) with a laser
    rangefinder on its gimbal: DISTANCE_SENSOR in the tlog, MNT's Dist in the .bin, PX4's
    distance_sensor in the .ulg; converged within 2 s of the first bearing, within 0.5 % of
    the range at the end."""
    from sim import logwriters

    sc = scenarios.make("hover", duration_s=30.0)
    cfg = EmitterConfig(bearing="gimbal", duration_s=30.0, seed=5, bearing_noise_deg=0.5,
                        rangefinder_noise_m=0.3)  # fmt: skip
    tlog = tmp_path / "h.tlog"
    run(Emitter(sc, cfg), tlog=tlog)
    src = tlog
    if fmt != "tlog":
        src = tmp_path / f"h.{fmt}"
        logwriters.convert(tlog, src)
    out = tmp_path / "est.jsonl"
    rp.replay(str(src), tracker_config=TrackerConfig(range_noise_m=0.3), output_jsonl=out)
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    t0 = recs[0]["t_boot_s"]
    first = next(r["t_boot_s"] for r in recs if r["status"] == "converged")
    assert first - t0 <= 2.0
    truth = np.array(sc.x(0.0))
    err = np.linalg.norm(np.array(recs[-1]["rel_pos_ned_m"]) - truth)
    assert err <= 0.005 * np.linalg.norm(truth)
