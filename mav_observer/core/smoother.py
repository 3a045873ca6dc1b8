"""The post-flight answer: every estimate from the whole log, by batch fits on windows (pure).

The filter's estimate at time ``t`` uses the data up to ``t``; after the flight, the data
after ``t`` count too. :func:`smooth` fits ``x(t) = x0 + a (t - t0) + D(t)`` (the model with a
constant ``a``, :func:`mav_observer.core.batch_fit.fit_batch`, Gauss-Newton on the angular residuals
with Huber weights, so gross bearing errors weigh little) over windows of ``window_s``
seconds that overlap by half, and gives every bearing time the fit of the window whose
centre is nearest among those that determine the answer. A log shorter than a window is one
fit over all of it. Windows rather than one fit: over many minutes a real log's velocity
drifts against its positions (an ``a`` that is not constant), which one fit would average
into a bias. The uncertainty of ``x(t)`` is ``J C J^T`` with ``J = [I, (t - t0) I]`` and ``C``
the fit's covariance, scaled by its residuals (the noise level need not be known well).

:class:`SampleLog` keeps the samples a replay saw (bearings per target, the vehicle's
LOCAL_POSITION_NED), split where the autopilot's clock restarts. No I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mav_observer.core.batch_fit import BatchFit, NotObservableError, displacement_at, fit_batch

#: Default window (s) of the smoother's fits.
WINDOW_S = 120.0
#: Huber threshold of the fits, in sigmas.
HUBER_K = 2.0
#: The whole log's one fit is kept when its residuals are within this share of the
#: windows' (a constant ``a`` over the whole flight fits as well as one per window).
WHOLE_TOLERANCE = 0.05
#: Fewest bearings for a window to be fitted.
MIN_BEARINGS = 20


@dataclass(frozen=True, eq=False)
class Smoothed:
    """:func:`smooth`'s result at the bearing times ``t_s`` (N,), s. ``rel_pos_ned_m``
    (N, 3): target minus vehicle position, NED, m; ``rel_pos_cov_m2`` (N, 3, 3);
    ``bias_ned_mps`` (N, 3) and ``bias_cov_m2ps2`` (N, 3, 3): the paper's ``a``;
    ``window`` (N,): index into ``fits`` of the window used (-1: none determined it, the
    row is NaN); ``fits``: ``(t_start_s, t_end_s, fit or None, why not)`` per window."""

    t_s: np.ndarray
    rel_pos_ned_m: np.ndarray
    rel_pos_cov_m2: np.ndarray
    bias_ned_mps: np.ndarray
    bias_cov_m2ps2: np.ndarray
    window: np.ndarray
    fits: list[tuple[float, float, BatchFit | None, str]]

    @property
    def rel_pos_std_ned_m(self) -> np.ndarray:
        return np.sqrt(np.diagonal(self.rel_pos_cov_m2, axis1=1, axis2=2))


def _windows(t0: float, t1: float, window_s: float) -> list[tuple[float, float]]:
    span = t1 - t0
    if span <= window_s:
        return [(t0, t1)]
    step = 0.5 * window_s
    count = math.ceil((span - window_s) / step) + 1
    starts = [t0 + i * step for i in range(count - 1)] + [t1 - window_s]
    return [(s, s + window_s) for s in starts]


def smooth(
    t_bearing_s: np.ndarray,
    bearings: np.ndarray,
    t_vel_s: np.ndarray,
    vel_ned_mps: np.ndarray,
    pos_ned_m: np.ndarray | None = None,
    *,
    sigma_rad: float,
    window_s: float = WINDOW_S,
    huber_k: float = HUBER_K,
    _split: bool = False,
) -> Smoothed:
    """Smooth one target's bearings ``(N, 3)`` (unit, NED) at the increasing
    ``t_bearing_s``, with the vehicle's measured velocity ``vel_ned_mps`` (the vehicle's
    own, ``u``; ``v = -u``) and optionally its positions at ``t_vel_s`` (used where the
    velocity is sparse, as the filter does). ``sigma_rad``: the bearing noise (the filter's
    learnt level), for the Huber threshold. See the module docstring."""
    tb = np.asarray(t_bearing_s, dtype=float)
    y = np.asarray(bearings, dtype=float)
    n = len(tb)
    if not window_s > 0.0:
        raise ValueError(f"window_s must be a number > 0, got {window_s!r}")
    x = np.full((n, 3), math.nan)
    a = np.full((n, 3), math.nan)
    cx = np.full((n, 3, 3), math.nan)
    ca = np.full((n, 3, 3), math.nan)
    best = np.full(n, math.inf)
    used = np.full(n, -1)
    fits: list[tuple[float, float, BatchFit | None, str]] = []
    if n == 0:
        return Smoothed(tb, x, cx, a, ca, used, fits)
    spans = _windows(float(tb[0]), float(tb[-1]), window_s)
    if len(spans) > 1 and not _split:
        # one fit over the whole log when it explains the bearings as well as the windows
        # do (a constant ``a`` all along: more data per unknown); windows when it does not
        whole = smooth(tb, y, t_vel_s, vel_ned_mps, pos_ned_m, sigma_rad=sigma_rad,
                       window_s=math.inf, huber_k=huber_k)  # fmt: skip
        parts = smooth(tb, y, t_vel_s, vel_ned_mps, pos_ned_m, sigma_rad=sigma_rad,
                       window_s=window_s, huber_k=huber_k, _split=True)  # fmt: skip
        r_whole, r_parts = _residual_rms(whole), _residual_rms(parts)
        if whole.fits and r_whole <= (1.0 + WHOLE_TOLERANCE) * r_parts:
            return whole
        return parts
    for w, (s, e) in enumerate(spans):
        sel = np.flatnonzero((tb >= s) & (tb <= e))
        if len(sel) < MIN_BEARINGS:
            fits.append((s, e, None, f"{len(sel)} bearings, fewer than {MIN_BEARINGS}"))
            continue
        ts = tb[sel]
        keep = np.concatenate(([True], np.diff(ts) > 0.0))  # strictly increasing
        sel, ts = sel[keep], ts[keep]
        d = displacement_at(ts, t_vel_s, vel_ned_mps, pos_ned_m)
        try:
            fit = fit_batch(
                ts, y[sel], d, sigma_rad=sigma_rad, huber_k=huber_k, covariance_from="residuals"
            )
        except NotObservableError as exc:
            fits.append((s, e, None, str(exc)))
            continue
        fits.append((s, e, fit, ""))
        dist = np.abs(ts - 0.5 * (s + e))
        better = dist < best[sel]
        idx = sel[better]
        tau = ts[better] - fit.t0_s
        xs = fit.rel_pos_at()[better]
        c = fit.covariance
        cxx, cxa, caa = c[:3, :3], c[:3, 3:], c[3:, 3:]
        x[idx] = xs
        a[idx] = fit.a_ned_mps
        cx[idx] = (
            cxx[None]
            + tau[:, None, None] * (cxa[None] + cxa.T[None])
            + (tau**2)[:, None, None] * caa[None]
        )
        ca[idx] = caa
        best[idx] = dist[better]
        used[idx] = w
    return Smoothed(tb, x, cx, a, ca, used, fits)


def _residual_rms(s: Smoothed) -> float:
    """The RMS angular residual (rad) of the fits, pooled over the windows by bearing count."""
    num = den = 0.0
    for _, _, fit, _ in s.fits:
        if fit is not None:
            k = len(fit.t_s)
            num += k * fit.residual_rms_rad**2
            den += k
    return math.sqrt(num / den) if den > 0 else math.inf


@dataclass
class _Track:
    t_s: list[float] = field(default_factory=list)
    values: list[list[float]] = field(default_factory=list)


class SampleLog:
    """The samples of a replay, for :func:`smooth`: per vehicle its LOCAL_POSITION_NED
    (time, position, velocity) and per target its bearings (time, unit NED), each split into
    epochs where the vehicle's autopilot clock restarts (:meth:`new_epoch`)."""

    def __init__(self) -> None:
        self._epoch: dict[int, int] = {}
        self._vehicle: dict[tuple[int, int], _Track] = {}
        self._bearings: dict[tuple[int, str, int], _Track] = {}

    def local_position(
        self, sysid: int, t_s: float, pos_ned_m: tuple[float, ...], vel_ned_mps: tuple[float, ...]
    ) -> None:
        tr = self._vehicle.setdefault((sysid, self._epoch.get(sysid, 0)), _Track())
        if tr.t_s and t_s <= tr.t_s[-1]:
            return  # a repeated time: keep the first
        tr.t_s.append(t_s)
        tr.values.append([*pos_ned_m, *vel_ned_mps])

    def new_epoch(self, sysid: int) -> None:
        """The vehicle's autopilot clock restarted (the tracker reset it): what follows is a
        track of its own."""
        self._epoch[sysid] = self._epoch.get(sysid, 0) + 1

    def bearing(self, sysid: int, target: str, t_s: float, y: list[float]) -> None:
        tr = self._bearings.setdefault((sysid, target, self._epoch.get(sysid, 0)), _Track())
        if tr.t_s and t_s <= tr.t_s[-1]:
            return
        tr.t_s.append(t_s)
        tr.values.append(list(y))

    def forget_bearings(self, sysid: int, target: str) -> None:
        """Drop ``target``'s bearings of the vehicle's current epoch (they were read
        wrongly: the tracker found its gimbal's angles to be body-relative)."""
        self._bearings.pop((sysid, target, self._epoch.get(sysid, 0)), None)

    def tracks(self) -> list[tuple[int, str, int]]:
        """``(sysid, target, epoch)`` of every bearing track, in order."""
        return sorted(self._bearings)

    def data(
        self, sysid: int, target: str, epoch: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``(t_bearing_s, bearings, t_vel_s, pos_ned_m, vel_ned_mps)`` of a track, or
        ``None`` without at least two velocity samples."""
        b = self._bearings.get((sysid, target, epoch))
        v = self._vehicle.get((sysid, epoch))
        if b is None or v is None or len(v.t_s) < 2:
            return None
        vals = np.array(v.values)
        return np.array(b.t_s), np.array(b.values), np.array(v.t_s), vals[:, :3], vals[:, 3:]
