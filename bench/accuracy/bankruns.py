"""The product's filter bank over many runs at once, for the Monte Carlo harness.

The kernels are the product's own (:mod:`mav_observer.core.kernels.bank`), called run by
run in a loop compiled with numba (``prange``: the runs shared out over the cores), so the
maths the harness measures is the maths the product runs. Arrays carry a leading runs axis
``R``: the filters ``fs`` (R, H + 3, 2n) and ``fp`` (R, H + 3, 2n, 2n), the log weights
``logw`` (R, H), the runs' scalars ``bs`` (R, layout.B_COUNT) and scratch ``wk`` (R, k); the
settings ``bp`` (:meth:`~mav_observer.core.config.BankParams.to_array`) are shared.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from mav_observer.core.compiled import clear_stale_cache
from mav_observer.core.config import BankParams
from mav_observer.core.kernels import bank, kalman
from mav_observer.core.kernels.layout import B_COUNT
from mav_observer.core.state import bank_scratch_size

clear_stale_cache(__file__)


class BankRuns:
    """``R`` runs of the bank: :meth:`start` at the first bearings, :meth:`step` per
    sample (prediction over ``h`` with the velocity's integral ``dx``, then the bearing),
    :meth:`estimate`."""

    def __init__(self, prm: BankParams, runs: int, n: int) -> None:
        self.bp = prm.to_array()
        h = prm.hypotheses
        self.fs = np.zeros((runs, h + 3, 2 * n))
        self.fp = np.zeros((runs, h + 3, 2 * n, 2 * n))
        self.logw = np.zeros((runs, h))
        self.bs = np.zeros((runs, B_COUNT))
        self.wk = np.zeros((runs, bank_scratch_size(n, h) + 8 * n * n + 8 * n))
        self.q_x = prm.q_x

    def start(self, y0: np.ndarray, r0: np.ndarray) -> None:
        _start(self.fs, self.fp, self.logw, self.bs, self.bp, np.ascontiguousarray(y0),
               np.ascontiguousarray(r0, dtype=float))  # fmt: skip

    def step(self, dx: np.ndarray, h_s: float, y: np.ndarray) -> None:
        _step(self.fs, self.fp, self.logw, self.bs, self.bp, self.wk,
              np.ascontiguousarray(dx), float(h_s), np.ascontiguousarray(y), self.q_x)  # fmt: skip

    def estimate(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        runs, _, d2 = self.fs.shape
        st = np.empty((runs, d2))
        p = np.empty((runs, d2, d2))
        _estimate(self.fs, self.fp, self.logw, self.bs, self.bp, self.wk, st, p)
        n = d2 // 2
        return st[:, :n], st[:, n:], p


@njit(cache=True, parallel=True)
def _start(fs, fp, logw, bs, bp, y0, r0):  # pragma: no cover - compiled
    for r in prange(fs.shape[0]):
        bank.start(fs[r], fp[r], logw[r], bs[r], bp, y0[r], r0[r])


@njit(cache=True, parallel=True)
def _step(fs, fp, logw, bs, bp, wk, dx, h, y, q_x):  # pragma: no cover - compiled
    for r in prange(fs.shape[0]):
        bank.predict(fs[r], fp[r], bs[r], bp, dx[r], h, q_x)
        bank.update(fs[r], fp[r], logw[r], bs[r], bp, y[r], h, False, 60.0, 0.0, wk[r])


@njit(cache=True, parallel=True)
def _estimate(fs, fp, logw, bs, bp, wk, st, p):  # pragma: no cover - compiled
    for r in prange(fs.shape[0]):
        bank.estimate(fs[r], fp[r], logw[r], bs[r], bp, st[r], p[r], wk[r])


class FilterRuns:
    """One Kalman filter per run on ``[x, a]`` with the bank's own filter kernels: the
    tracking form (``r_w`` 0, an EKF) or the Riccati observer's with the weight range
    ``r_w`` (R,) (a pseudo-linear KF). ``p0`` (R, 2n, 2n) the prior."""

    def __init__(self, x0: np.ndarray, p0: np.ndarray, r_w: np.ndarray, sigma_rad: float,
                 q_x: float) -> None:  # fmt: skip
        runs, n = x0.shape
        self.s = np.zeros((runs, 2 * n))
        self.s[:, :n] = x0
        self.p = np.array(p0, dtype=float)
        self.r_w = np.ascontiguousarray(r_w, dtype=float)
        self.sig2 = max(sigma_rad, 0.0) ** 2
        self.q_x = q_x
        self.wk = np.zeros((runs, bank_scratch_size(n, 1)))

    def update(self, y: np.ndarray) -> None:
        _filter_update(self.s, self.p, np.ascontiguousarray(y), self.sig2, self.r_w, self.wk)

    def predict(self, dx: np.ndarray, h_s: float) -> None:
        _filter_predict(self.s, self.p, np.ascontiguousarray(dx), float(h_s), self.q_x)


@njit(cache=True, parallel=True)
def _filter_update(s, p, y, sig2, r_w, wk):  # pragma: no cover - compiled
    for r in prange(s.shape[0]):
        res = np.empty(4)
        kalman.update_filter(s[r], p[r], y[r], sig2, r_w[r], math.inf, wk[r], res)


@njit(cache=True, parallel=True)
def _filter_predict(s, p, dx, h, q_x):  # pragma: no cover - compiled
    for r in prange(s.shape[0]):
        kalman.predict_filter(s[r], p[r], dx[r], h, q_x, 0.0)


def initial_covariance(y0: np.ndarray, range0: np.ndarray, range_std: np.ndarray,
                       bias_std: float, sigma_rad: float) -> np.ndarray:  # fmt: skip
    """The bank's prior of ``x = range0 y0``, ``a = 0`` for each run (R, 2n, 2n)."""
    runs, n = y0.shape
    out = np.zeros((runs, 2 * n, 2 * n))
    _initial_covariance(np.ascontiguousarray(y0), np.ascontiguousarray(range0, dtype=float),
                        np.ascontiguousarray(range_std, dtype=float), bias_std, sigma_rad,
                        out)  # fmt: skip
    return out


@njit(cache=True)
def _initial_covariance(y0, range0, range_std, bias_std, sigma, out):  # pragma: no cover
    for r in range(y0.shape[0]):
        kalman.initial_covariance(y0[r], range0[r], range_std[r], bias_std, sigma, out[r])
