"""The best a live estimator can do on a real log: causal least-squares fits against the product.

``python -m bench.accuracy.causal [LOG.tlog ...] [--seeds N] [--fits K] [--json F]``

The bar of the real-log bench (:mod:`bench.accuracy.reallogs`) is the batch least-squares fit
over the whole log, which uses every bearing, past and future, for each position. A live
estimator (the service, and ``replay --live``, which gives what the service would have
published) has at time ``t`` only the bearings up to ``t``, and of the vehicle's positions
only those LOCAL_POSITION_NED has sent by then: between two samples of a 1 Hz stream it must
predict where the vehicle went. ``replay`` by default publishes each bearing's estimate once
the next velocity sample is in (``docs/cli.md``): it knows where the vehicle went. For each
log and seed (the same injection as the real-log bench: a 0.5 deg, 10 Hz gimbal bearing
toward a point under the flight, a (2, -1, 0) m/s velocity error) this reports, as position
RMS relative to the range over the last third of the injected span:

* ``product``: ``mav-observer replay`` with the default settings (as the real-log bench),
  and ``product, live``: with ``--live``;
* ``batch``: the whole-log fit (the real-log bench's reference);
* ``causal, interpolated``: at ``K`` times of the last third, the fit of the bearings up to
  that time, the vehicle's positions interpolated between LOCAL_POSITION_NED samples (it
  knows the next sample: not causal in the positions);
* ``causal, extrapolated``: the same, the vehicle's positions past the latest sample
  extrapolated with that sample's velocity, the injected velocity error removed (told the
  error and the true noise). A reference, not a bound: the product continues the latest
  interval's trend instead of holding the velocity (``docs/frames.md``), and publishes at the
  bearings' times, not at evenly spaced ones; it can come out a little below it.

Where ``causal, extrapolated`` is far above ``batch``, the gap between the product and the
whole-log fit is the price of publishing live, not the estimator's. The causal fits take the
vehicle's displacement from LOCAL_POSITION_NED's positions, as the product does for a stream
of 5 Hz or sparser (``docs/frames.md``, "Sparse velocity"); on a denser stream the product
integrates the velocity, its errors included, while the injected truth is the positions'
straight lines: there the causal fits know the truth's kinematics and are no reference (the
SITL servo log: 0.11 %).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.accuracy import reallogs
from bench.accuracy.report import markdown_table
from mav_observer.core.batch_fit import fit_batch
from sim import inject as inj


def causal_fits(
    t_s: np.ndarray,
    bearings: np.ndarray,
    rel_pos_true_m: np.ndarray,
    lpn_t_s: np.ndarray,
    lpn_pos_m: np.ndarray,
    lpn_vel_true_mps: np.ndarray,
    *,
    sigma_rad: float,
    fits: int,
) -> dict[str, float]:
    """Position RMS relative to the range (a fraction) of the causal fits over the last
    third of ``t_s``: the positions interpolated (``interpolated``) and extrapolated past
    the latest LOCAL_POSITION_NED with its velocity (``extrapolated``)."""
    t0, t1 = float(t_s[0]), float(t_s[-1])
    last = np.flatnonzero(t_s >= t0 + (t1 - t0) * (1.0 - 1.0 / 3.0))
    at = last[:: max(1, len(last) // fits)]
    interp = np.column_stack([np.interp(t_s, lpn_t_s, lpn_pos_m[:, i]) for i in range(3)])
    out = {}
    for name in ("interpolated", "extrapolated"):
        rel = []
        for k in at:
            pos = interp[: k + 1].copy()
            if name == "extrapolated":
                j = int(np.searchsorted(lpn_t_s, t_s[k], side="right")) - 1
                if j >= 0:
                    past = t_s[: k + 1] >= lpn_t_s[j]
                    dt = (t_s[: k + 1][past] - lpn_t_s[j])[:, None]
                    pos[past] = lpn_pos_m[j] + lpn_vel_true_mps[j] * dt
            fit = fit_batch(t_s[: k + 1], bearings[: k + 1], -(pos - pos[0]), sigma_rad=sigma_rad)
            x = fit.rel_pos_at()[-1]
            rel.append(np.linalg.norm(x - rel_pos_true_m[k]) / np.linalg.norm(rel_pos_true_m[k]))
        out[name] = math.sqrt(float(np.mean(np.square(rel))))
    return out


def run_log(
    log: Path,
    *,
    seed: int,
    fits: int,
    noise_deg: float = 0.5,
    vel_error: tuple[float, float, float] = (2.0, -1.0, 0.0),
) -> dict[str, Any]:
    """The product and the whole-log fit (:func:`bench.accuracy.reallogs.run_log`) and the
    causal fits of one log and seed."""
    row = reallogs.run_log(log, seed=seed, noise_deg=noise_deg, vel_error=vel_error)
    live = reallogs.run_log(log, seed=seed, noise_deg=noise_deg, vel_error=vel_error, live=True)
    res = reallogs.injected(log, seed=seed, noise_deg=noise_deg, vel_error=vel_error)
    truth = res.truth
    epochs = [d.get("epoch", 0) for d in truth]
    ep = max(set(epochs), key=epochs.count)  # as the real-log bench: the largest epoch
    truth = [d for d in truth if d.get("epoch", 0) == ep]
    flight = inj.read_flight(inj.split_records(b"".join(res.records)), sysid=res.sysid)
    lpn = flight.local_position[ep]
    c = causal_fits(
        np.array([d["t_boot_s"] for d in truth]),
        np.array([d["bearing_ned"] for d in truth]),
        np.array([d["rel_pos_ned_m"] for d in truth]),
        np.asarray(lpn.t_boot_s),
        lpn.values[:, :3],
        lpn.values[:, 3:6] - np.asarray(vel_error),
        sigma_rad=math.radians(noise_deg),
        fits=fits,
    )
    return {
        "log": log.name,
        "seed": seed,
        "lpn_hz": row["lpn_hz"],
        "range_last_third_m": row["range_last_third_m"],
        "product_rel_rms": row["product_rel_rms"],
        "product_live_rel_rms": live["product_rel_rms"],
        "batch_rel_rms": row["batch_rel_rms"],
        "causal_interpolated_rel_rms": c["interpolated"],
        "causal_extrapolated_rel_rms": c["extrapolated"],
    }


def table(rows: list[dict[str, Any]]) -> str:
    out = []
    for r in rows:
        p, pl = r["product_rel_rms"], r["product_live_rel_rms"]
        ci, ce = r["causal_interpolated_rel_rms"], r["causal_extrapolated_rel_rms"]
        out.append(
            f"| {r['log']} (seed {r['seed']}) | {r['lpn_hz']:.1f} Hz "
            f"| {r['range_last_third_m']:.1f} m | {100 * p:.2f} % | {100 * pl:.2f} % "
            f"| {100 * r['batch_rel_rms']:.2f} % "
            f"| {100 * ci:.2f} % | {100 * ce:.2f} % "
            f"| {p / ci:.2f}x | {pl / ce:.2f}x |"
        )
    columns = (
        "log",
        "LPN rate",
        "range (last third)",
        "product",
        "product, live",
        "batch (whole log)",
        "causal, interpolated",
        "causal, extrapolated",
        "product / causal interpolated",
        "live / causal extrapolated",
    )
    return markdown_table(columns, out)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.causal", description=__doc__)
    p.add_argument("logs", nargs="*", type=Path, help="default: the shared logs with LPN")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--fits", type=int, default=40, help="causal fits per run (last third)")
    p.add_argument("--json", type=Path, help="write every run's figures here")
    args = p.parse_args(argv)
    if args.seeds < 1 or args.fits < 1:
        p.error(f"--seeds and --fits must be >= 1, got {args.seeds} and {args.fits}")
    logs = args.logs or reallogs.shared_logs()
    missing = [str(x) for x in logs if not x.is_file()]
    if missing:
        p.error(f"no such log: {', '.join(missing)}")
    t0 = time.perf_counter()
    rows = [run_log(log, seed=s, fits=args.fits) for log in logs for s in range(args.seeds)]
    print(table(rows))
    print(f"{len(rows)} runs in {time.perf_counter() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
