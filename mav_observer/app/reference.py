"""A reference track (the truth, when there is one) and the errors of a replay against it.

``mav-observer replay LOG --truth FILE`` reads FILE as JSON Lines, one object per reference
point, with the estimate record's own names and meaning (``docs/schema.md``, "A reference
track"): ``t_boot_s`` (vehicle autopilot clock, s), ``sysid``, ``target``,
``rel_pos_ned_m`` (target minus vehicle, NED, m) and ``bias_ned_mps`` (the paper's ``a``,
NED, m/s). Other keys are ignored: any tool may write a reference track. The simulator's
truth files (``sim/truth.py``, which owns their format) are such tracks.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from mav_observer.errors import MavObserverError

#: The keys a reference point must have.
KEYS = ("t_boot_s", "sysid", "target", "rel_pos_ned_m", "bias_ned_mps")


class ReferenceError(MavObserverError, ValueError):
    """A reference track could not be read; the message names the file, line and field."""


class TimedEstimates(Protocol):
    """What the errors are computed from (a :class:`mav_observer.app.replay.Series`)."""

    t_boot_s: list[float]
    rel_pos: list[Any]
    bias: list[Any]
    pos_std: list[Any]
    status: list[str]


def parse_line(line: str) -> tuple[str, float, list[float], list[float]]:
    """One reference point -> (``"sysid/target"``, ``t_boot_s``, position, bias); raises
    :class:`ReferenceError` naming what is wrong."""
    try:
        d = json.loads(line)
        key = f"{int(d['sysid'])}/{d['target']}"
        t = float(d["t_boot_s"])
        x = [float(v) for v in d["rel_pos_ned_m"]]
        a = [float(v) for v in d["bias_ned_mps"]]
    except (ValueError, KeyError, TypeError) as exc:
        raise ReferenceError(f"bad reference point: {exc!r}") from exc
    if len(x) != 3 or len(a) != 3:
        raise ReferenceError(f"rel_pos_ned_m and bias_ned_mps need 3 values, got {x!r}, {a!r}")
    if not all(math.isfinite(v) for v in (t, *x, *a)):
        raise ReferenceError(f"non-finite value in a reference point: t_boot_s={t!r}, {x!r}, {a!r}")
    return key, t, x, a


def read(path: str | Path) -> dict[str, dict[str, list[Any]]]:
    """A reference track file -> per ``"sysid/target"``: ``t_boot_s``, ``rel_pos_ned_m``,
    ``bias_ned_mps`` lists (file order)."""
    out: dict[str, dict[str, list[Any]]] = {}
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ReferenceError(f"cannot read the reference track {path}: {exc}") from exc
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            key, t, x, a = parse_line(line)
        except ReferenceError as exc:
            raise ReferenceError(f"{path}:{lineno}: {exc}") from exc
        s = out.setdefault(key, {"t_boot_s": [], "rel_pos_ned_m": [], "bias_ned_mps": []})
        s["t_boot_s"].append(t)
        s["rel_pos_ned_m"].append(x)
        s["bias_ned_mps"].append(a)
    return out


def errors(series: TimedEstimates, track: dict[str, list[Any]]) -> dict[str, Any]:
    """Position (m) and bias (m/s) error norms of ``series`` against ``track`` interpolated at
    the series' times (those inside the track's span), with the true range (m)."""
    tt = np.asarray(track["t_boot_s"], dtype=float)
    order = np.argsort(tt, kind="stable")
    tt = tt[order]
    xs = np.asarray(track["rel_pos_ned_m"], dtype=float)[order]
    as_ = np.asarray(track["bias_ned_mps"], dtype=float)[order]
    t = np.asarray(series.t_boot_s, dtype=float)
    inside = (t >= tt[0]) & (t <= tt[-1])
    t = t[inside]
    x_true = np.column_stack([np.interp(t, tt, xs[:, i]) for i in range(3)])
    a_true = np.column_stack([np.interp(t, tt, as_[:, i]) for i in range(3)])
    xhat = np.asarray(series.rel_pos, dtype=float).reshape(-1, 3)[inside]
    ahat = np.asarray(series.bias, dtype=float).reshape(-1, 3)[inside]
    sd = np.asarray(series.pos_std, dtype=float).reshape(-1, 3)[inside]
    return {
        "t_boot_s": t,
        "pos_err_m": np.linalg.norm(xhat - x_true, axis=1),
        "pos_sigma_m": np.sqrt(np.sum(sd**2, axis=1)),  # NaN: no covariance published
        "converged": np.asarray(series.status, dtype=object)[inside] == "converged",
        "range_true_m": np.linalg.norm(x_true, axis=1),
        "bias_err_mps": np.linalg.norm(ahat - a_true, axis=1),
    }


def honesty(errs: dict[str, Any], rel_threshold: float = 0.05) -> dict[str, float]:
    """From the first ``converged`` estimate on: how many estimates there are, how many of
    them the published sigma did not cover (position error beyond twice the 1-sigma radius
    ``sqrt(trace P_xx)``, or no sigma), the worst error over that sigma, and the time (s) and
    share of the whole span during which the error exceeded ``rel_threshold`` of the range
    (each estimate's error held to the next)."""
    t = errs["t_boot_s"]
    conv = np.nonzero(errs["converged"])[0]
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    if len(conv) == 0:
        return {"after_convergence": 0, "uncovered": 0, "worst_sigma_ratio": math.nan,
                "time_above_s": 0.0, "time_above_share": 0.0}  # fmt: skip
    k = int(conv[0])
    err, sig = errs["pos_err_m"][k:], errs["pos_sigma_m"][k:]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = err / sig
    uncovered = int(np.sum(~(ratio <= 2.0)))
    above = err / errs["range_true_m"][k:] > rel_threshold
    dt = np.diff(t[k:], append=t[-1])
    time_above = float(np.sum(dt[above]))
    finite = ratio[np.isfinite(ratio)]
    return {
        "after_convergence": len(err),
        "uncovered": uncovered,
        "worst_sigma_ratio": float(np.max(finite)) if len(finite) else math.nan,
        "time_above_s": time_above,
        "time_above_share": time_above / span if span > 0.0 else 0.0,
    }


def last_third(errs: dict[str, Any]) -> dict[str, float]:
    """Over the last third of the span: the worst position error relative to the range, the
    worst bias error (m/s), and how many estimates that was."""
    t = errs["t_boot_s"]
    if len(t) == 0:
        return {"max_rel_pos_err": math.nan, "max_bias_err_mps": math.nan, "samples": 0}
    sel = t >= t[0] + 2.0 * (t[-1] - t[0]) / 3.0
    return {
        "max_rel_pos_err": float(np.max(errs["pos_err_m"][sel] / errs["range_true_m"][sel])),
        "max_bias_err_mps": float(np.max(errs["bias_err_mps"][sel])),
        "samples": int(np.sum(sel)),
    }


__all__ = ["KEYS", "ReferenceError", "errors", "honesty", "last_third", "parse_line", "read"]
