"""End-to-end accuracy: emitter tlogs replayed through the product, scored against the truth.

``python -m bench.accuracy.e2e [--cases NAME ...] [--seeds N] [--duration S] [--jobs J]``
``[--defaults | --adaptive] [--live] [--write-docs]``

Unlike the batched harness (:mod:`bench.accuracy.run`), which feeds the estimator's maths
directly, every run here goes the way a user's data goes:

1. the software emitter (:mod:`sim.emitter`) writes a tlog of a named case: a scenario, a
   bearing stream and the realism knobs of :class:`sim.emitter.EmitterConfig` (per-stream
   latency and jitter, a gimbal that is its own component with its own drifting clock, fast
   yaw, sparse or coloured velocity, dropouts, tlog clock jitter and jumps), with its truth;
2. the tlog is replayed by the product's own replay (:func:`mav_observer.app.replay.replay`) with
   the settings a user would write in a settings file (``settings`` of the case: the bearing
   and velocity noise told, or nothing for the defaults): what replay publishes by default,
   each bearing's estimate once the velocity after it is known, or with ``--live`` what the
   service publishes, each at its arrival;
3. the estimates are scored against the truth: position RMS over the last third and its ratio
   to the Cramér-Rao bound along the same truth (:func:`bench.accuracy.core.crlb` of the
   stream's true noise: the bearing noise, the velocity's white noise and its Gauss-Markov
   part, the constant part being the bias ``a``; a model error such as a gimbal's lag is
   not in it), the range bias, the bias RMS, NEES per axis (from the per-axis
   standard deviations published in every record), and the time after which the error stays
   below 10 % of the range.

The cases of :data:`ADAPTIVE` (the noise not told: a bearing noise other than the defaults',
velocity noise, bearing outliers) are run only when asked for (``--adaptive`` or ``--cases``)
and have a block of their own in ``docs/accuracy.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.accuracy import blocks, core, geo
from bench.accuracy.report import markdown_table
from mav_observer.app import settings as st
from mav_observer.app.replay import replay
from mav_observer.core.observer import ObserverConfig
from mav_observer.tracking.tracker import TrackerConfig
from sim import emitter as em
from sim import logwriters, realism, scenarios
from sim import truth as truth_file
from sim.inject import split_records

DOCS = Path(__file__).resolve().parents[2] / "docs" / "accuracy.md"
#: The window of the steady metrics: the last third of a run.
STEADY_FRACTION = 1.0 / 3.0


@dataclass(frozen=True)
class E2ECase:
    """One end-to-end case: what the emitter sends and what the user tells the product."""

    name: str
    description: str
    scenario: str
    bearing: str
    scenario_params: dict[str, Any] = field(default_factory=dict)
    emitter: dict[str, Any] = field(default_factory=dict)
    #: :class:`sim.realism.Realism` knobs (latency, jitter, component clock, velocity error,
    #: dropouts, tlog clock) and the vehicle's yaw swing (``yaw_swing_deg``, 0: none)
    realism: dict[str, Any] = field(default_factory=dict)
    yaw_swing_deg: float = 0.0
    #: TrackerConfig fields (how the messages are read, e.g. ``gimbal_angles``)
    tracker: dict[str, Any] = field(default_factory=dict)
    #: the ``[observer]`` settings of the user's settings file (empty: the defaults)
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def bearing_deg(self) -> float:
        """The stream's bearing noise, its standard deviation per tangent axis (degrees):
        outliers (``outlier_prob``) are not counted."""
        return float(self.emitter.get("bearing_noise_deg", 0.0))

    @property
    def bound_bearing_deg(self) -> float:
        """The bearing noise of the CRLB (degrees): :attr:`bearing_deg`, the bound
        that of the clean stream; Student-t noise (``bearing_noise_dof`` finite) as the
        Gaussian noise of the same per-axis Fisher information,
        ``(nu + 1) nu / ((nu + 3) (nu - 2))`` over the variance."""
        sd = self.bearing_deg
        nu = float(self.emitter.get("bearing_noise_dof", math.inf))
        if math.isfinite(nu):
            sd /= math.sqrt((nu + 1.0) * nu / ((nu + 3.0) * (nu - 2.0)))
        return sd

    @property
    def velocity_white_mps(self) -> float:
        return float(self.emitter.get("velocity_noise_mps", 0.0))

    def bound_noise(self, velocity_dt_s: float) -> dict[str, float]:
        """The true noise of the stream as :func:`bench.accuracy.core.crlb` takes it: the
        bearing noise, the velocity's white noise as process noise on ``x`` (``q_x``) and
        its Gauss-Markov part (the realism knobs ``velocity_gm_std_mps``,
        ``velocity_gm_tau_s``; 0 when off, and the bound is then the constant-bias one)."""
        gm = float(self.realism.get("velocity_gm_std_mps", 0.0))
        out = {
            "sigma_rad": math.radians(self.bound_bearing_deg),
            "q_x": self.velocity_white_mps**2 * velocity_dt_s,
        }
        if gm > 0.0:
            out["gm_std_mps"] = gm
            out["gm_tau_s"] = float(self.realism.get("velocity_gm_tau_s", 60.0))
        if self.emitter.get("rangefinder_noise_m"):
            out["range_sigma_m"] = float(self.emitter["rangefinder_noise_m"])
        return out

    @property
    def knobs(self) -> str:
        """The realism knobs in force, for the tables."""
        parts = [f"{k}={v}" for k, v in self.realism.items()]
        if self.yaw_swing_deg:
            parts.append(f"yaw_swing_deg={self.yaw_swing_deg:g}")
        return ", ".join(parts) or "none"


#: A gimbal that is its own MAVLink component (MAV_COMP_ID_GIMBAL) beside the autopilot:
#: 25 Hz against ATTITUDE at 50 Hz, 5 ms latency and up to 15 ms of jitter (about half of
#: the bearings arrive before the ATTITUDE of their own time), its own boot clock 3.7 s off
#: the autopilot's and drifting 40 ppm.
OWN_COMPONENT = {
    "component_id": 154,
    "bearing_latency_s": 0.005,
    "attitude_latency_s": 0.002,
    "position_latency_s": 0.003,
    "jitter_s": 0.015,
    "component_boot_offset_s": 3.7,
    "component_clock_drift_ppm": 40.0,
}
FAST = {"attitude_hz": 50.0, "bearing_hz": 25.0, "position_hz": 10.0}
RANGED_RATES = {"attitude_hz": 50.0, "bearing_hz": 10.0, "position_hz": 10.0}
TOLD_05 = {"bearing_noise_deg": 0.5, "velocity_noise_mps": 0.0, "bias_walk_mps_per_sqrt_s": 0.0}
B05 = {"bearing_noise_deg": 0.5}
#: A velocity error that wanders: 0.1 m/s Gauss-Markov over 60 s plus a constant.
VELOCITY_GM = {
    "velocity_gm_std_mps": 0.1,
    "velocity_gm_tau_s": 60.0,
    "velocity_bias_ned_mps": (0.3, -0.2, 0.0),
}


def _adaptive(name: str, what: str, **emitter: Any) -> E2ECase:
    """A case of the noise not told (the default settings): the gimbal figure-8 of
    gimbal_vehicle_fig8 with the emitter settings ``emitter`` (its noise, its outliers)."""
    return E2ECase(
        name,
        what,
        "figure8",
        "gimbal",
        emitter={**FAST, **emitter},
        realism=OWN_COMPONENT,
        yaw_swing_deg=30.0,
    )


CASES: dict[str, E2ECase] = {
    c.name: c
    for c in (
        # the headline: the five bearing paths at 0.5 deg, the noise told in the settings file
        E2ECase(
            "gimbal_vehicle_fig8",
            "gimbal, own component and clock, yaw in the vehicle frame, figure-8, yaw swing 30 deg",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05},
            realism=OWN_COMPONENT,
            yaw_swing_deg=30.0,
            settings=TOLD_05,
        ),
        E2ECase(
            "gimbal_earth_fig8",
            "gimbal, own component and clock, yaw in the earth frame, figure-8, yaw swing 30 deg",
            "figure8",
            "gimbal_earth",
            emitter={**FAST, **B05},
            realism=OWN_COMPONENT,
            yaw_swing_deg=30.0,
            settings=TOLD_05,
        ),
        E2ECase(
            "landing_target_weave",
            "LANDING_TARGET, body-frame downward camera (own component), weaving flight, 20 Hz",
            "weave",
            "landing_target",
            emitter={"attitude_hz": 50.0, "bearing_hz": 20.0, **B05},
            realism={**OWN_COMPONENT, "component_id": 100, "bearing_latency_s": 0.02},
            settings=TOLD_05,
        ),
        E2ECase(
            "mount_status_orbit",
            "MOUNT_STATUS (no time field, ArduPilot), orbit, 10 Hz",
            "orbit",
            "mount_status",
            emitter={"attitude_hz": 20.0, "bearing_hz": 10.0, **B05},
            realism={"jitter_s": 0.003},
            settings=TOLD_05,
        ),
        E2ECase(
            "camera_point_orbit",
            "camera tracked point (no time field) through a roughly pointed gimbal, orbit",
            "orbit",
            "camera",
            emitter={"attitude_hz": 50.0, "bearing_hz": 20.0, **B05},
            realism={"jitter_s": 0.003},
            settings=TOLD_05,
        ),
        # each realism knob in a case of its own (gimbal, vehicle-frame yaw, figure-8)
        E2ECase(
            "yaw_60dps",
            "yaw swing of 57 deg over 6 s (60 deg/s), gimbal own component with jitter",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05},
            realism=OWN_COMPONENT,
            yaw_swing_deg=57.0,
            settings=TOLD_05,
        ),
        E2ECase(
            "velocity_1hz",
            "LOCAL_POSITION_NED at 1 Hz (positions true), figure-8",
            "figure8",
            "gimbal",
            emitter={**FAST, "position_hz": 1.0, **B05},
            settings=TOLD_05,
        ),
        E2ECase(
            "velocity_coloured",
            "velocity error: 0.05 m/s white + 0.1 m/s Gauss-Markov (60 s) + (0.3, -0.2, 0) m/s",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05, "velocity_noise_mps": 0.05},
            realism=VELOCITY_GM,
            # told as a user would: the white part, and the Gauss-Markov part as the bias's
            # random walk of the same short-term spread, 0.1 * sqrt(2 / 60 s)
            settings={
                "bearing_noise_deg": 0.5,
                "velocity_noise_mps": 0.05,
                "bias_walk_mps_per_sqrt_s": 0.018,
            },
        ),
        E2ECase(
            "plain_fig8",
            "gimbal from the autopilot, no realism knob, figure-8 (the reference)",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05},
            settings=TOLD_05,
        ),
        E2ECase(
            "dropouts",
            "bearing dropouts: 3 s every 20 s, and 10 % of the rest lost",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05, "drop_prob": 0.1},
            realism={"dropout_every_s": 20.0, "dropout_length_s": 3.0},
            settings=TOLD_05,
        ),
        E2ECase(
            "gimbal_lag",
            "gimbal tracking lag: the boresight trails the line of sight by 0.1 s (a model error)",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05},
            realism={"gimbal_lag_s": 0.1},
            settings=TOLD_05,
        ),
        E2ECase(
            "tlog_clock",
            "the tlog's own clock: 30 ms jitter, jumps of +500 s and -200 s",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05},
            realism={
                **OWN_COMPONENT,
                "tlog_jitter_s": 0.03,
                "tlog_jumps": ((100.0, 500.0), (200.0, -200.0)),
            },
            settings=TOLD_05,
        ),
        # the noise not told (the default settings), for an estimator that learns it online:
        # the plain gimbal figure-8 of gimbal_vehicle_fig8 with other noise than the defaults
        # assume, and with gross bearing errors; the CRLB is the clean stream's (outliers not
        # counted)
        _adaptive(
            "noise_0p2deg",
            "bearing noise 0.2 deg, exact velocity, not told (gimbal, own component, figure-8)",
            bearing_noise_deg=0.2,
        ),
        _adaptive(
            "noise_2deg",
            "bearing noise 2 deg, exact velocity, not told (gimbal, own component, figure-8)",
            bearing_noise_deg=2.0,
        ),
        _adaptive(
            "noise_student3",
            "bearing noise 0.5 deg RMS, Student-t with 3 degrees of freedom per axis (heavy "
            "tails, no separate outliers), exact velocity, not told (gimbal, figure-8; the bound "
            "is the t noise's, 0.71x the Gaussian's)",
            bearing_noise_deg=0.5,
            bearing_noise_dof=3.0,
        ),
        _adaptive(
            "velocity_white_0p1",
            "bearing noise 0.5 deg, white velocity noise 0.1 m/s, not told (gimbal, figure-8)",
            **B05,
            velocity_noise_mps=0.1,
        ),
        E2ECase(
            "velocity_gm_0p2",
            "velocity error: 0.2 m/s white + 0.1 m/s Gauss-Markov (60 s) + (0.3, -0.2, 0) m/s, "
            "bearing noise 0.5 deg, not told (gimbal from the autopilot, figure-8)",
            "figure8",
            "gimbal",
            emitter={**FAST, **B05, "velocity_noise_mps": 0.2},
            realism=VELOCITY_GM,
        ),
        _adaptive(
            "outliers_5pct",
            "bearing noise 0.5 deg and 5 % outliers 5-30 deg off (false locks), not told",
            **B05,
            outlier_prob=0.05,
        ),
        _adaptive(
            "outliers_20pct",
            "bearing noise 0.5 deg and 20 % outliers 5-30 deg off (false locks), not told",
            **B05,
            outlier_prob=0.2,
        ),
        # a rangefinder on the gimbal: 0.3 m, told (tracker.range_noise_m)
        *(
            E2ECase(
                f"range_{sc}",
                f"gimbal at 10 Hz with a 0.3 m rangefinder, {what}",
                sc,
                "gimbal",
                emitter={**RANGED_RATES, **B05, "rangefinder_noise_m": 0.3},
                realism={"jitter_s": 0.003},
                tracker={"range_noise_m": 0.3},
                settings=TOLD_05,
            )
            for sc, what in (
                ("hover", "hovering still (no motion at all), the target 24.5 m away"),
                ("figure8", "figure-8"),
                ("orbit", "orbit"),
            )
        ),
    )
}
HEADLINE = CASES_HEADLINE = (
    "gimbal_vehicle_fig8",
    "gimbal_earth_fig8",
    "landing_target_weave",
    "mount_status_orbit",
    "camera_point_orbit",
)
#: The noise not told, learnt online (and bearing outliers): run with ``--adaptive`` (or by
#: name with ``--cases``), in their own block of ``docs/accuracy.md``.
ADAPTIVE = (
    "noise_0p2deg",
    "noise_2deg",
    "noise_student3",
    "velocity_white_0p1",
    "velocity_gm_0p2",
    "outliers_5pct",
    "outliers_20pct",
)
#: A rangefinder on the gimbal (its range fused with each bearing): run by name with
#: ``--cases`` or by :mod:`bench.accuracy.ranged`, which writes their block.
RANGED = ("range_hover", "range_figure8", "range_orbit")
#: The blocks of ``docs/accuracy.md`` this bench writes.
BLOCK, BLOCK_DEFAULTS, BLOCK_ADAPTIVE = "end-to-end", "end-to-end-defaults", "end-to-end-adaptive"


def make_scenario(name: str, duration_s: float, **params: Any) -> scenarios.Scenario:
    return scenarios.make(name, duration_s=duration_s, **params)


# -- one run --------------------------------------------------------------------------------


def settings_toml(settings: dict[str, Any], tracker: dict[str, Any]) -> str:
    """The settings file a user would write for this case."""
    lines = ["[observer]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in settings.items()]
    if tracker:
        lines.append("[tracker]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in tracker.items()]
    return "\n".join(lines) + "\n"


def tracker_config(case: E2ECase) -> TrackerConfig:
    return TrackerConfig(observer=ObserverConfig(**case.settings), **case.tracker)


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    with open(path, encoding="utf-8") as fh:
        return [json.loads(line) for line in fh if line.strip()]


def score(
    records: list[dict[str, Any]],
    truth: list[dict[str, Any]],
    *,
    sigma_rad: float,
    q_x: float,
    duration_s: float,
    t0_boot_s: float,
    gm_std_mps: float = 0.0,
    gm_tau_s: float = math.inf,
    range_sigma_m: float = 0.0,
) -> dict[str, float]:
    """Metrics of one run: the records of its target against its truth (both keyed by the
    autopilot clock, ``t_boot_s``); the bound is that of the true noise (``sigma_rad``,
    ``q_x`` and the velocity's Gauss-Markov part, :func:`bench.accuracy.core.crlb`)."""
    tt = np.array([d["t_boot_s"] for d in truth])
    order = np.argsort(tt, kind="stable")
    tt = tt[order]
    xt = np.array([d["rel_pos_ned_m"] for d in truth])[order]
    at = np.array([d["bias_ned_mps"] for d in truth])[order]
    t = np.array([r["t_boot_s"] for r in records])
    xh = np.array([r["rel_pos_ned_m"] for r in records], dtype=float)
    ah = np.array([r["bias_ned_mps"] for r in records], dtype=float)
    sd = np.array([r["rel_pos_std_ned_m"] or [math.nan] * 3 for r in records], dtype=float)
    inside = (t >= tt[0]) & (t <= tt[-1])
    t, xh, ah, sd = t[inside], xh[inside], ah[inside], sd[inside]
    x_true = np.column_stack([np.interp(t, tt, xt[:, i]) for i in range(3)])
    a_true = np.column_stack([np.interp(t, tt, at[:, i]) for i in range(3)])
    err = xh - x_true
    e2 = np.sum(err * err, axis=1)
    r_true = np.linalg.norm(x_true, axis=1)
    rel = np.sqrt(e2) / r_true
    t_steady = t0_boot_s + (1.0 - STEADY_FRACTION) * duration_s
    sel = t >= t_steady
    bound = core.crlb(
        tt, xt, sigma_rad, q_x, gm_std_mps=gm_std_mps, gm_tau_s=gm_tau_s,
        range_sigma_m=range_sigma_m,
    )  # fmt: skip
    bsel = tt >= t_steady
    crlb_rms = math.sqrt(float(np.mean(bound[bsel] ** 2)))
    rms = math.sqrt(float(np.mean(e2[sel])))
    with np.errstate(all="ignore"):
        nees = float(np.mean((err[sel] / sd[sel]) ** 2))
    above = ~(rel < core.CONVERGED_REL)
    t10 = math.inf
    if not above[-1]:
        last = np.nonzero(above)[0]
        t10 = float(t[last[-1] + 1] - t0_boot_s) if len(last) else float(t[0] - t0_boot_s)
    db = ah[sel] - a_true[sel]
    geo = _geodetic_errors(records, truth, inside, sel)
    return {
        **geo,
        "rms_m": rms,
        "crlb_m": crlb_rms,
        "ratio": rms / crlb_rms,
        "sq_m2": float(np.sum(e2[sel])),
        "crlb_sq_m2": float(np.sum(bound[bsel] ** 2)),
        "n": int(np.sum(sel)),
        "n_bound": int(np.sum(bsel)),
        "rel_rms_pct": 100.0 * math.sqrt(float(np.mean(rel[sel] ** 2))),
        "max_rel_pct": 100.0 * float(np.max(rel[sel])),
        "range_bias_pct": 100.0
        * float(np.mean((np.linalg.norm(xh[sel], axis=1) - r_true[sel]) / r_true[sel])),
        "bias_rms_mps": math.sqrt(float(np.mean(np.sum(db * db, axis=1)))),
        "nees_axis": nees,
        "t10_s": t10,
        "converged_share": float(
            np.mean([r["status"] == "converged" for r, k in zip(records, inside, strict=True) if k])
        ),
        "first_converged_s": next(
            (r["t_boot_s"] - records[0]["t_boot_s"] for r in records if r["status"] == "converged"),
            math.inf,
        ),
    }


def _geodetic_errors(
    records: list[dict[str, Any]],
    truth: list[dict[str, Any]],
    inside: np.ndarray,
    sel: np.ndarray,
) -> dict[str, float]:
    """The target's published latitude, longitude and altitude against the truth's (its
    local position on the emitter's origin, :data:`sim.emitter.ORIGIN_LAT_DEG`, as the emitter, an
    ArduPilot, places it: :func:`sim.emitter.ardupilot_offset`)
    over the steady window: the median horizontal and vertical errors (m) and the share of
    estimates whose horizontal error is within twice their ``target_h_std_m`` (about 95 %
    for an honest one); the same share over every estimate from the run's first
    ``converged`` status on (``geo_h_within_2sd_conv``, with ``geo_conv_n`` such estimates:
    "after convergence" as the product declares it); empty when no record carries them."""
    recs = [r for r, k in zip(records, inside, strict=True) if k]
    recs = [r for r, k in zip(recs, sel, strict=True) if k and r.get("target_lat_deg") is not None]
    if not recs:
        return {}
    err = geo.map_errors(recs, *_truth_ll(recs, truth))
    after = [r for r in geo.after_convergence(records) if r.get("target_lat_deg") is not None]
    conv = geo.map_errors(after, *_truth_ll(after, truth))["within_2sd"] if after else math.nan
    return {
        "geo_h_med_m": err["h_median_m"],
        "geo_v_med_m": err["v_median_m"],
        "geo_h_within_2sd": err["within_2sd"],
        "geo_h_within_2sd_conv": conv,
        "geo_conv_n": len(after),
    }


def _truth_ll(recs: list[dict[str, Any]], truth: list[dict[str, Any]]) -> tuple[Any, Any, Any]:
    """The truth's target latitude, longitude and altitude at the records' times (its local
    position interpolated, on the emitter's origin, placed as the emitter places it)."""
    tt = np.array([d["t_boot_s"] for d in truth])
    order = np.argsort(tt, kind="stable")
    tp = np.array([d["target_pos_ned_m"] for d in truth])[order]
    t = np.array([r["t_boot_s"] for r in recs])
    tp_i = np.column_stack([np.interp(t, tt[order], tp[:, i]) for i in range(3)])
    lat0, lon0, alt0 = em.ORIGIN_LAT_DEG, em.ORIGIN_LON_DEG, em.ORIGIN_ALT_M
    return em.ardupilot_offset(lat0, lon0, alt0, tp_i[:, 0], tp_i[:, 1], tp_i[:, 2])


def run_one(
    case_name: str,
    seed: int,
    duration_s: float,
    workdir: str | None = None,
    defaults: bool = False,
    keep_records: bool = False,
    live: bool = False,
    log_format: str = "tlog",
) -> dict:
    """Emit, replay and score one run of a case (a process-pool task); ``defaults``: the
    product's default settings instead of the case's (the noise not told); ``keep_records``:
    the run's estimate records and truth too (``records``, ``truth``); ``live``: replay's
    ``--live`` (what the service publishes) instead of its default (committed estimates)."""
    case = CASES[case_name]
    if defaults:
        case = replace(case, settings={})
    t_wall = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        d = Path(tmp)
        sc = make_scenario(case.scenario, duration_s, **case.scenario_params)
        cfg = em.EmitterConfig(
            bearing=case.bearing, duration_s=duration_s, seed=seed, **case.emitter
        )
        vehicle = realism.SwingVehicle(sc, yaw_swing_deg=case.yaw_swing_deg)
        emitter = em.Emitter(sc, cfg, vehicle)
        link = realism.Realism(seed=seed, **case.realism)
        tlog, truth_path, out = d / "run.tlog", d / "truth.jsonl", d / "est.jsonl"
        arrivals = link.apply(emitter.emissions(), cfg.t0_unix_s, cfg.sysid)
        realism.write(arrivals, tlog=tlog, truth=truth_path)
        t_emit = time.perf_counter() - t_wall
        settings = d / "settings.toml"  # what the user writes, read as replay --config does
        settings.write_text(settings_toml(case.settings, case.tracker))
        tc = st.resolve(settings).tracker_config()
        source, target = tlog, em.TARGET_OF[case.bearing]
        if log_format != "tlog":  # the same flight as the autopilot's own log
            source = d / f"run.{log_format}"
            logwriters.convert(tlog, source)
            target = logwriters.TARGET_IN.get((log_format, target), target)
            t_emit = time.perf_counter() - t_wall
        summary = replay(str(source), tracker_config=tc, output_jsonl=out, live=live)
        t_replay = time.perf_counter() - t_wall - t_emit
        noise_end = summary.targets[f"{cfg.sysid}/{target}"].noise
        noise_60 = None
        if case_name in ADAPTIVE:  # what was learnt after the first 60 s
            recs = split_records(tlog.read_bytes())
            t_first = recs[0].t_us
            early = d / "first60.tlog"
            cut = (t_first or 0) + 60_000_000
            kept = [r.data for r in recs if r.t_us is not None and r.t_us <= cut]
            early.write_bytes(b"".join(kept))
            noise_60 = (
                replay(str(early), tracker_config=tc, live=live)
                .targets[f"{cfg.sysid}/{target}"]
                .noise
            )
        records = [r for r in read_jsonl(out) if r["target"] == target]
        truth = truth_file.read(truth_path, em.TARGET_OF[case.bearing])
    dt_v = 1.0 / cfg.position_hz
    m = score(
        records,
        truth,
        **case.bound_noise(dt_v),
        duration_s=duration_s,
        t0_boot_s=cfg.boot_at_start_s,
    )
    m.update(
        case=case_name,
        seed=seed,
        emit_s=t_emit,
        replay_s=t_replay,
        events=dict(summary.events),
        skipped=dict(summary.skipped),
        learnt_bearing_deg=None if noise_end is None else noise_end.bearing_noise_deg,
        learnt_velocity_mps=None if noise_end is None else noise_end.velocity_noise_mps,
        learnt_bearing_deg_60s=None if noise_60 is None else noise_60.bearing_noise_deg,
        learnt_velocity_mps_60s=None if noise_60 is None else noise_60.velocity_noise_mps,
        outliers=None if noise_end is None else noise_end.outliers,
        reacquisitions=None if noise_end is None else noise_end.reacquisitions,
        innovation_lag1=None
        if noise_end is None or noise_end.innovation_corr is None
        else noise_end.innovation_corr.lag1,
    )
    if keep_records:
        m.update(records=records, truth=truth)
    return m


def pooled(runs: list[dict]) -> dict[str, float]:
    """Metrics of a case over its runs (RMS values pooled over all steady samples)."""
    sq = sum(r["sq_m2"] for r in runs)
    n = sum(r["n"] for r in runs)
    csq = sum(r["crlb_sq_m2"] for r in runs)
    nb = sum(r["n_bound"] for r in runs)
    rms = math.sqrt(sq / n)
    crlb = math.sqrt(csq / nb)
    t10 = sorted(r["t10_s"] for r in runs)
    return {
        "runs": len(runs),
        "rms_m": rms,
        "crlb_m": crlb,
        "ratio": rms / crlb,
        "worst_ratio": max(r["ratio"] for r in runs),
        "rel_rms_pct": float(np.mean([r["rel_rms_pct"] for r in runs])),
        "range_bias_pct": float(np.mean([r["range_bias_pct"] for r in runs])),
        "bias_rms_mps": math.sqrt(float(np.mean([r["bias_rms_mps"] ** 2 for r in runs]))),
        "nees_axis": float(np.mean([r["nees_axis"] for r in runs])),
        "t10_med_s": float(np.median(t10)),
        "t10_max_s": t10[-1],
        "converged_share": float(np.mean([r["converged_share"] for r in runs])),
        **{
            k: float(np.mean([r[k] for r in runs]))
            for k in (
                "learnt_bearing_deg", "learnt_velocity_mps",
                "learnt_bearing_deg_60s", "learnt_velocity_mps_60s", "reacquisitions",
            )
            if all(r.get(k) is not None for r in runs)
        },
        **(
            {"innovation_lag1_max": max(r["innovation_lag1"] for r in runs)}
            if all(r.get("innovation_lag1") is not None for r in runs)
            else {}
        ),
        **(
            {
                "geo_h_med_m": float(np.median([r["geo_h_med_m"] for r in runs])),
                "geo_h_med_worst_m": max(r["geo_h_med_m"] for r in runs),
                "geo_v_med_m": float(np.median([r["geo_v_med_m"] for r in runs])),
                "geo_h_within_2sd": float(np.mean([r["geo_h_within_2sd"] for r in runs])),
                # over the estimates after convergence, pooled over the runs that converged
                "geo_conv_n": sum(r.get("geo_conv_n", 0) for r in runs),
                "geo_h_within_2sd_conv": _pooled_share(runs),
            }
            if all("geo_h_med_m" in r for r in runs)
            else {}
        ),
    }  # fmt: skip


def _pooled_share(runs: list[dict[str, Any]]) -> float:
    """The share within twice ``target_h_std_m`` over every run's estimates after its
    convergence, pooled (weighted by their numbers); NaN when no run converged."""
    n = sum(r.get("geo_conv_n", 0) for r in runs)
    if not n:
        return math.nan
    return (
        sum(r["geo_h_within_2sd_conv"] * r["geo_conv_n"] for r in runs if r.get("geo_conv_n")) / n
    )


def run_cases(
    names: Sequence[str],
    seeds: int,
    duration_s: float,
    jobs: int,
    defaults: bool = False,
    live: bool = False,
) -> dict[str, dict[str, Any]]:
    tasks = [(n, s) for n in names for s in range(seeds)]
    out: dict[str, list[dict]] = {n: [] for n in names}
    k = len(tasks)
    if jobs <= 1:
        results = [run_one(n, s, duration_s, None, defaults, False, live) for n, s in tasks]
    else:
        with ProcessPoolExecutor(jobs) as pool:
            names_, seeds_ = zip(*tasks, strict=True)
            results = list(
                pool.map(
                    run_one, names_, seeds_, [duration_s] * k, [None] * k, [defaults] * k,
                    [False] * k, [live] * k,
                )
            )  # fmt: skip
    for r in results:
        out[r["case"]].append(r)
    return {n: {"pooled": pooled(rs), "runs": rs} for n, rs in out.items()}


def table(results: dict[str, dict[str, Any]]) -> str:
    rows = []
    for name, res in results.items():
        p = res["pooled"]
        rows.append(
            f"| {name} | {1000 * p['rms_m']:.1f} mm | {1000 * p['crlb_m']:.1f} mm "
            f"| {p['ratio']:.2f}x ({p['worst_ratio']:.2f}x) | {p['nees_axis']:.2f} "
            f"| {p['range_bias_pct']:+.2f} % | {p['bias_rms_mps']:.3f} m/s "
            f"| {p['t10_med_s']:.1f} / {p['t10_max_s']:.1f} s "
            f"| {100 * p['converged_share']:.0f} % |"
        )
    columns = (
        "case",
        "position RMS, last third",
        "CRLB",
        "ratio (worst seed)",
        "NEES per axis",
        "range bias",
        "bias RMS",
        "t10 median / max",
        "converged",
    )
    return markdown_table(columns, rows)


def _share(x: float) -> str:
    return "no convergence" if not math.isfinite(x) else f"{100 * x:.0f} %"


def geo_table(results: dict[str, dict[str, Any]]) -> str:
    """The target on the map (``target_lat_deg``, ``target_lon_deg``, ``target_alt_m``)
    against the truth's over the last third: median errors (median over runs, and the worst
    run's horizontal median) and the share of estimates within twice ``target_h_std_m``;
    and that share over every estimate from each run's first ``converged`` status on."""
    rows = []
    for name, res in results.items():
        p = res["pooled"]
        if "geo_h_med_m" not in p:
            continue
        rows.append(
            f"| {name} | {100 * p['geo_h_med_m']:.1f} cm ({100 * p['geo_h_med_worst_m']:.1f} cm) "
            f"| {100 * p['geo_v_med_m']:.1f} cm | {100 * p['geo_h_within_2sd']:.0f} % "
            f"| {_share(p.get('geo_h_within_2sd_conv', math.nan))} |"
        )
    columns = (
        "case",
        "horizontal error, median (worst run)",
        "vertical error, median",
        "within 2 target_h_std_m",
        "within 2 sigma, after convergence",
    )
    return markdown_table(columns, rows)


def markdown(
    res: dict[str, dict[str, Any]], *, seeds: int, duration_s: float, wall_s: float
) -> str:
    """The end-to-end block of ``docs/accuracy.md``."""
    head = [c for c in res if c in HEADLINE]
    knobs = [c for c in res if c not in HEADLINE]
    lines = [
        "## End to end, through replay",
        "",
        "Measured the way a user's data goes (`python -m bench.accuracy.e2e --seeds "
        f"{seeds} --write-docs`, {len(res) * seeds} runs of {duration_s:g} s, {wall_s:.0f} s "
        "on 2 cores): the emitter writes a tlog of each case with the realism knobs of "
        "`sim/realism.py`, `mav-observer replay`'s code reads it with the settings a user "
        "would write in a settings file (the bearing and velocity noise told) and publishes "
        "each bearing's estimate once the velocity after it is known (replay's default; "
        "`--live`, what the service publishes, above), and the "
        "estimates are scored against the emitter's truth and the Cramér-Rao bound along the "
        "same truth. RMS over the last third of every run, pooled over seeds (one run's error "
        "is correlated over minutes: one seed alone ranges from 0.6x to 1.6x the bound); NEES "
        "per axis from the per-axis standard deviations of the records (1: consistent); t10 the "
        "time after which the error stays under 10 % of the range.",
        "",
        "### The five bearing paths at 0.5 deg, the noise told",
        "",
        table({c: res[c] for c in head}),
        "",
        "| case | what |",
        "|---|---|",
        *[f"| {c} | {CASES[c].description} |" for c in head],
    ]
    if knobs:
        lines += [
            "",
            "### Each realism knob",
            "",
            "The CRLB is that of the stream's true noise: white bearing and velocity noise "
            "and the velocity error's Gauss-Markov part (velocity_coloured: the posterior "
            "bound of the state augmented with it); a model error (gimbal_lag) is not in it. "
            "It is the bound of the velocity and the bearings alone: the product also takes "
            "the vehicle's displacement from LOCAL_POSITION_NED's positions, which the "
            "emitter keeps true (GNSS-like), so where the velocity carries an error that the "
            "positions do not (velocity_coloured) it can do better than that bound "
            '([frames.md](frames.md), "Velocity from the positions"); its bias RMS is then '
            "against the constant part, while the estimate holds the constant plus the "
            "Gauss-Markov part's value when the positions' drift was learnt.",
            "",
            table({c: res[c] for c in knobs}),
            "",
            "| case | what | settings told |",
            "|---|---|---|",
            *[
                f"| {c} | {CASES[c].description} | "
                + ", ".join(f"{k} = {v}" for k, v in CASES[c].settings.items())
                + " |"
                for c in knobs
            ],
        ]
    return "\n".join(lines)


def markdown_defaults(
    res: dict[str, dict[str, Any]], *, seeds: int, duration_s: float, wall_s: float
) -> str:
    """The block of the same cases with the default settings (the noise not told)."""
    return "\n".join(
        [
            "### The same, with the default settings (the noise not told)",
            "",
            f"`python -m bench.accuracy.e2e --defaults --seeds {seeds} --write-docs` "
            f"({len(res) * seeds} runs of {duration_s:g} s, {wall_s:.0f} s): what a new user "
            "gets without a settings file: the bearing and velocity noise and the bearings' "
            "latency and the bias's random walk learnt online (`docs/tuning.md`), robust "
            "weighting of gross errors on.",
            "",
            table(res),
        ]
    )


def markdown_adaptive(
    res: dict[str, dict[str, Any]], *, seeds: int, duration_s: float, wall_s: float
) -> str:
    """The block of the :data:`ADAPTIVE` cases: the noise not told, learnt online, and
    bearing outliers."""
    return "\n".join(
        [
            "### Noise not told: learnt online, and outliers",
            "",
            f"`python -m bench.accuracy.e2e --adaptive --seeds {seeds} --write-docs` "
            f"({len(res) * seeds} runs of {duration_s:g} s, {wall_s:.0f} s): the gimbal "
            "figure-8 of gimbal_vehicle_fig8 with the default settings (the noise learnt "
            "online, from a 1 deg and a 0.05 m/s prior), on streams whose noise differs from "
            "those priors, or with a share of bearings that are gross errors (5-30 deg off the "
            "line of sight, a tracker's false lock); the CRLB is that of the clean stream's "
            "true noise (the outliers not counted). `learnt` is the bearing noise in use at the "
            "end of the runs (mean over seeds) against the stream's.",
            "",
            table(res),
            "",
            "| case | what | bearing noise: stream / learnt at 60 s / at the end "
            "| velocity noise: stream / learnt at 60 s / at the end | re-acquisitions per run |",
            "|---|---|---|---|---|",
            *[_learnt_row(c, r["pooled"]) for c, r in res.items()],
        ]
    )


def _learnt_row(name: str, p: dict[str, float]) -> str:
    c = CASES[name]

    def val(key: str, fmt: str) -> str:
        return format(p[key], fmt) if key in p else "-"

    return (
        f"| {name} | {c.description} "
        f"| {c.bearing_deg:g} / {val('learnt_bearing_deg_60s', '.3f')} / "
        f"{val('learnt_bearing_deg', '.3f')} deg "
        f"| {c.velocity_white_mps:g} / {val('learnt_velocity_mps_60s', '.3f')} / "
        f"{val('learnt_velocity_mps', '.3f')} m/s | {val('reacquisitions', '.2f')} |"
    )


def block_of(cases: Sequence[str], *, defaults: bool, adaptive: bool) -> str:
    """The block of ``docs/accuracy.md`` that a run of ``cases`` writes: the adaptive cases
    go in a block of their own, and not with the others (:class:`ValueError` for a mix)."""
    n_adaptive = sum(c in ADAPTIVE for c in cases)
    if adaptive or (cases and n_adaptive == len(cases)):
        if n_adaptive != len(cases):
            raise ValueError(
                f"the {BLOCK_ADAPTIVE} block is of the ADAPTIVE cases only {ADAPTIVE}, "
                f"got {[c for c in cases if c not in ADAPTIVE]}"
            )
        name = BLOCK_ADAPTIVE
    elif n_adaptive:
        raise ValueError(
            f"the ADAPTIVE cases {[c for c in cases if c in ADAPTIVE]} have a block of their "
            "own: run them apart (--adaptive)"
        )
    else:
        name = BLOCK_DEFAULTS if defaults else BLOCK
    if name not in blocks.ORDER:  # put_block would drop it, and so would the page's writer
        raise ValueError(f"block {name!r} is not in bench.accuracy.blocks.ORDER {blocks.ORDER}")
    return name


def write_block(name: str, res: dict[str, dict[str, Any]], **kw: Any) -> None:
    """Write block ``name`` (of :func:`block_of`) of ``docs/accuracy.md`` from ``res``."""
    make = {BLOCK: markdown, BLOCK_DEFAULTS: markdown_defaults, BLOCK_ADAPTIVE: markdown_adaptive}
    blocks.put_block(DOCS, name, make[name](res, **kw))


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.accuracy.e2e", description=__doc__)
    p.add_argument(
        "--cases",
        nargs="+",
        choices=list(CASES),
        help="default: every case but the ADAPTIVE ones (with --adaptive: those)",
    )
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--duration", type=float, default=300.0, help="s per run")
    p.add_argument("--jobs", type=int, default=min(4, os.cpu_count() or 1))
    p.add_argument("--json", type=Path, help="write every run's metrics here")
    p.add_argument("--write-docs", action="store_true", help="write the block of docs/accuracy.md")
    p.add_argument("--from-json", type=Path, help="tables from a --json file, no run")
    p.add_argument(
        "--defaults",
        action="store_true",
        help="the product's default settings instead of each case's (the noise not told)",
    )
    p.add_argument(
        "--live",
        action="store_true",
        help="replay --live: what the service publishes (each bearing's estimate at its "
        "arrival) instead of replay's default (once the velocity after it is known); no docs "
        "block of its own",
    )
    p.add_argument(
        "--adaptive",
        action="store_true",
        help=f"the cases of the noise not told and outliers {ADAPTIVE} (already with the "
        f"default settings); --write-docs writes their block, {BLOCK_ADAPTIVE}",
    )
    args = p.parse_args(argv)
    if args.cases is None:
        args.cases = (
            list(ADAPTIVE)
            if args.adaptive
            else [c for c in CASES if c not in ADAPTIVE and c not in RANGED]
        )
    if args.from_json:
        doc = json.loads(args.from_json.read_text())
        if "results" not in doc:  # a bare {case: results} file
            doc = {"results": doc, "wall_s": math.nan, "seeds": args.seeds}
            doc["duration_s"] = args.duration
        res, wall = doc["results"], doc["wall_s"]
        args.seeds, args.duration = doc["seeds"], doc["duration_s"]
        if args.write_docs:
            try:
                name = block_of(list(res), defaults=args.defaults, adaptive=args.adaptive)
            except ValueError as e:
                p.error(str(e))
            write_block(name, res, seeds=args.seeds, duration_s=args.duration, wall_s=wall)
        print(table(res))
        print(geo_table(res))
        return 0
    block = None
    if args.write_docs and args.live:
        p.error("--live has no docs block: give its --json to the docs by hand")
    if args.write_docs:  # refused before the runs, not after
        try:
            block = block_of(args.cases, defaults=args.defaults, adaptive=args.adaptive)
        except ValueError as e:
            p.error(str(e))
    t0 = time.perf_counter()
    res = run_cases(args.cases, args.seeds, args.duration, args.jobs, args.defaults, args.live)
    wall = time.perf_counter() - t0
    print(table(res))
    print(geo_table(res))
    for name, r in res.items():
        ev = {}
        for run in r["runs"]:
            for k, v in run["events"].items():
                ev[k] = ev.get(k, 0) + v
        if ev:
            print(f"{name}: events {ev}")
    print(f"{sum(len(r['runs']) for r in res.values())} runs in {wall:.0f} s")
    if args.json:
        doc = {"results": res, "wall_s": wall, "seeds": args.seeds, "duration_s": args.duration}
        args.json.write_text(json.dumps(doc, indent=1, default=str))
    if block is not None:
        write_block(block, res, seeds=args.seeds, duration_s=args.duration, wall_s=wall)
    return 0


if __name__ == "__main__":
    sys.exit(main())
