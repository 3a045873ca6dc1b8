"""``python -m sim``: run scenarios through the observer (the simulator's command line).

* ``demo``: run a named scenario and print a table of estimate against truth, then a
  one-line verdict. Exit status 0 if the run ended converged, 2 if not.
* ``figures``: reproduce the paper's six figures as PNG files (needs matplotlib).
* ``live``: the emitter, the service and a subscriber on loopback (``mav-observer demo``,
  :mod:`sim.live`).
* ``emit``: send a scenario as MAVLink (a vehicle and its gimbal or camera) to a pymavlink
  output string and/or a tlog, with the truth as JSON Lines.
* ``fleet``: two or three vehicles, each with its own system id, clock, velocity error and
  EKF origin, watching one ground target on the WGS84 earth (:mod:`sim.fleet`), as tlogs
  with the fleet's truth and/or live links, one per vehicle.
* ``convert``: a tlog's flight as an ArduPilot ``.bin`` or PX4 ``.ulg`` (:mod:`sim.logwriters`).
* ``inject``: add a synthetic bearing stream toward a fixed local NED point to a real tlog
  (:mod:`sim.inject`), with the truth as JSON Lines.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mav_observer.core.observer import BiasObserver, ObserverConfig
from sim import scenarios
from sim.runner import run
from sim.stream import Noise, generate


def observer_config(args: argparse.Namespace, n: int) -> ObserverConfig:
    preset = args.config
    if preset == "auto":
        preset = "paper" if args.scenario == "paper" else "default"
    overrides: dict[str, object] = {"n": n}
    if args.k is not None:
        overrides["k_per_s"] = args.k
    if args.k_star is not None:
        overrides["k_star_per_s"] = args.k_star
    if preset == "paper":
        return ObserverConfig.paper(**overrides)
    if len(overrides) > 1:  # gains given: the paper's observer with them
        return ObserverConfig(estimator="paper", **overrides)
    # the default estimator, told the stream's noise (a floor for exact bearings)
    return ObserverConfig(
        n=n,
        bearing_noise_deg=max(args.bearing_noise_deg, 0.05),
        velocity_noise_mps=args.velocity_noise_mps,
    )


def cmd_demo(args: argparse.Namespace) -> int:
    sc = scenarios.make(args.scenario)
    duration = sc.duration_s if args.duration is None else args.duration
    noise = Noise(
        bearing_sigma_deg=args.bearing_noise_deg,
        position_noise_m=args.position_noise_m,
        velocity_sigma_mps=args.velocity_noise_mps,
    )
    cfg = observer_config(args, sc.n)
    stream = generate(
        sc,
        seed=args.seed,
        bearing_rate_hz=args.rate_hz,
        velocity_rate_hz=args.rate_hz,
        duration_s=duration,
        noise=noise,
    )
    print(f"scenario {sc.name}: {sc.description}")
    print(
        f"estimator {cfg.estimator}"
        + (
            f" (k={cfg.k_per_s} 1/s, k*={cfg.k_star_per_s} 1/s)"
            if cfg.estimator == "paper"
            else f" (told {cfg.bearing_noise_deg} deg, {cfg.velocity_noise_mps} m/s)"
        )
        + f", mode {cfg.mode}; "
        f"bearings and velocity at {args.rate_hz} Hz for {duration:g} s; noise {noise}"
    )
    res = run(BiasObserver(cfg), stream)
    header = (
        f"{'t_s':>7} {'range_m':>8} {'range_est':>9} {'pos_err_m':>10} {'err_%':>7} "
        f"{'bias_err':>9} {'excit':>6} {'cond_M':>7}  status"
    )
    print(header)
    next_t = res.t_s[0]
    for i, t in enumerate(res.t_s):
        if t + 1e-9 < next_t and i != len(res.t_s) - 1:
            continue
        next_t = t + args.every
        r = res.range_m[i]
        print(
            f"{t:7.1f} {r:8.3f} {np.linalg.norm(res.xhat_m[i]):9.3f} {res.pos_err_m[i]:10.4f} "
            f"{100 * res.pos_err_m[i] / r:7.2f} {res.bias_err_mps[i]:9.4f} "
            f"{res.excitation[i]:6.3f} {res.cond_m[i]:7.1f}  {res.status[i]}"
        )
    t10 = res.time_to_stay_below(0.10)
    converged = res.status[-1] == "converged"
    verdict = "CONVERGED" if converged else f"NOT CONVERGED ({res.status[-1]})"
    t10_txt = "never" if t10 is None else f"{t10:.1f} s"
    print(
        f"verdict: {verdict}: final position error {res.pos_err_m[-1]:.4g} m "
        f"({100 * res.pos_err_m[-1] / res.range_m[-1]:.3g} % of range), bias error "
        f"{res.bias_err_mps[-1]:.4g} m/s; error stays below 10 % of range from {t10_txt}"
    )
    return 0 if converged else 2


def cmd_figures(args: argparse.Namespace) -> int:
    from sim import figures  # matplotlib only needed here

    summary = figures.paper_figures(args.out, duration_s=args.duration)
    for line in figures.summary_lines(summary):
        print(line)
    return 0


def cmd_emit(args: argparse.Namespace) -> int:
    from pathlib import Path

    from sim import emitter

    if not (args.to or args.tlog):
        raise SystemExit("python -m sim emit: give --to and/or --tlog")
    sc = scenarios.make(args.scenario, duration_s=args.duration)
    cfg = emitter.EmitterConfig(
        bearing=args.bearing,
        sysid=args.sysid,
        duration_s=args.duration,
        attitude_hz=args.attitude_hz,
        position_hz=args.position_hz,
        bearing_hz=args.bearing_hz,
        background_hz=args.background_hz,
        bearing_noise_deg=args.bearing_noise_deg,
        velocity_noise_mps=args.velocity_noise_mps,
        drop_prob=args.drop_prob,
        latency_s=args.latency_s,
        seed=args.seed,
        rangefinder_noise_m=args.rangefinder_noise_m,
    )
    em = emitter.Emitter(sc, cfg)
    report = emitter.run(
        em,
        to=args.to,
        tlog=Path(args.tlog) if args.tlog else None,
        truth=Path(args.truth) if args.truth else None,
        speed=args.speed,
    )
    print(
        f"emitted {report.messages} messages ({report.bearing_messages} bearing) of "
        f"{args.duration:g} s of scenario {args.scenario} in {report.wall_s:.2f} s"
    )
    return 0


def _drop(text: str) -> tuple[int, float]:
    sysid, _, t = text.partition("@")
    try:
        return int(sysid), float(t)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SYSID@SECONDS, got {text!r}") from None


def _clock_offset(text: str) -> tuple[int, float]:
    sysid, _, s = text.partition("=")
    try:
        return int(sysid), float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SYSID=SECONDS, got {text!r}") from None


def cmd_fleet(args: argparse.Namespace) -> int:
    from sim import fleet

    to = [u for u in (args.to or "").split(",") if u]
    if not (to or args.tlog_dir):
        raise SystemExit("python -m sim fleet: give --to and/or --tlog-dir")
    try:
        fl = fleet.make_fleet(
            args.fleet,
            vehicles=args.vehicles,
            seed=args.seed,
            duration_s=args.duration,
            bearing_noise_deg=args.bearing_noise_deg,
            drop=args.drop,
            clock_offsets_s=dict(args.clock_offset or []),
        )
        if to and len(to) != len(fl.members):
            raise ValueError(f"--to needs {len(fl.members)} outputs (one per vehicle)")
    except ValueError as exc:
        print(f"python -m sim fleet: {exc}", file=sys.stderr)
        return 2
    if args.tlog_dir:
        paths = fleet.write_tlogs(fl, Path(args.tlog_dir))
        print(f"wrote {', '.join(str(p) for p in paths)}")
    if to:
        fleet.run_live(fl, to, speed=args.speed)
        print(f"sent {args.duration:g} s of {args.fleet} ({len(to)} vehicles) to {', '.join(to)}")
    return 0


def _triple(text: str) -> tuple[float, float, float]:
    try:
        parts = tuple(float(v) for v in text.split(","))
    except ValueError:
        parts = ()
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected N,E,D (three numbers), got {text!r}")
    return parts  # type: ignore[return-value]


def _target(text: str) -> tuple[float, float, float] | None:
    return None if text == "auto" else _triple(text)


def cmd_convert(args: argparse.Namespace) -> int:
    from sim import logwriters

    out = Path(args.output)
    try:
        n = logwriters.convert(Path(args.tlog), out)
        if args.truth:
            truth_out = Path(args.truth_output or f"{out}.truth.jsonl")
            logwriters.convert_truth(Path(args.truth), truth_out, out)
    except (ValueError, OSError) as exc:
        print(f"python -m sim convert: {exc}", file=sys.stderr)
        return 1
    print(f"wrote {n} records to {out}")
    return 0


def cmd_inject(args: argparse.Namespace) -> int:
    from sim import inject

    try:
        cfg = inject.InjectConfig(
            target_ned_m=args.target,
            bearing=args.bearing,
            rate_hz=args.rate_hz,
            noise_deg=args.noise_deg,
            vel_error_ned_mps=args.vel_error,
            seed=args.seed,
            sysid=args.sysid,
            compid=args.compid,
            gimbal_device_id=args.gimbal_device_id,
        )
        result = inject.inject_file(args.log, args.output, args.truth, cfg)
    except (inject.InjectError, OSError) as exc:
        print(f"python -m sim inject: {exc}", file=sys.stderr)
        return 2
    if args.target is None:
        t = result.target_ned_m
        print(f"target auto: [{t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}] m NED")
    print(result.text())
    if not result.injected:
        print("python -m sim inject: no bearing could be injected", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sim", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run a scenario and print estimate against truth")
    demo.add_argument("--scenario", default="paper", choices=sorted(scenarios.SCENARIOS))
    demo.add_argument(
        "--config",
        default="auto",
        choices=("auto", "paper", "default"),
        help="observer preset: the paper's (k=0.5, k*=5, no static hold) or the default "
        "(the riccati estimator told the stream's noise; with --k/--k-star the paper's observer "
        "with those gains); auto: paper for the paper scenario",
    )
    demo.add_argument("--k", type=float, default=None, help="gain k (1/s)")
    demo.add_argument("--k-star", type=float, default=None, help="gain k* (1/s)")
    demo.add_argument("--duration", type=float, default=None, help="seconds of simulated time")
    demo.add_argument("--rate-hz", type=float, default=20.0, help="bearing and velocity rate")
    demo.add_argument("--bearing-noise-deg", type=float, default=0.0)
    demo.add_argument("--position-noise-m", type=float, default=0.0, help="paper's uniform noise")
    demo.add_argument("--velocity-noise-mps", type=float, default=0.0)
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--every", type=float, default=10.0, help="table row every N seconds")
    demo.set_defaults(func=cmd_demo)
    em = sub.add_parser("emit", help="emit a scenario as MAVLink (UDP/TCP/serial and/or tlog)")
    em.add_argument(
        "--scenario",
        default="orbit",
        choices=sorted(s for s in scenarios.SCENARIOS if s != "planar"),
    )
    em.add_argument(
        "--bearing",
        default="gimbal",
        help="gimbal, gimbal_earth, camera, mount, "
        "mount_status, landing_target, landing_target_local",
    )
    em.add_argument("--to", help="pymavlink output string, e.g. udpout:127.0.0.1:14550")
    em.add_argument("--tlog", help="also write a tlog")
    em.add_argument("--truth", help="write the truth, JSON Lines")
    em.add_argument("--duration", type=float, default=300.0, help="simulated seconds")
    em.add_argument(
        "--speed",
        type=float,
        default=None,
        help="1 real time, 20 twenty times faster; default as fast as possible",
    )
    em.add_argument("--sysid", type=int, default=1)
    em.add_argument("--attitude-hz", type=float, default=20.0)
    em.add_argument("--position-hz", type=float, default=10.0)
    em.add_argument("--bearing-hz", type=float, default=10.0)
    em.add_argument("--background-hz", type=float, default=0.0, help="other telemetry, msg/s")
    em.add_argument("--bearing-noise-deg", type=float, default=0.0)
    em.add_argument("--velocity-noise-mps", type=float, default=0.0)
    em.add_argument("--drop-prob", type=float, default=0.0)
    em.add_argument("--latency-s", type=float, default=0.0, help="bearing stream latency")
    em.add_argument("--seed", type=int, default=0)
    em.add_argument(
        "--rangefinder-noise-m",
        type=float,
        default=None,
        help="a rangefinder on the gimbal: DISTANCE_SENSOR with each bearing, this noise (m)",
    )
    em.set_defaults(func=cmd_emit)
    fl = sub.add_parser(
        "fleet", help="two or three vehicles watching one target (tlogs and/or live links)"
    )
    fl.add_argument("--fleet", default="fleet_hover", choices=("fleet_hover", "fleet_moving"))
    fl.add_argument("--vehicles", type=int, default=2, choices=(1, 2, 3))
    fl.add_argument("--duration", type=float, default=30.0, help="simulated seconds")
    fl.add_argument("--seed", type=int, default=0)
    fl.add_argument("--bearing-noise-deg", type=float, default=0.5)
    fl.add_argument("--tlog-dir", help="write vehicle_<sysid>.tlog and the fleet's truth here")
    fl.add_argument(
        "--to",
        help="one pymavlink output per vehicle, comma-separated, e.g. "
        "udpout:127.0.0.1:14551,udpout:127.0.0.1:14552",
    )
    fl.add_argument(
        "--speed", type=float, default=1.0, help="with --to: 1 real time, 0 as fast as possible"
    )
    fl.add_argument(
        "--drop", type=_drop, default=None, help="SYSID@T: that vehicle is lost from T seconds"
    )
    fl.add_argument(
        "--clock-offset",
        type=_clock_offset,
        action="append",
        help="SYSID=SECONDS: that vehicle's SYSTEM_TIME Unix time is off (repeatable)",
    )
    fl.set_defaults(func=cmd_fleet)
    inj = sub.add_parser(
        "inject",
        help="add a synthetic bearing stream toward a fixed local NED point to a real tlog",
    )
    inj.add_argument("log", help="the real tlog")
    inj.add_argument(
        "--target",
        type=_target,
        required=True,
        help="N,E,D (m) in the LOCAL_POSITION_NED frame, or auto: median north and east of "
        "the track, 2 m below its lowest point",
    )
    inj.add_argument("-o", "--output", required=True, help="the new tlog")
    inj.add_argument("--truth", required=True, help="the truth, JSON Lines")
    inj.add_argument(
        "--bearing", default="gimbal", choices=("gimbal", "gimbal_earth", "landing_target")
    )
    inj.add_argument("--rate-hz", type=float, default=10.0, help="bearing rate")
    inj.add_argument("--noise-deg", type=float, default=0.5, help="isotropic angular noise")
    inj.add_argument(
        "--vel-error",
        type=_triple,
        default=(0.0, 0.0, 0.0),
        help="N,E,D (m/s) added to every LOCAL_POSITION_NED velocity (the truth's a)",
    )
    inj.add_argument("--seed", type=int, default=0)
    inj.add_argument(
        "--sysid", type=int, default=None, help="default: the vehicle sending LOCAL_POSITION_NED"
    )
    inj.add_argument("--compid", type=int, default=1, help="component of the injected frames")
    inj.add_argument(
        "--gimbal-device-id",
        type=int,
        default=1,
        help="1: target 'gimbal'; N > 1: 'gimbalN' (when the log has its own gimbal)",
    )
    inj.set_defaults(func=cmd_inject)
    cv = sub.add_parser(
        "convert", help="write a tlog's flight as an ArduPilot .bin or a PX4 .ulg (same data)"
    )
    cv.add_argument("tlog", help="the tlog (emitted or injected)")
    cv.add_argument("output", help="OUT.bin or OUT.ulg")
    cv.add_argument("--truth", help="the tlog's truth: written beside OUT, targets renamed")
    cv.add_argument("--truth-output", help="default: OUT.truth.jsonl")
    cv.set_defaults(func=cmd_convert)
    from sim import live

    live.add_parser(sub)
    fig = sub.add_parser("figures", help="reproduce the paper's figures as PNG files")
    fig.add_argument("--out", default="docs/figures", help="output folder")
    fig.add_argument("--duration", type=float, default=300.0)
    fig.set_defaults(func=cmd_figures)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
