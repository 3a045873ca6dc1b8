"""Loopback: emitter -> UDP 127.0.0.1 -> the service (its own process) -> Zenoh 127.0.0.1 ->
a subscriber here. Free ports; every process started here is ended here."""

from __future__ import annotations

import bisect
import json
import math
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import free_tcp_port, wait_for

from mav_observer.outputs.zenoh_io import open_session, session_config
from sim import emitter, fuzz, scenarios
from sim.live import free_port, service_command, stop_process

pytestmark = pytest.mark.slow  # whole flights, loopback services or the end-to-end harness


@contextmanager
def service(
    mav_port: int, z_port: int, log: Path, *extra: str
) -> Iterator[subprocess.Popen[bytes]]:
    with open(log, "ab") as fh:
        proc = subprocess.Popen(
            service_command(mav_port, z_port, "--log-level", "INFO", *extra),
            stdout=fh,
            stderr=subprocess.STDOUT,
        )
    try:
        yield proc
    finally:
        stop_process(proc)


@contextmanager
def subscriber(z_port: int, mode: str = "peer") -> Iterator[Sink]:
    session = open_session(
        session_config(mode=mode, listen=[], connect=[f"tcp/127.0.0.1:{z_port}"]), retry_s=15.0
    )
    sink = Sink()
    session.declare_subscriber("mav_observer/**", sink.on_sample)
    session.liveliness().declare_subscriber("mav_observer/**", sink.on_alive, history=True)
    sink.session = session
    try:
        yield sink
    finally:
        session.close()


class Sink:
    """What the subscriber received: samples by key with their arrival time, liveliness."""

    def __init__(self) -> None:
        self.samples: list[tuple[float, str, dict[str, Any]]] = []
        self.alive: list[tuple[float, str, bool]] = []
        self.lock = threading.Lock()
        self.session: Any = None

    def on_sample(self, s: Any) -> None:
        with self.lock:
            self.samples.append(
                (time.monotonic(), str(s.key_expr), json.loads(s.payload.to_bytes()))
            )

    def on_alive(self, s: Any) -> None:
        import zenoh

        with self.lock:
            self.alive.append((time.monotonic(), str(s.key_expr), s.kind == zenoh.SampleKind.PUT))

    def of(self, key: str) -> list[tuple[float, dict[str, Any]]]:
        with self.lock:
            return [(t, d) for t, k, d in self.samples if k == key]


def connected(sink: Sink, timeout_s: float = 15.0) -> bool:
    s = sink.session
    return wait_for(lambda: list(s.info.peers_zid()) or list(s.info.routers_zid()), timeout_s)


def emit(
    port: int,
    *,
    duration_s: float,
    speed: float,
    sysid: int = 1,
    bearing: str = "gimbal",
    silent: tuple[tuple[float, float], ...] = (),
    truths: Truths | None = None,
    stop: threading.Event | None = None,
) -> tuple[threading.Thread, emitter.Emitter]:
    em = emitter.Emitter(
        scenarios.orbit(duration_s=duration_s),
        emitter.EmitterConfig(
            bearing=bearing,
            sysid=sysid,
            duration_s=duration_s,
            bearing_noise_deg=0.5,
            seed=sysid,
        ),
    )

    def keep(t: dict[str, Any]) -> None:
        if truths is not None:
            truths.add(t)

    th = threading.Thread(
        target=emitter.run,
        args=(em,),
        kwargs={
            "to": f"udpout:127.0.0.1:{port}",
            "speed": speed,
            "silent": silent,
            "on_truth": keep,
            "stop": stop,
        },
        daemon=True,
    )
    th.start()
    return th, em


class Truths:
    """The emitters' truth records by vehicle, matched to estimates by bearing time (the
    service maps a sensor's clock onto the autopilot's, within a few ms)."""

    def __init__(self) -> None:
        self.by_sysid: dict[int, tuple[list[float], list[dict[str, Any]]]] = {}

    def add(self, t: dict[str, Any]) -> None:
        times, recs = self.by_sysid.setdefault(t["sysid"], ([], []))
        times.append(t["t_boot_s"])
        recs.append(t)

    def at(self, sysid: int, t_boot_s: float, tol_s: float = 0.02) -> dict[str, Any] | None:
        times, recs = self.by_sysid.get(sysid, ([], []))
        i = bisect.bisect_left(times, t_boot_s)
        best = min(
            (j for j in (i - 1, i) if 0 <= j < len(times)),
            key=lambda j: abs(times[j] - t_boot_s),
            default=None,
        )
        if best is None or abs(times[best] - t_boot_s) > tol_s:
            return None
        return recs[best]


def errors(est: dict[str, Any], truth: dict[str, Any]) -> tuple[float, float]:
    """(position error relative to the range, bias error in m/s)."""
    xt = truth["rel_pos_ned_m"]
    rel = math.dist(est["rel_pos_ned_m"], xt) / math.hypot(*xt)
    return rel, math.dist(est["bias_ned_mps"], truth["bias_ned_mps"])


def ports() -> tuple[int, int]:
    return free_port(socket.SOCK_DGRAM), free_tcp_port()


def test_two_vehicles_gimbal_and_landing_target_converge_on_their_own_keys(
    tmp_path: Path,
) -> None:
    mav, zp = ports()
    truths = Truths()
    with service(mav, zp, tmp_path / "svc.log", "--estimate-rate-hz", "0"), subscriber(zp) as sink:
        assert connected(sink)
        listener = subprocess.Popen(
            [
                *(sys.executable, "-m", "mav_observer", "listen", "mav_observer/2/**"),
                *("--connect", f"tcp/127.0.0.1:{zp}", "--json", "--count", "5", "--duration", "30"),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        time.sleep(0.3)
        t1, _ = emit(mav, duration_s=150.0, speed=30.0, sysid=1, truths=truths)
        t2, _ = emit(
            mav, duration_s=150.0, speed=30.0, sysid=2, bearing="landing_target", truths=truths
        )
        t1.join(30)
        t2.join(30)
        time.sleep(0.3)
        try:
            listened, _ = listener.communicate(timeout=30)
        finally:
            stop_process(listener)
    # the listen command, as a user would run it: JSON lines of vehicle 2 only
    rows = [json.loads(x) for x in listened.splitlines()]
    assert len(rows) == 5 and listener.returncode == 0
    assert all(r["key"].startswith("mav_observer/2/") for r in rows)
    assert any(r.get("liveliness") == "alive" for r in rows)
    for sysid, target in ((1, "gimbal"), (2, "landing_target_0")):
        est = [d for _, d in sink.of(f"mav_observer/{sysid}/{target}/estimate")]
        assert len(est) > 1000, (sysid, target, len(est))
        assert {d["sysid"] for d in est} == {sysid}
        last_third = [d for d in est if d["t_boot_s"] >= est[-1]["t_boot_s"] - 50.0]
        matched = [(d, truths.at(sysid, d["t_boot_s"])) for d in last_third]
        errs = [errors(d, t) for d, t in matched if t is not None]
        assert len(errs) > 300
        assert max(e[0] for e in errs) < 0.05, (target, max(e[0] for e in errs))
        assert max(e[1] for e in errs) < 0.1
        assert last_third[-1]["status"] == "converged"
        status = [d for _, d in sink.of(f"mav_observer/{sysid}/status")]
        assert status and list(status[-1]["observers"]) == [target]
    # nobody else's keys
    keys = {k for _, k, _ in sink.samples}
    assert all(k.startswith(("mav_observer/1/", "mav_observer/2/")) for k in keys)


def test_router_mode_client_subscriber_queryable_liveliness_and_sigterm(tmp_path: Path) -> None:
    mav, zp = ports()
    stop = threading.Event()
    log = tmp_path / "svc.log"
    with service(mav, zp, log, "--zenoh-mode", "router") as proc, subscriber(zp, "client") as sink:
        assert connected(sink)
        time.sleep(0.3)
        th, _ = emit(mav, duration_s=600.0, speed=20.0, stop=stop)
        try:
            assert wait_for(lambda: sink.of("mav_observer/1/status"), 10.0)
            assert any(alive for _, k, alive in sink.alive if k == "mav_observer/1/alive")
            replies = {
                str(r.ok.key_expr): json.loads(r.ok.payload.to_bytes())
                for r in sink.session.get("mav_observer/1/**", timeout=3.0)
                if r.ok is not None
            }
            assert set(replies) == {"mav_observer/1/gimbal/estimate", "mav_observer/1/status"}
            assert replies["mav_observer/1/gimbal/estimate"]["target"] == "gimbal"
            assert replies["mav_observer/1/status"]["link"]["state"] == "up"
            # SIGTERM while data flows: a last status, the token goes, exit 0 within 2 s
            code, took = stop_process(proc)
            t_stopped = time.monotonic()
        finally:
            stop.set()
            th.join(5)
        assert code == 0, log.read_text()
        assert took < 2.0
        assert wait_for(
            lambda: [t for t, k, a in sink.alive if k == "mav_observer/1/alive" and not a], 2.0
        ), "the liveliness token did not disappear"
        gone = [t for t, k, a in sink.alive if k == "mav_observer/1/alive" and not a]
        assert gone[0] <= t_stopped + 1.0
        last = sink.of("mav_observer/1/status")[-1][1]
        assert last["service"]["state"] == "stopping"
    assert "stopped after" in log.read_text()


def test_a_pause_longer_than_the_stale_time_then_estimates_again(tmp_path: Path) -> None:
    mav, zp = ports()
    # 40-70 s of the scenario silent: 3 s of wall time at 10x; stale after 1 s
    with (
        service(mav, zp, tmp_path / "svc.log", "--stale-after-s", "1") as proc,
        subscriber(zp) as sink,
    ):
        assert connected(sink)
        time.sleep(0.3)
        th, em = emit(mav, duration_s=100.0, speed=10.0, silent=((40.0, 70.0),))
        th.join(30)
        time.sleep(0.5)
        t_int = time.monotonic()
        proc.send_signal(signal.SIGINT)  # Ctrl-C stops it as cleanly as SIGTERM
        assert proc.wait(5) == 0 and time.monotonic() - t_int < 2.0
    statuses = [d for _, d in sink.of("mav_observer/1/status")]
    stale = [i for i, d in enumerate(statuses) if d["link"]["state"] == "stale"]
    assert stale, [d["link"]["state"] for d in statuses]
    assert statuses[stale[0]]["observers"]["gimbal"]["status"] == "stale"
    assert any(d["link"]["state"] == "up" for d in statuses[stale[-1] :])
    boot0 = em.boot_ms(0.0) / 1000
    est_t = [d["t_boot_s"] - boot0 for _, d in sink.of("mav_observer/1/gimbal/estimate")]
    assert any(t < 40.0 for t in est_t) and any(t > 75.0 for t in est_t)
    assert not any(40.1 < t < 70.0 for t in est_t)
    # recovery: the first bearing after the link returns gives an estimate (30 Hz bearings)
    first_back = min(t for t in est_t if t >= 70.0)
    print(f"link back: first estimate {1000 * (first_back - 70.0):.0f} ms of data time later")
    assert first_back - 70.0 < 0.1


@pytest.mark.parametrize("how", ["SIGTERM", "SIGKILL"])
def test_restart_with_a_state_file_is_converged_within_a_second(tmp_path: Path, how: str) -> None:
    """Stop a converged service while the vehicle flies on: SIGTERM (the state saved on the
    way out) or SIGKILL (no goodbye: the state file is the last periodic save, every 1 s
    here). The restarted one, with the same state file, publishes a converged estimate
    within 1 s of the data returning (here: of its liveliness token, declared at the first
    message). The subscriber stays as it is through the restart (a Zenoh peer needs no
    restart)."""
    mav, zp = ports()
    state = tmp_path / "state.json"
    log = tmp_path / "svc.log"
    conf = tmp_path / "svc.toml"
    conf.write_text("[state]\nsave_period_s = 1.0\n")
    stop = threading.Event()
    truths = Truths()
    with subscriber(zp) as sink:
        with service(mav, zp, log, "--state-file", str(state), "--config", str(conf)) as proc:
            assert connected(sink)
            time.sleep(0.3)
            th, _ = emit(mav, duration_s=400.0, speed=20.0, stop=stop, truths=truths)
            key = "mav_observer/1/gimbal/estimate"
            assert wait_for(lambda: any(d["status"] == "converged" for _, d in sink.of(key)), 15)
            time.sleep(1.5)  # at least one periodic save of a converged observer
            if how == "SIGKILL":
                proc.kill()
                assert proc.wait(5) == -signal.SIGKILL
            else:
                code, took = stop_process(proc)
                assert code == 0 and took < 2.0
        assert state.exists()
        n_before = len(sink.of(key))
        t_restart = time.monotonic()
        try:
            with service(mav, zp, log, "--state-file", str(state), "--config", str(conf)):
                assert wait_for(lambda: len(sink.of(key)) > n_before + 20, 15)
                alive = [
                    t
                    for t, k, a in sink.alive
                    if a and k == "mav_observer/1/alive" and t > t_restart
                ]
                after = sink.of(key)[n_before:]
        finally:
            stop.set()
            th.join(5)
    assert alive, "the restarted service declared no liveliness token"
    first_conv = next(t for t, d in after if d["status"] == "converged")
    print(f"{how}: converged {1000 * (first_conv - alive[0]):.1f} ms after the data returned")
    assert first_conv - alive[0] < 1.0
    # the very first estimates after the restart are converged, and stay so
    assert all(d["status"] == "converged" for _, d in after[:20])
    d0 = after[0][1]
    truth = truths.at(1, d0["t_boot_s"])
    assert truth is not None
    rel, bias = errors(d0, truth)
    assert rel < 0.05 and bias < 0.1
    assert "restored observer 'gimbal' (converged)" in log.read_text()


def test_run_exits_with_a_message_on_a_bad_setting() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "mav_observer", "run", "--estimator", "paper", "--k", "-1"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert res.returncode == 2  # a usage error
    assert "command line (--k): observer.k_per_s must be a finite number > 0" in res.stderr


def test_fuzzed_garbage_among_a_valid_stream_is_counted_and_changes_nothing(
    tmp_path: Path,
) -> None:
    """100,000 damaged and nonsensical frames (``sim.fuzz``: random bytes, bit flips, cut
    and over-long frames, lying lengths, bad checksums, unknown ids, NaN/infinite/absurd
    fields of the vehicle's own sysid) sent over UDP while the emitter's orbit streams: the
    service keeps running, counts what it skipped by reason, loses nothing in the kernel,
    and the orbit's estimates converge as the clean test's do."""
    mav, zp = ports()
    truths = Truths()
    frames = [f for _, f in fuzz.garbage(np.random.default_rng(2026), 100_000)]
    log = tmp_path / "svc.log"
    with (
        service(mav, zp, log, "--estimate-rate-hz", "0") as proc,
        subscriber(zp) as sink,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock,
    ):
        assert connected(sink)
        time.sleep(0.3)
        th, _ = emit(mav, duration_s=150.0, speed=15.0, truths=truths)  # 10 s of wall time
        start = time.monotonic()
        for i in range(0, len(frames), 500):  # spread over 9 s: about 11,000 frames/s
            for f in frames[i : i + 500]:
                sock.sendto(f, ("127.0.0.1", mav))
            time.sleep(max(0.0, start + 9.0 * (i + 500) / len(frames) - time.monotonic()))
        th.join(30)
        time.sleep(1.5)  # the next status
        assert proc.poll() is None, log.read_text()[-2000:]
        code, _ = stop_process(proc)
    assert code == 0
    status = sink.of("mav_observer/1/status")[-1][1]
    assert status["link"]["kernel_drops"] == 0
    skipped = {**status["skipped"], **status["link_skipped"]}
    assert skipped["bad_data"] > 50_000  # every damaged frame at least once
    # the nonsense frames carry an old or absurd time_boot_ms: refused for it first
    for reason in ("clock_unconfirmed", "time_jump", "non_finite", "zero_quaternion"):
        assert skipped.get(reason, 0) > 100, (reason, skipped, status["events"])
    assert status["events"].get("autopilot_reboot", 0) == 0
    est = [d for _, d in sink.of("mav_observer/1/gimbal/estimate")]
    last = [d for d in est if d["t_boot_s"] >= est[-1]["t_boot_s"] - 50.0]
    errs = [errors(d, t) for d in last if (t := truths.at(1, d["t_boot_s"])) is not None]
    assert len(errs) > 300
    assert max(e[0] for e in errs) < 0.05
    assert max(e[1] for e in errs) < 0.1
    assert last[-1]["status"] == "converged"


def test_mavlink_out_sends_the_converged_target_back_as_landing_target_and_statustext(
    tmp_path: Path,
) -> None:
    """emitter -> the service with ``--mavlink-out udpout:...`` -> a pymavlink receiver here:
    LANDING_TARGET in its position form with the target's local position within 0.5 m of
    the emitter's (40, 30, 0), from our onboard-computer ids, and a STATUSTEXT with the
    target's latitude and longitude."""
    from mav_observer.geo.geodesy import Origin, to_geodetic
    from mav_observer.mavlink.dialect import connect
    from sim.emitter import ORIGIN_ALT_M, ORIGIN_LAT_DEG, ORIGIN_LON_DEG

    mav_port, z_port = ports()
    out_port = free_port(socket.SOCK_DGRAM)
    rx = connect(f"udpin:127.0.0.1:{out_port}", source_system=1, source_component=1)
    got: dict[str, list[Any]] = {"LANDING_TARGET": [], "STATUSTEXT": []}
    try:
        with service(mav_port, z_port, tmp_path / "svc.log",
                     "--mavlink-out", f"udpout:127.0.0.1:{out_port}"):  # fmt: skip
            # (converged from 60 s on, once the gimbal's latency learnt has settled)
            th, _ = emit(mav_port, duration_s=90.0, speed=10.0)
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline and (
                len(got["LANDING_TARGET"]) < 5 or not got["STATUSTEXT"]
            ):
                m = rx.recv_match(type=list(got), blocking=True, timeout=0.2)
                if m is not None:
                    got[m.get_type()].append(m)
            th.join(timeout=10.0)
    finally:
        rx.close()
    lt = got["LANDING_TARGET"]
    assert len(lt) >= 5, (tmp_path / "svc.log").read_text()[-3000:]
    last = lt[-1]
    assert (last.get_srcSystem(), last.get_srcComponent()) == (254, 191)
    assert last.frame == 1 and last.position_valid == 1  # MAV_FRAME_LOCAL_NED
    assert math.dist((last.x, last.y, last.z), (40.0, 30.0, 0.0)) < 0.5
    assert last.distance > 10.0
    text = got["STATUSTEXT"][0].text
    assert text.startswith("gimbal: ")
    lat, lon = (float(v) for v in text.split()[1:3])
    origin = Origin(ORIGIN_LAT_DEG, ORIGIN_LON_DEG, ORIGIN_ALT_M, "GLOBAL_POSITION_INT")
    lat_t, lon_t, _ = to_geodetic(origin, (40.0, 30.0, 0.0))
    assert abs(lat - lat_t) < 2e-5 and abs(lon - lon_t) < 2e-5  # the text's 5 decimals


def test_mavlink_out_over_the_input_connection_answers_the_peer_it_hears(tmp_path: Path) -> None:
    """``--mavlink-out input``: the service sends LANDING_TARGET back over its ``udpin`` link,
    to the peer it hears (a companion's router): the socket that sends the telemetry gets
    the answers."""
    from mav_observer.mavlink.dialect import connect
    from sim.inject import split_records

    tl = tmp_path / "orbit.tlog"
    emitter.run(
        emitter.Emitter(scenarios.orbit(duration_s=90.0),
                        emitter.EmitterConfig(duration_s=90.0, bearing_noise_deg=0.5, seed=4)),
        tlog=tl,
    )  # fmt: skip
    frames = [(r.t_us, r.frame) for r in split_records(tl.read_bytes()) if r.t_us is not None]
    mav_port, z_port = ports()
    got = []
    with service(mav_port, z_port, tmp_path / "svc.log", "--mavlink-out", "input"):
        peer = connect(f"udpout:127.0.0.1:{mav_port}", source_system=1, source_component=1)
        try:
            t0 = frames[0][0]
            start = time.monotonic()
            for t_us, fr in frames:  # 20 times real time, replies read in between
                while time.monotonic() - start < (t_us - t0) * 5e-8:
                    m = peer.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.005)
                    if m is not None:
                        got.append(m)
                peer.write(fr)
            deadline = time.monotonic() + 3.0
            while time.monotonic() < deadline and len(got) < 3:
                m = peer.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.05)
                if m is not None:
                    got.append(m)
        finally:
            peer.close()
    assert len(got) >= 3, (tmp_path / "svc.log").read_text()[-2000:]
    assert math.dist((got[-1].x, got[-1].y, got[-1].z), (40.0, 30.0, 0.0)) < 0.5
