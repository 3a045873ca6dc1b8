"""Observability monitor: excitation over a sliding window, convergence, status rules (pure).

**Excitation** is the smallest eigenvalue of the time-average of ``Pi_y = I - y y^T`` over
the last ``window_s`` seconds (the paper's persistent-excitation integral, Definition 2.1,
divided by the window length). It is dimensionless, between 0 (the bearing did not move,
or there was no bearing) and ``(n-1)/n`` (bearings spread evenly in every direction). Time
without a usable bearing counts as zero excitation. For a vehicle circling a target the level
is roughly the squared sine of the angle the bearing sweeps away from its mean direction.

The window is kept as ``buckets`` equal time buckets (memory is constant, whatever the
sample rate): the effective window is between ``(buckets-1)/buckets * window_s`` and
``window_s`` long.

**Convergence indicator** ``correction_rel``: the net correction the observer applied over
the window, relative to the estimated range::

    (|sum dx| + W |sum da|) / |xhat|

where ``dx`` is what each step's correction moved ``xhat`` beyond the pure prediction
``v + ahat``, ``da`` the change of ``ahat`` and ``W`` the covered window length. For an
exponentially converging observer with time constant shorter than the window, the net
correction over a window is about the remaining error, so this is a truth-free proxy of the
relative error.

**Status rules** (first match wins; ``window full`` means the window holds ``window_s`` of
data since the observer started):

1. ``stale``: no estimate possible or trustworthy: observer not started, or the latest
   bearing is older than ``max_bearing_age_s``, or the latest velocity older than
   ``max_velocity_age_s``. The observer only predicts.
2. ``not observable``: window full and excitation below ``excitation_min`` (below twice it
   while already ``not observable``: hysteresis). Range and the bias along the bearing are
   not observable; the estimate drifts with any error of the bias along the line of sight.
3. ``converged``: observable (not stale, not "not observable") for at least ``window_s``,
   ``correction_rel <= converged_tol`` (``<= 2 converged_tol`` while already converged) and
   the estimator settled (what it learns, a gimbal's latency, no longer moving the estimate:
   ``Estimator.settled``).
4. ``converging``: otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from mav_observer.discrete import sym_eigvals
from mav_observer.errors import StateError
from mav_observer.samples import Status


class ExcitationWindow:
    """Sliding-window accumulator of ``int y y^T dt``, usable-bearing time and corrections.

    Times are on the observer's time base (s). Intervals must be added in time order.
    """

    def __init__(self, n: int, window_s: float, buckets: int) -> None:
        self.n = n
        self.window_s = float(window_s)
        self.buckets = int(buckets)
        self.bucket_s = self.window_s / self.buckets
        # per bucket: index, covered_s, valid_s, yy (flat n x n), dx (n), da (n): plain lists
        self._idx: list[int] = []
        self._covered: list[float] = []
        self._valid: list[float] = []
        self._yy: list[list[float]] = []
        self._dx: list[list[float]] = []
        self._da: list[list[float]] = []
        self._resum()

    @staticmethod
    def _sum(vectors: list[list[float]], size: int) -> list[float]:
        out = [0.0] * size
        for vec in vectors:
            for i, x in enumerate(vec):
                out[i] += x
        return out

    def _resum(self) -> None:
        """Recompute the window totals from the buckets (exact; done when buckets drop)."""
        n = self.n
        self._tot_covered = float(sum(self._covered))
        self._tot_valid = float(sum(self._valid))
        self._tot_yy = self._sum(self._yy, n * n)
        self._tot_dx = self._sum(self._dx, n)
        self._tot_da = self._sum(self._da, n)

    # -- accumulation ---------------------------------------------------------------
    def _bucket(self, t_s: float) -> int:
        """Position in the lists of the bucket holding time ``t_s``, creating it."""
        idx = math.floor(t_s / self.bucket_s)
        if self._idx and idx <= self._idx[-1]:
            # same bucket, or (rounding at an edge) an older one: use the newest
            return len(self._idx) - 1
        self._idx.append(idx)
        self._covered.append(0.0)
        self._valid.append(0.0)
        self._yy.append([0.0] * (self.n * self.n))
        self._dx.append([0.0] * self.n)
        self._da.append([0.0] * self.n)
        self._drop_old(idx)
        return len(self._idx) - 1

    def _drop_old(self, newest_idx: int) -> None:
        cut = 0
        while cut < len(self._idx) and self._idx[cut] <= newest_idx - self.buckets:
            cut += 1
        if cut:
            for lst in (self._idx, self._covered, self._valid, self._yy, self._dx, self._da):
                del lst[:cut]
            self._resum()

    def add_interval(
        self, t0_s: float, t1_s: float, yy_integral: Sequence[float] | None, valid_s: float
    ) -> None:
        """Account ``[t0_s, t1_s]``: ``valid_s`` of it had a usable bearing, over which
        ``yy_integral`` is the integral of ``y y^T`` (flat, row-major; ``None`` when
        ``valid_s`` is 0). An interval spanning buckets is shared out in proportion to time."""
        span = t1_s - t0_s
        if span <= 0.0:
            return
        idx = math.floor(t0_s / self.bucket_s)
        if self._idx and self._idx[-1] == idx and t1_s <= (idx + 1) * self.bucket_s:
            # the usual case: inside the newest bucket
            self._covered[-1] += span
            self._tot_covered += span
            if yy_integral is not None and valid_s > 0.0:
                self._valid[-1] += valid_s
                self._tot_valid += valid_s
                bucket, tot = self._yy[-1], self._tot_yy
                for i, v in enumerate(yy_integral):
                    bucket[i] += v
                    tot[i] += v
            return
        start = max(t0_s, t1_s - self.window_s)  # older parts would fall out anyway
        t = start
        while t < t1_s:
            pos = self._bucket(t)
            end = min(t1_s, (self._idx[pos] + 1) * self.bucket_s)
            if end <= t:  # guard against rounding at a bucket edge
                end = t1_s
            dt = end - t
            self._covered[pos] += dt
            self._tot_covered += dt
            if yy_integral is not None and valid_s > 0.0:
                f = dt / span
                self._valid[pos] += f * valid_s
                self._tot_valid += f * valid_s
                bucket, tot = self._yy[pos], self._tot_yy
                for i, v in enumerate(yy_integral):
                    bucket[i] += f * v
                    tot[i] += f * v
            t = end

    def add_correction(self, t_s: float, dx_m: Sequence[float], da_mps: Sequence[float]) -> None:
        """Record the correction applied by a step ending at ``t_s``."""
        pos = self._bucket(t_s)
        bx, ba, tx, ta = self._dx[pos], self._da[pos], self._tot_dx, self._tot_da
        for i in range(self.n):
            bx[i] += dx_m[i]
            ba[i] += da_mps[i]
            tx[i] += dx_m[i]
            ta[i] += da_mps[i]

    # -- read-out -------------------------------------------------------------------
    def covered_s(self) -> float:
        return self._tot_covered

    def excitation(self) -> float:
        """Smallest eigenvalue of the window average of ``Pi_y`` (0 with no data)."""
        covered = self._tot_covered
        if covered <= 0.0:
            return 0.0
        n = self.n
        avg = [-v / covered for v in self._tot_yy]
        for i in range(n):
            avg[i * n + i] += self._tot_valid / covered
        return max(0.0, sym_eigvals(avg, n)[0])

    def correction_rel(self, range_m: float) -> float:
        """The convergence indicator (see the module docstring)."""
        dx, da = self._tot_dx, self._tot_da
        scale = max(range_m, 1e-9)
        if self.n == 3:
            ndx = math.sqrt(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2])
            nda = math.sqrt(da[0] * da[0] + da[1] * da[1] + da[2] * da[2])
        else:
            ndx = math.sqrt(sum(v * v for v in dx))
            nda = math.sqrt(sum(v * v for v in da))
        return (ndx + self._tot_covered * nda) / scale

    def shift(self, dt_s: float) -> None:
        """Move the window's contents ``dt_s`` seconds later (rounded to whole buckets): a
        restored observer carried across a gap keeps the excitation it had seen."""
        k = round(dt_s / self.bucket_s)
        self._idx = [i + k for i in self._idx]

    # -- persistence ----------------------------------------------------------------
    def to_dict(self) -> dict[str, object]:
        return {
            "window_s": self.window_s,
            "buckets": self.buckets,
            "idx": list(self._idx),
            "covered": list(self._covered),
            "valid": list(self._valid),
            "yy": [list(a) for a in self._yy],
            "dx": [list(a) for a in self._dx],
            "da": [list(a) for a in self._da],
        }

    @classmethod
    def from_dict(cls, n: int, d: dict[str, Any]) -> ExcitationWindow:
        try:
            win = cls(n, float(d["window_s"]), int(d["buckets"]))
            win._idx = [int(i) for i in d["idx"]]
            win._covered = [float(c) for c in d["covered"]]
            win._valid = [float(c) for c in d["valid"]]
            win._yy = [_floats(a, n * n) for a in d["yy"]]
            win._dx = [_floats(a, n) for a in d["dx"]]
            win._da = [_floats(a, n) for a in d["da"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise StateError(f"monitor state is malformed: {exc}") from exc
        lengths = {len(win._idx), len(win._covered), len(win._valid), len(win._yy), len(win._dx)}
        if len(lengths | {len(win._da)}) != 1:
            raise StateError("monitor state is malformed: bucket lists differ in length")
        win._resum()
        return win


def _floats(values: object, size: int) -> list[float]:
    """A list of ``size`` finite floats (nested lists flattened), or ValueError."""
    flat: list[float] = []
    for v in values:  # type: ignore[attr-defined]
        if isinstance(v, list):
            flat.extend(float(x) for x in v)
        else:
            flat.append(float(v))
    if len(flat) != size or not all(math.isfinite(x) for x in flat):
        raise ValueError(f"expected {size} finite numbers, got {values!r}")
    return flat


@dataclass(frozen=True)
class StatusMemory:
    """What the status rules remember between estimates: the last status and since when
    (s) the observer has been continuously observable (``None``: not now)."""

    status: Status = Status.STALE
    observable_since_s: float | None = None


@dataclass(frozen=True)
class MonitorThresholds:
    """Thresholds of the status rules (see the module docstring)."""

    max_bearing_age_s: float
    max_velocity_age_s: float
    window_s: float
    window_full_s: float
    excitation_min: float
    converged_tol: float


def next_status(
    memory: StatusMemory,
    *,
    t_s: float,
    started: bool,
    bearing_age_s: float | None,
    velocity_age_s: float | None,
    excitation: float,
    covered_s: float,
    correction_rel: float,
    th: MonitorThresholds,
    settled: bool = True,
) -> StatusMemory:
    """Apply the status rules; returns the new memory, whose ``status`` is the answer
    (``settled``: the estimator's, rule 3)."""
    if (
        not started
        or bearing_age_s is None
        or velocity_age_s is None
        or bearing_age_s > th.max_bearing_age_s
        or velocity_age_s > th.max_velocity_age_s
    ):
        return StatusMemory(Status.STALE, None)
    exc_threshold = th.excitation_min * (2.0 if memory.status is Status.NOT_OBSERVABLE else 1.0)
    if covered_s >= th.window_full_s and excitation < exc_threshold:
        return StatusMemory(Status.NOT_OBSERVABLE, None)
    since = t_s if memory.observable_since_s is None else memory.observable_since_s
    tol = th.converged_tol * (2.0 if memory.status is Status.CONVERGED else 1.0)
    status = (
        Status.CONVERGED
        if settled and t_s - since >= th.window_s and correction_rel <= tol
        else Status.CONVERGING
    )
    if status is memory.status and since == memory.observable_since_s:
        return memory  # unchanged (the common case): no new object
    return StatusMemory(status, since)
