"""The software MAVLink emitter (sim/emitter.py), checked against real peers."""

import json
import math
import queue
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from mav_observer.mavlink.tlog import TlogReader
from sim import scenarios
from sim.emitter import BEARINGS, Emitter, EmitterConfig, run


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def emit(tmp_path: Path, name: str = "e", **kw) -> tuple[Path, Path, Emitter]:
    sc = kw.pop("scenario", scenarios.orbit(duration_s=kw.get("duration_s", 20.0)))
    em = Emitter(sc, EmitterConfig(**{"duration_s": 20.0, **kw}))
    tl, tr = tmp_path / f"{name}.tlog", tmp_path / f"{name}.jsonl"
    run(em, tlog=tl, truth=tr)
    return tl, tr, em


def counts(path: Path) -> Counter[str]:
    return Counter(m.get_type() for _, m in TlogReader(path))


def test_streams_and_rates(tmp_path: Path) -> None:
    tl, tr, _ = emit(tmp_path, background_hz=100.0)
    c = counts(tl)
    assert c["HEARTBEAT"] == 20 and c["SYSTEM_TIME"] == 20 and c["SYS_STATUS"] == 20
    assert c["ATTITUDE"] == 400 and c["ATTITUDE_QUATERNION"] == 400
    assert c["LOCAL_POSITION_NED"] == 200 and c["GLOBAL_POSITION_INT"] == 200
    assert c["GIMBAL_DEVICE_ATTITUDE_STATUS"] == 200
    assert 1900 <= c["VFR_HUD"] * 10 <= 2100  # ten background types, 100 messages/s in all
    truth = [json.loads(x) for x in tr.read_text().splitlines()]
    assert len(truth) == 200
    for d in truth[::37]:
        assert np.allclose(
            np.add(d["vehicle_pos_ned_m"], d["rel_pos_ned_m"]), d["target_pos_ned_m"]
        )
        assert d["bias_ned_mps"] == [-3.0, 2.0, 0.0] and d["target"] == "gimbal"


@pytest.mark.parametrize("bearing", BEARINGS)
def test_every_bearing_stream_is_emitted(tmp_path: Path, bearing: str) -> None:
    tl, tr, _ = emit(tmp_path, bearing=bearing, duration_s=5.0)
    c = counts(tl)
    expected = {
        "gimbal": "GIMBAL_DEVICE_ATTITUDE_STATUS",
        "gimbal_earth": "GIMBAL_DEVICE_ATTITUDE_STATUS",
        "camera": "CAMERA_TRACKING_IMAGE_STATUS",
        "mount": "MOUNT_ORIENTATION",
        "mount_status": "MOUNT_STATUS",
        "landing_target": "LANDING_TARGET",
        "landing_target_local": "LANDING_TARGET",
    }[bearing]
    assert c[expected] == 50
    assert len(tr.read_text().splitlines()) == 50
    if bearing == "camera":
        assert c["CAMERA_FOV_STATUS"] == 5


def test_noise_drops_and_latency(tmp_path: Path) -> None:
    _, tr, _ = emit(tmp_path, drop_prob=0.3, latency_s=0.25, duration_s=60.0, seed=3)
    truth = [json.loads(x) for x in tr.read_text().splitlines()]
    assert 0.6 * 600 < len(truth) < 0.8 * 600
    lag = np.array([d["t_unix_s"] for d in truth]) - (
        1_767_225_600.0 + np.array([d["t_boot_s"] for d in truth]) - 120.0
    )
    assert np.allclose(lag, 0.25, atol=1e-6)


def bearing_errors_deg(em: Emitter) -> np.ndarray:
    """The angle between each emitted gimbal bearing and its truth's line of sight."""
    from mav_observer.mavlink.dialect import codec
    from mav_observer.tracking import directions as adapters

    dec = codec()
    out = []
    for e in em.emissions():
        if e.truth is None:
            continue
        m = dec.decode(bytearray(e.frame))
        assert m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"
        b = np.array(
            adapters.gimbal_boresight(
                tuple(m.q), m.flags, 0, vehicle_yaw=e.truth["attitude_rpy_rad"][2]
            )
        )
        los = np.array(e.truth["rel_pos_ned_m"])
        los /= np.linalg.norm(los)
        out.append(math.degrees(math.acos(min(1.0, float(b @ los)))))
    return np.array(out)


@pytest.mark.slow
def test_bearing_outliers_are_a_share_of_gross_errors_off_the_true_line_of_sight() -> None:
    p, sigma = 0.2, 0.5
    cfg = EmitterConfig(duration_s=200.0, bearing_noise_deg=sigma, outlier_prob=p, seed=11)
    em = Emitter(scenarios.orbit(duration_s=200.0), cfg)
    err = bearing_errors_deg(em)
    n = len(err)
    assert n == 2000
    out = err > 4.0  # the Gaussian part (0.5 deg per axis) passes 4 deg once in 10^14
    k = int(out.sum())
    assert abs(k - p * n) < 4.0 * math.sqrt(n * p * (1 - p))  # binomial, 4 sigma
    assert err[out].min() >= 5.0 - 1e-3 and err[out].max() <= 30.0 + 1e-3
    assert np.mean(err[out]) == pytest.approx(17.5, abs=2.0)  # uniform in [5, 30] deg
    # the rest is the Gaussian noise about the truth's line of sight (a Rayleigh angle: the
    # truth is the true line of sight, not the outlier)
    assert err[~out].max() < 5.0 * sigma
    assert np.median(err[~out]) == pytest.approx(sigma * math.sqrt(2 * math.log(2)), rel=0.1)


@pytest.mark.slow
def test_student_t_bearing_noise_has_the_same_spread_and_heavier_tails() -> None:
    """``bearing_noise_dof`` 3: the angle off the true line of sight has the Gaussian's
    mean square (2 sigma^2 over the two tangent axes) but far more errors beyond 4 sigma."""
    sigma = 0.5
    sc = scenarios.orbit(duration_s=600.0)
    err = {
        dof: bearing_errors_deg(
            Emitter(
                sc,
                EmitterConfig(
                    duration_s=600.0, bearing_noise_deg=sigma, bearing_noise_dof=dof, seed=3
                ),
            )
        )
        for dof in (math.inf, 3.0)
    }
    for e in err.values():
        assert len(e) == 6000
    assert float(np.mean(err[math.inf] ** 2)) == pytest.approx(2 * sigma**2, rel=0.06)
    # the t's variance converges slowly (its fourth moment is infinite): a loose check
    assert float(np.mean(err[3.0] ** 2)) == pytest.approx(2 * sigma**2, rel=0.35)
    far = {dof: int(np.sum(e > 4.0 * sigma)) for dof, e in err.items()}
    assert far[math.inf] <= 8 and far[3.0] >= 30, far  # Rayleigh: 3e-4 of 6000; t(3): ~1 %
    assert np.median(err[3.0]) < np.median(err[math.inf])  # the mass moves to the centre


def test_no_outliers_leaves_the_random_stream_and_the_frames_as_they_were() -> None:
    base = {"duration_s": 30.0, "bearing_noise_deg": 0.5, "velocity_noise_mps": 0.1}
    base |= {"drop_prob": 0.1, "seed": 5}
    sc = scenarios.orbit(duration_s=30.0)
    plain = list(Emitter(sc, EmitterConfig(**base)).emissions())
    zero = list(Emitter(sc, EmitterConfig(**base, outlier_prob=0.0)).emissions())
    assert [e.frame for e in zero] == [e.frame for e in plain]
    assert [e.truth for e in zero] == [e.truth for e in plain]
    some = list(Emitter(sc, EmitterConfig(**base, outlier_prob=0.05)).emissions())
    assert [e.frame for e in some] != [e.frame for e in plain]


def test_pacing_real_time_and_speed_factor(tmp_path: Path) -> None:
    em = Emitter(scenarios.orbit(), EmitterConfig(duration_s=2.0))
    t0 = time.monotonic()
    run(em, tlog=tmp_path / "paced.tlog", speed=10.0)
    assert 0.18 <= time.monotonic() - t0 < 1.5
    stop = threading.Event()
    stop.set()
    rep = run(
        Emitter(scenarios.orbit(), EmitterConfig(duration_s=100.0)),
        tlog=tmp_path / "s.tlog",
        speed=1.0,
        stop=stop,
    )
    assert rep.messages == 0


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="bearing must be one of"):
        EmitterConfig(bearing="radar")
    with pytest.raises(ValueError, match="attitude_hz must be > 0"):
        EmitterConfig(attitude_hz=0.0)
    with pytest.raises(ValueError, match="outlier_prob"):
        EmitterConfig(outlier_prob=1.0)
    with pytest.raises(ValueError, match="outlier_min_deg"):
        EmitterConfig(outlier_min_deg=-1.0)
    with pytest.raises(ValueError, match="outlier_max_deg"):
        EmitterConfig(outlier_min_deg=10.0, outlier_max_deg=5.0)
    with pytest.raises(ValueError, match="bearing_noise_dof must be > 2"):
        EmitterConfig(bearing_noise_dof=2.0)
    with pytest.raises(ValueError, match="n=2"):
        Emitter(scenarios.planar(), EmitterConfig())


def test_pymavlink_mavlogdump_reads_the_emitter_tlog_cleanly(tmp_path: Path) -> None:
    tl, _, _ = emit(tmp_path, bearing="camera", duration_s=10.0, background_hz=50.0)
    dump = Path(sys.executable).with_name("mavlogdump.py")
    proc = subprocess.run(
        [sys.executable, str(dump), "--format", "json", str(tl)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(x) for x in proc.stdout.splitlines() if x.startswith("{")]
    types = Counter(d["meta"]["type"] for d in lines)
    assert "BAD_DATA" not in types
    assert types == counts(tl)


@pytest.mark.slow
def test_mavsdk_sees_an_autopilot_with_the_scenario_attitude_and_velocity() -> None:
    """MAVSDK (C++ library, Python binding) as a ground station on 127.0.0.1 finds the emitter,
    and the attitude and NED velocity it reports are the scenario's truth."""
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.telemetry import Telemetry

    port = free_udp_port()
    sc = scenarios.straight_pass()  # constant velocity for the first 32 s
    em = Emitter(sc, EmitterConfig(duration_s=8.0))
    stop = threading.Event()
    th = threading.Thread(
        target=run,
        args=(em,),
        kwargs={"to": f"udpout:127.0.0.1:{port}", "speed": 1.0, "stop": stop},
    )
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    euler: queue.Queue = queue.Queue()
    posvel: queue.Queue = queue.Queue()
    try:
        with Mavsdk(cfg) as drone:
            drone.add_any_connection_with_handle(f"udpin://127.0.0.1:{port}")
            th.start()
            system = drone.first_autopilot(10.0)
            assert system is not None
            assert system.autopilot_type().name == "ARDUPILOT"
            tel = Telemetry(system)
            tel.subscribe_attitude_euler(lambda d, _u: euler.put(d))
            tel.subscribe_position_velocity_ned(lambda d, _u: posvel.put(d))
            got_e = [euler.get(timeout=5) for _ in range(10)]
            got_v = [posvel.get(timeout=5) for _ in range(5)]
    finally:
        stop.set()
        if th.is_alive():
            th.join(timeout=5)
        cfg.destroy()
    for e in got_e:
        t = e.timestamp_us * 1e-6 - em.config.boot_at_start_s  # MAVSDK keeps time_boot_ms
        s = em.vehicle.state(t)
        assert (e.roll_deg, e.pitch_deg, e.yaw_deg) == pytest.approx(
            tuple(math.degrees(a) for a in (s.roll, s.pitch, s.yaw)), abs=1e-3
        )
    want = em.vehicle.state(1.0).vel_meas_ned_mps
    for pv in got_v:
        got = (pv.velocity.north_m_s, pv.velocity.east_m_s, pv.velocity.down_m_s)
        assert got == pytest.approx(tuple(want), abs=1e-4)
