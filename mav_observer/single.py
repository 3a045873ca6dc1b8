"""One run of the riccati bank in plain floats, in three dimensions (pure): the service's
case, one estimator per target.

A run is a few small Kalman filters on 6-vectors: the hypotheses (seven at the start, one
once they have been pruned and merged), the Riccati observer and, while the bias's random
walk is learnt, two probes. numpy's per-call overhead is most of what numpy costs there, so
this module repeats :func:`~mav_observer.riccati.bank_predict`,
:func:`~mav_observer.riccati.bank_update` and :func:`~mav_observer.riccati.bank_estimate`
for one run on lists: the same arithmetic, the same decisions, equal to rounding
(``tests/test_single.py`` runs both on the same streams and compares every estimate).
:func:`from_bank` and :func:`to_bank` convert; a re-seeding (a re-acquisition, rare) is done
by the bank's :func:`~mav_observer.riccati.reseed` on the converted run. The covariance
updates are straight-line code on the upper triangle, mirrored (loops over the entries cost
twice as much). The batched numpy bank stays for the Monte Carlo harness (a thousand runs at
once).

A filter: ``x``, ``a`` (lists of 3, m and m/s), ``p`` (the 6x6 covariance of ``[x, a]``, a
flat row-major list of 36: m^2, m^2/s, m^2/s^2). No I/O, no clock.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass
from typing import Any

import numpy as np

from mav_observer import riccati

N = 3
#: tangent directions per bearing
M = N - 1
#: the upper triangle of a flat 6x6, row by row (:data:`~mav_observer.riccati.UPPER_6`)
_UPPER = operator.itemgetter(*riccati.UPPER_6)


@dataclass
class Single:
    """One run of :class:`~mav_observer.riccati.Bank`, the fields of the bank as floats and
    lists (see there): the hypotheses' ``x``, ``a``, ``p``, ``logw`` (one entry per filter,
    the heaviest not necessarily first); the Riccati observer ``xp``, ``ap``, ``pp``; the
    probes ``walk_x``, ``walk_a``, ``walk_p`` (two each) and the run's scalars."""

    x: list[list[float]]
    a: list[list[float]]
    p: list[list[float]]
    logw: list[float]
    r0: float
    xp: list[float]
    ap: list[float]
    pp: list[float]
    nis_avg: float
    age_s: float
    reseeds: int
    noise_alpha: float
    noise_beta: float
    outliers: int
    bearings: int
    inlier_avg: float
    walk_q: float
    walk_on: float
    walk_ll: list[float]
    walk_x: list[list[float]]
    walk_a: list[list[float]]
    walk_p: list[list[float]]

    def noise_var_rad2(self, prm: riccati.BankParams) -> float:
        """The bearing noise variance in use (rad^2), as ``Bank.noise_var_rad2``."""
        if not prm.learn_noise:
            return prm.sigma_rad**2
        v = self.noise_beta / self.noise_alpha
        return min(max(v, prm.noise_min_rad**2), prm.noise_max_rad**2)

    def bias_walk(self, prm: riccati.BankParams) -> float:
        """The bias's random-walk intensity in use (m^2/s^3), as ``Bank.bias_walk``."""
        return self.walk_q if prm.learn_walk else prm.q_a

    def copy(self) -> Single:
        """A copy whose lists of filters are its own. The vectors and covariances inside are
        shared: nothing changes one in place (every step makes new ones)."""
        other = object.__new__(Single)
        d = other.__dict__
        d.update(self.__dict__)
        d["x"], d["a"], d["p"], d["logw"] = self.x[:], self.a[:], self.p[:], self.logw[:]
        d["walk_ll"], d["walk_x"] = self.walk_ll[:], self.walk_x[:]
        d["walk_a"], d["walk_p"] = self.walk_a[:], self.walk_p[:]
        return other

    def shift(self, dx_m: list[float]) -> None:
        """Move every position (filters, observer, probes) by ``dx_m`` (m). In place (new
        vectors: see :meth:`copy`)."""
        d0, d1, d2 = dx_m

        def moved(v: list[float]) -> list[float]:
            return [v[0] + d0, v[1] + d1, v[2] + d2]

        self.x = [moved(v) for v in self.x]
        self.xp = moved(self.xp)
        self.walk_x = [moved(v) for v in self.walk_x]

    def mean(self) -> tuple[list[float], list[float]]:
        """The run's ``(x, a)`` (new lists): the mixture's mean, as :meth:`estimate`'s."""
        if len(self.x) == 1:
            return self.x[0][:], self.a[0][:]
        _, _, mean = self._weighted()
        return mean[:N], mean[N:]

    def estimate(self) -> tuple[list[float], list[float], list[float]]:
        """The run's estimate ``(x, a, p)`` (new lists): the mixture's mean and covariance
        (spread of the hypotheses included), as :func:`~mav_observer.riccati.bank_estimate`;
        with one filter whose bias-walk probes run, its mean and the covariance over the
        walk's three levels (:meth:`walk_mixture`)."""
        if len(self.x) == 1:
            if self.walk_on > 0.0:
                return self.x[0][:], self.a[0][:], self.walk_mixture()
            return self.x[0][:], self.a[0][:], self.p[0][:]
        w, states, mean = self._weighted()
        return mean[:N], mean[N:], _spread(w, states, self.p, mean)

    def walk_mixture(self) -> list[float]:
        """The covariance of the one filter's ``[x, a]`` over the bias walk's three levels
        (flat 6x6): the filter and its two probes (:func:`_walk_step`), weighted by their
        likelihood over the walk's memory (1 and ``exp(walk_ll)``, normalised), each with
        its spread about the filter's mean (which stays the estimate), as
        :func:`~mav_observer.riccati.walk_mixture`."""
        lo, hi = self.walk_ll
        top = max(0.0, lo, hi)
        w0, w1, w2 = math.exp(-top), math.exp(lo - top), math.exp(hi - top)
        t = 1.0 / (w0 + w1 + w2)
        w0, w1, w2 = w0 * t, w1 * t, w2 * t
        x0, a0 = self.x[0], self.a[0]
        (x1, x2), (a1, a2) = self.walk_x, self.walk_a
        # the probes' offsets from the filter's [x, a], written out (6 entries each)
        d1 = [x1[0] - x0[0], x1[1] - x0[1], x1[2] - x0[2],
              a1[0] - a0[0], a1[1] - a0[1], a1[2] - a0[2]]  # fmt: skip
        d2 = [x2[0] - x0[0], x2[1] - x0[1], x2[2] - x0[2],
              a2[0] - a0[0], a2[1] - a0[1], a2[2] - a0[2]]  # fmt: skip
        e1, e2 = [w1 * c for c in d1], [w2 * c for c in d2]
        p0, p1, p2 = self.p[0], self.walk_p[0], self.walk_p[1]
        acc = [
            w0 * p0[k] + w1 * p1[k] + w2 * p2[k] + e1[i] * d1[j] + e2[i] * d2[j]
            for k, i, j in _UPPER_KIJ
        ]
        return list(_MIRROR(acc))

    def _weighted(self) -> tuple[list[float], list[list[float]], list[float]]:
        """The hypotheses' weights, their states ``[x, a]`` and the mixture's mean state."""
        w = [math.exp(v) for v in self.logw]
        states = [x + a for x, a in zip(self.x, self.a, strict=True)]
        # sum_k w_k s_k, accumulated hypothesis by hypothesis (the same sums as term by term)
        mean = [0.0] * (2 * N)
        for wi, si in zip(w, states, strict=True):
            mean = [m + wi * c for m, c in zip(mean, si, strict=True)]
        return w, states, mean


def _spread(
    w: list[float], states: list[list[float]], p: list[list[float]], mean: list[float]
) -> list[float]:
    """``sum_k w_k (P_k + d_k d_k^T)``, ``d_k = s_k - mean``: a mixture's covariance (flat,
    exactly symmetric: its upper triangle, mirrored)."""
    acc = [0.0] * 21
    for wk, sk, pk in zip(w, states, p, strict=True):
        d = [u - v for u, v in zip(sk, mean, strict=True)]
        dw = [wk * c for c in d]
        # the entry plus w P_ij plus w d_i d_j (i <= j)
        acc = [
            c + wk * q + a * b
            for c, q, a, b in zip(acc, _UPPER(pk), _ROW(dw), _COL(d), strict=True)
        ]
    return list(_MIRROR(acc))


#: the upper triangle's rows and columns (in :data:`_UPPER`'s order), and the flat 6x6 from it
#: (:data:`~mav_observer.riccati.UPPER_IJ_6`, :data:`~mav_observer.riccati.MIRROR_6`)
_ROW = operator.itemgetter(*(i for i, _ in riccati.UPPER_IJ_6))
_COL = operator.itemgetter(*(j for _, j in riccati.UPPER_IJ_6))
#: the upper triangle's flat 6x6 indices with their rows and columns
_UPPER_KIJ = tuple((k, i, j) for k, (i, j) in zip(riccati.UPPER_6, riccati.UPPER_IJ_6, strict=True))
_MIRROR = operator.itemgetter(*riccati.MIRROR_6)


def applies(bank: riccati.Bank) -> bool:
    """Whether ``bank`` is this module's case: one run in three dimensions."""
    return bank.runs == 1 and bank.x.shape[-1] == N


def from_bank(bank: riccati.Bank) -> Single:
    """The bank (see :func:`applies`) as a :class:`Single`."""
    return Single(
        bank.x.tolist(), bank.a.tolist(), bank.p.reshape(len(bank.owner), -1).tolist(),
        bank.logw.tolist(), float(bank.r0[0]),
        bank.xp[0].tolist(), bank.ap[0].tolist(), bank.pp[0].ravel().tolist(),
        float(bank.nis_avg[0]), float(bank.age_s[0]), int(bank.reseeds[0]),
        float(bank.noise_alpha[0]), float(bank.noise_beta[0]), int(bank.outliers[0]),
        int(bank.bearings[0]), float(bank.inlier_avg[0]), float(bank.walk_q[0]),
        float(bank.walk_on[0]), bank.walk_ll[0].tolist(), bank.walk_x[0].tolist(),
        bank.walk_a[0].tolist(), bank.walk_p[0].reshape(2, -1).tolist(),
    )  # fmt: skip


def to_bank(s: Single) -> riccati.Bank:
    """The :class:`Single` as a bank of one run."""
    d = 2 * N
    f = len(s.x)

    def one(v: Any) -> np.ndarray:
        return np.array([v], dtype=float)

    return riccati.Bank(
        x=np.array(s.x, dtype=float).reshape(f, N), a=np.array(s.a, dtype=float).reshape(f, N),
        p=np.array(s.p, dtype=float).reshape(f, d, d), logw=np.array(s.logw, dtype=float),
        owner=np.zeros(f, dtype=int), r0=one(s.r0), xp=one(s.xp), ap=one(s.ap),
        pp=np.array(s.pp).reshape(1, d, d), nis_avg=one(s.nis_avg), age_s=one(s.age_s),
        reseeds=np.array([s.reseeds]), noise_alpha=one(s.noise_alpha),
        noise_beta=one(s.noise_beta), outliers=np.array([s.outliers]),
        bearings=np.array([s.bearings]), inlier_avg=one(s.inlier_avg), walk_q=one(s.walk_q),
        walk_on=one(s.walk_on), walk_ll=one(s.walk_ll), walk_x=one(s.walk_x),
        walk_a=one(s.walk_a), walk_p=np.array(s.walk_p).reshape(1, 2, d, d),
    )  # fmt: skip


def predict_one(
    x: list[float],
    a: list[float],
    p: list[float],
    dx_m: list[float],
    h_s: float,
    q_x: float,
    q_a: float,
) -> tuple[list[float], list[float], list[float]]:
    """:func:`~mav_observer.riccati.predict` of one filter: ``x + dx_m + h a``, ``a``, and
    ``F P F^T + Q`` (new lists)."""
    h = h_s
    hh = h * h
    x2 = [x[0] + dx_m[0] + h * a[0], x[1] + dx_m[1] + h * a[1], x[2] + dx_m[2] + h * a[2]]
    q0 = q_x * h + q_a * h * hh / 3.0
    q1 = q_a * hh / 2.0
    q2 = q_a * h
    # fmt: off
    (p00, p01, p02, p03, p04, p05, p11,
     p12, p13, p14, p15, p22, p23, p24,
     p25, p33, p34, p35, p44, p45, p55) = _UPPER(p)
    # fmt: on
    m00 = p00 + h * (p03 + p03) + hh * p33 + q0
    m01 = p01 + h * (p04 + p13) + hh * p34
    m02 = p02 + h * (p05 + p23) + hh * p35
    m03 = p03 + h * p33 + q1
    m04 = p04 + h * p34
    m05 = p05 + h * p35
    m11 = p11 + h * (p14 + p14) + hh * p44 + q0
    m12 = p12 + h * (p15 + p24) + hh * p45
    m13 = p13 + h * p34
    m14 = p14 + h * p44 + q1
    m15 = p15 + h * p45
    m22 = p22 + h * (p25 + p25) + hh * p55 + q0
    m23 = p23 + h * p35
    m24 = p24 + h * p45
    m25 = p25 + h * p55 + q1
    m33 = p33 + q2
    m34 = p34
    m35 = p35
    m44 = p44 + q2
    m45 = p45
    m55 = p55 + q2
    # fmt: off
    p2 = [
        m00, m01, m02, m03, m04, m05,
        m01, m11, m12, m13, m14, m15,
        m02, m12, m22, m23, m24, m25,
        m03, m13, m23, m33, m34, m35,
        m04, m14, m24, m34, m44, m45,
        m05, m15, m25, m35, m45, m55,
    ]
    # fmt: on
    return x2, a[:], p2


def update_one(
    x: list[float],
    a: list[float],
    p: list[float],
    y: list[float],
    sig2_rad2: float,
    tracking: bool,
    r_w_m: float,
    outlier_nis: float,
) -> tuple[list[float], list[float], list[float], float, float, float, float]:
    """:func:`~mav_observer.riccati.update_robust` of one filter (``r_min = r_max = r_w_m``
    for the acquisition form): ``(x, a, p, nis, log det S, weight, noise_stat)``."""
    x0, x1, x2 = x
    r = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    trk = tracking and r > 1e-9
    if trk:
        d0, d1, d2 = x0 / r, x1 / r, x2 / r
        rw = r
    else:
        d0, d1, d2 = y
        rw = r_w_m
    # the tangent basis (riccati.tangent_basis): columns 1, 2 of I - beta u u^T
    u0 = d0 + (1.0 if d0 >= 0.0 else -1.0)
    beta = 2.0 / (u0 * u0 + d1 * d1 + d2 * d2)
    bu0, bu1, bu2 = beta * u0, beta * d1, beta * d2
    ea = (-bu0 * d1, 1.0 - bu1 * d1, -bu2 * d1)
    eb = (-bu0 * d2, -bu1 * d2, 1.0 - bu2 * d2)
    ha0, ha1, ha2 = ea[0] / rw, ea[1] / rw, ea[2] / rw
    hb0, hb1, hb2 = eb[0] / rw, eb[1] / rw, eb[2] / rw
    if trk:
        z0 = ea[0] * y[0] + ea[1] * y[1] + ea[2] * y[2]
        z1 = eb[0] * y[0] + eb[1] * y[1] + eb[2] * y[2]
    else:
        z0 = -(ha0 * x0 + ha1 * x1 + ha2 * x2)
        z1 = -(hb0 * x0 + hb1 * x1 + hb2 * x2)
    # the columns q, w of P H^T (6 x 2; the upper triangle of P read), H P H^T (2 x 2)
    # fmt: off
    (p00, p01, p02, p03, p04, p05, p11,
     p12, p13, p14, p15, p22, p23, p24,
     p25, p33, p34, p35, p44, p45, p55) = _UPPER(p)
    # fmt: on
    q0 = p00 * ha0 + p01 * ha1 + p02 * ha2
    q1 = p01 * ha0 + p11 * ha1 + p12 * ha2
    q2 = p02 * ha0 + p12 * ha1 + p22 * ha2
    q3 = p03 * ha0 + p13 * ha1 + p23 * ha2
    q4 = p04 * ha0 + p14 * ha1 + p24 * ha2
    q5 = p05 * ha0 + p15 * ha1 + p25 * ha2
    w0 = p00 * hb0 + p01 * hb1 + p02 * hb2
    w1 = p01 * hb0 + p11 * hb1 + p12 * hb2
    w2 = p02 * hb0 + p12 * hb1 + p22 * hb2
    w3 = p03 * hb0 + p13 * hb1 + p23 * hb2
    w4 = p04 * hb0 + p14 * hb1 + p24 * hb2
    w5 = p05 * hb0 + p15 * hb1 + p25 * hb2
    h00 = ha0 * q0 + ha1 * q1 + ha2 * q2
    h01 = ha0 * w0 + ha1 * w1 + ha2 * w2
    h11 = hb0 * w0 + hb1 * w1 + hb2 * w2
    s00, s11 = h00 + sig2_rad2, h11 + sig2_rad2
    det = s00 * s11 - h01 * h01
    logdet = math.log(det)
    i00, i11, i01 = s11 / det, s00 / det, -h01 / det
    nis = z0 * (i00 * z0 + i01 * z1) + z1 * (i01 * z0 + i11 * z1)
    weight = 1.0
    r_eff = sig2_rad2
    if nis > outlier_nis:
        weight = (outlier_nis / nis) ** 2
        r_eff = sig2_rad2 / weight
        s00, s11 = h00 + r_eff, h11 + r_eff
        det = s00 * s11 - h01 * h01
        i00, i11, i01 = s11 / det, s00 / det, -h01 / det
    # K = P H^T S^-1 by columns (k, l); P - K (P H^T)^T, its upper triangle mirrored
    k0 = q0 * i00 + w0 * i01
    l0 = q0 * i01 + w0 * i11
    k1 = q1 * i00 + w1 * i01
    l1 = q1 * i01 + w1 * i11
    k2 = q2 * i00 + w2 * i01
    l2 = q2 * i01 + w2 * i11
    k3 = q3 * i00 + w3 * i01
    l3 = q3 * i01 + w3 * i11
    k4 = q4 * i00 + w4 * i01
    l4 = q4 * i01 + w4 * i11
    k5 = q5 * i00 + w5 * i01
    l5 = q5 * i01 + w5 * i11
    n00 = p00 - (k0 * q0 + l0 * w0)
    n01 = p01 - (k0 * q1 + l0 * w1)
    n02 = p02 - (k0 * q2 + l0 * w2)
    n03 = p03 - (k0 * q3 + l0 * w3)
    n04 = p04 - (k0 * q4 + l0 * w4)
    n05 = p05 - (k0 * q5 + l0 * w5)
    n11 = p11 - (k1 * q1 + l1 * w1)
    n12 = p12 - (k1 * q2 + l1 * w2)
    n13 = p13 - (k1 * q3 + l1 * w3)
    n14 = p14 - (k1 * q4 + l1 * w4)
    n15 = p15 - (k1 * q5 + l1 * w5)
    n22 = p22 - (k2 * q2 + l2 * w2)
    n23 = p23 - (k2 * q3 + l2 * w3)
    n24 = p24 - (k2 * q4 + l2 * w4)
    n25 = p25 - (k2 * q5 + l2 * w5)
    n33 = p33 - (k3 * q3 + l3 * w3)
    n34 = p34 - (k3 * q4 + l3 * w4)
    n35 = p35 - (k3 * q5 + l3 * w5)
    n44 = p44 - (k4 * q4 + l4 * w4)
    n45 = p45 - (k4 * q5 + l4 * w5)
    n55 = p55 - (k5 * q5 + l5 * w5)
    # fmt: off
    p2 = [
        n00, n01, n02, n03, n04, n05,
        n01, n11, n12, n13, n14, n15,
        n02, n12, n22, n23, n24, n25,
        n03, n13, n23, n33, n34, n35,
        n04, n14, n24, n34, n44, n45,
        n05, n15, n25, n35, n45, n55,
    ]
    # fmt: on
    si0 = i00 * z0 + i01 * z1
    si1 = i01 * z0 + i11 * z1
    stat = r_eff * (M - r_eff * ((i00 + i11) - (si0 * si0 + si1 * si1)))
    return (
        [x0 + k0 * z0 + l0 * z1, x1 + k1 * z0 + l1 * z1, x2 + k2 * z0 + l2 * z1],
        [a[0] + k3 * z0 + l3 * z1, a[1] + k4 * z0 + l4 * z1, a[2] + k5 * z0 + l5 * z1],
        p2,
        nis,
        logdet,
        weight,
        weight * stat,
    )


def walk_levels(q: float, prm: riccati.BankParams) -> tuple[float, float]:
    """The probes' ``q_a`` around ``q`` (m^2/s^3), as ``riccati._walk_levels``."""
    lo = q / prm.walk_factor
    hi = min(max(q * prm.walk_factor, prm.walk_min), prm.walk_max)
    if q <= 0.0:
        return prm.walk_jump, hi
    return (0.0 if lo < prm.walk_min else lo), hi


def predict(s: Single, dx_m: list[float], h_s: float, prm: riccati.BankParams, q_x: float) -> None:
    """:func:`~mav_observer.riccati.bank_predict` of the :class:`Single` with the process
    noise ``q_x`` (m^2/s) on ``x`` (the estimator's, not ``prm.q_x``: it follows the learnt
    velocity noise). In place."""
    probes = prm.learn_walk and s.walk_on > 0.0
    q = s.walk_q if probes else prm.q_a
    xs, as_, ps = s.x, s.a, s.p
    for i in range(len(xs)):
        xs[i], as_[i], ps[i] = predict_one(xs[i], as_[i], ps[i], dx_m, h_s, q_x, q)
    s.xp, s.ap, s.pp = predict_one(s.xp, s.ap, s.pp, dx_m, h_s, q_x, q)
    if probes:
        lo, hi = walk_levels(q, prm)
        wx, wa, wp = s.walk_x, s.walk_a, s.walk_p
        wx[0], wa[0], wp[0] = predict_one(wx[0], wa[0], wp[0], dx_m, h_s, q_x, lo)
        wx[1], wa[1], wp[1] = predict_one(wx[1], wa[1], wp[1], dx_m, h_s, q_x, hi)
    s.age_s += h_s


def _logsumexp(values: list[float]) -> float:
    top = max(values)
    return top + math.log(sum(math.exp(v - top) for v in values))


def update(s: Single, y: list[float], h_s: float, prm: riccati.BankParams) -> bool:
    """:func:`~mav_observer.riccati.bank_update` of the :class:`Single` with the bearing
    ``y``, ``h_s`` after the previous one. In place; returns whether the run's innovations
    are inconsistent: the bank must then re-seed (:func:`~mav_observer.riccati.reseed` on
    :func:`to_bank`), with this update applied."""
    g = prm.outlier_nis
    var = s.noise_var_rad2(prm)
    xs, as_, ps = s.x, s.a, s.p
    f = len(xs)
    if f == 1:
        r = update_one(xs[0], as_[0], ps[0], y, var, True, 1.0, g)
        xs[0], as_[0], ps[0] = r[0], r[1], r[2]
        res = [r]
    else:
        res = [update_one(xs[i], as_[i], ps[i], y, var, True, 1.0, g) for i in range(f)]
        for i, r in enumerate(res):
            xs[i], as_[i], ps[i] = r[0], r[1], r[2]
    s.xp, s.ap, s.pp, _, _, w_obs, _ = update_one(s.xp, s.ap, s.pp, y, var, False, s.r0, g)
    probes = prm.learn_walk and s.walk_on > 0.0
    robust = w_obs < 1.0
    if probes:
        wx, wa, wp = s.walk_x, s.walk_a, s.walk_p
        r_lo = update_one(wx[0], wa[0], wp[0], y, var, True, 1.0, g)
        r_hi = update_one(wx[1], wa[1], wp[1], y, var, True, 1.0, g)
        wx[0], wa[0], wp[0] = r_lo[0], r_lo[1], r_lo[2]
        wx[1], wa[1], wp[1] = r_hi[0], r_hi[1], r_hi[2]
        rp = (r_lo, r_hi)
        robust = robust or r_lo[5] < 1.0 or r_hi[5] < 1.0
    if prm.learn_walk:
        off = prm.walk_hold and not math.isfinite(prm.walk_hold_nats)
        if off or f != 1 or not s.age_s > prm.walk_warmup_s:
            s.walk_on = 0.0
        elif probes:
            nis0, logdet0 = res[0][3], res[0][4]
            _walk_step(s, nis0, logdet0, rp[0][3], rp[0][4], rp[1][3], rp[1][4], h_s, prm)
        else:  # start the probes as copies of the filter
            _start_probes(s)
            s.walk_on = 1.0
    if f == 1:  # the converged run: its one filter weighs 1
        nis, weight, stat = res[0][3], res[0][5], res[0][6]
        mix_nis = min(nis, g)
        w_run = weight
        inlier_share = 1.0 if weight >= 1.0 else 0.0
    else:
        w_prior = [math.exp(v) for v in s.logw]
        robust = robust or any(r[5] < 1.0 for r in res)
        if robust:
            floor = g + M * math.log(var)
            loss = [min(r[3] + r[4], floor) for r in res]
        else:
            loss = [r[3] + r[4] for r in res]
        logw = [s.logw[i] - 0.5 * loss[i] for i in range(f)]
        top = _logsumexp(logw)
        s.logw = [v - top for v in logw]
        mix_nis = sum(w * min(r[3], g) for w, r in zip(w_prior, res, strict=True))
        w_run = sum(w * r[5] for w, r in zip(w_prior, res, strict=True))
        inlier_share = sum(w for w, r in zip(w_prior, res, strict=True) if r[5] >= 1.0)
    s.nis_avg += min(riccati.NIS_MAX_WEIGHT, h_s / prm.nis_window_s) * (mix_nis - s.nis_avg)
    s.bearings += 1
    if w_run < 0.5:
        s.outliers += 1
    if prm.learn_noise:
        s.inlier_avg += min(1.0, max(h_s, 0.0) / prm.nis_window_s) * (inlier_share - s.inlier_avg)
        all_in = s.inlier_avg >= riccati.INLIER_SHARE_MIN
        if f == 1:
            if weight < 1.0 and all_in:
                stat = M * var
        else:
            stat = sum(
                w * (r[6] if r[5] >= 1.0 or not all_in else M * var)
                for w, r in zip(w_prior, res, strict=True)
            )
        stat = min(stat, riccati.NOISE_CLIP * M * var)
        rho = math.exp(-max(h_s, 0.0) / prm.noise_memory_s)
        s.noise_alpha = rho * s.noise_alpha + 0.5 * M
        s.noise_beta = rho * s.noise_beta + 0.5 * stat
    if f > 1:
        early = s.age_s < prm.prune_early_s and s.reseeds == 0
        floor = prm.prune_early if early else prm.prune
        keep = [i for i in range(f) if math.exp(s.logw[i]) >= floor]
        if len(keep) < f:
            _select(s, keep)
        if len(s.x) > 1:
            _merge(s, prm)
    return s.nis_avg > prm.nis_gate * M and s.age_s > 2.0 * prm.nis_window_s


def _select(s: Single, keep: list[int]) -> None:
    s.x = [s.x[i] for i in keep]
    s.a = [s.a[i] for i in keep]
    s.p = [s.p[i] for i in keep]
    logw = [s.logw[i] for i in keep]
    top = _logsumexp(logw)
    s.logw = [v - top for v in logw]


def _merge(s: Single, prm: riccati.BankParams) -> None:
    """``riccati._merge`` on the :class:`Single`: every hypothesis within
    ``prm.merge_maha`` (squared Mahalanobis distance under the sum of the two covariances)
    of the heaviest merged into it, moments matched."""
    f = len(s.x)
    w = [math.exp(v) for v in s.logw]
    k = max(range(f), key=lambda i: (w[i], -i))  # the heaviest, the first of equals
    others = [i for i in range(f) if i != k]
    dist = _distances(s, k, others, prm.merge_maha)
    if dist is None:  # the distances in one numpy call, as the bank computes them
        st = np.array([x + a for x, a in zip(s.x, s.a, strict=True)])
        pp = np.array(s.p).reshape(f, 2 * N, 2 * N)
        d = st[others] - st[k]
        m = np.einsum("ij,ij->i", d, np.linalg.solve(pp[others] + pp[k], d[..., None])[..., 0])
        dist = m.tolist()
    close = [i for i, mi in zip(others, dist, strict=True) if mi < prm.merge_maha]
    if not close:
        return
    group = [k, *close]
    total = sum(w[i] for i in group)
    states = [s.x[i] + s.a[i] for i in group]
    wg = [w[i] for i in group]
    mean = [
        sum(wi * si[j] for wi, si in zip(wg, states, strict=True)) / total for j in range(2 * N)
    ]
    p = _spread(wg, states, [s.p[i] for i in group], mean)
    s.x[k], s.a[k], s.p[k] = mean[:N], mean[N:], [v / total for v in p]
    s.logw[k] = math.log(total)
    _select(s, [i for i in range(f) if i not in close])


def _distances(s: Single, k: int, others: list[int], bar: float) -> list[float] | None:
    """The squared Mahalanobis distances of the hypotheses ``others`` from hypothesis ``k``
    under the sum of the two covariances (one 6x6 Cholesky factorisation per pair: 10 us,
    numpy's batched solve costs more up to the bank's seven), or ``None`` if a sum is not
    numerically positive definite (numpy's solve then decides, as the bank's). A pair whose
    distance is surely at least ``bar`` is given a lower bound over ``bar`` instead (only
    whether a distance is under ``bar`` is used): ``|d|^2 / trace``, else the factorisation's
    partial sum once it passes ``bar`` (``d^T A^-1 d >= d_x^T A_xx^-1 d_x``, the position
    block first); in the acquisition the hypotheses are far apart in range and most pairs
    end early."""
    sk = s.x[k] + s.a[k]
    pk = s.p[k]
    out = []
    for i in others:
        d = [u - v for u, v in zip(s.x[i] + s.a[i], sk, strict=True)]
        pi = s.p[i]
        trace = sum(pi[j] + pk[j] for j in _DIAG)
        d2 = sum(c * c for c in d)
        if trace > 0.0 and d2 > bar * trace * (1.0 + 1e-9):
            out.append(d2 / trace)
            continue
        m = mahalanobis2(d, [u + v for u, v in zip(pi, pk, strict=True)], over=bar)
        if m is None:
            return None
        out.append(m)
    return out


#: the diagonal of a flat 6x6
_DIAG = tuple(7 * j for j in range(2 * N))


def mahalanobis2(
    d: list[float], a: list[float], n: int = 2 * N, over: float = math.inf
) -> float | None:
    """``d^T a^-1 d`` for a symmetric positive definite ``n x n`` ``a`` (flat, row-major) by
    its Cholesky factor (``a = L L^T``, ``z = L^-1 d``, the answer ``|z|^2``, accumulated
    column by column); ``None`` if ``a`` is not positive definite to working precision. With
    ``over``: once the partial sum passes ``over`` it is returned (a lower bound of the
    answer: the first columns' sum is the leading block's own distance)."""
    low = [0.0] * (n * n)
    z = [0.0] * n
    bar = over * (1.0 + 1e-9)
    acc = 0.0
    for j in range(n):
        rj = n * j
        t = a[rj + j]
        for k in range(j):
            t -= low[rj + k] * low[rj + k]
        if not t > 0.0:
            return None
        ljj = math.sqrt(t)
        low[rj + j] = ljj
        for i in range(j + 1, n):
            ri = n * i
            t = a[ri + j]
            for k in range(j):
                t -= low[ri + k] * low[rj + k]
            low[ri + j] = t / ljj
        t = d[j]
        for k in range(j):
            t -= low[rj + k] * z[k]
        z[j] = t / ljj
        acc += z[j] * z[j]
        if acc > bar:
            return acc
    return sum(c * c for c in z)


def _start_probes(s: Single) -> None:
    """The probes start as the filter (its vectors shared: no step changes one in place)."""
    s.walk_x = [s.x[0], s.x[0]]
    s.walk_a = [s.a[0], s.a[0]]
    s.walk_p = [s.p[0], s.p[0]]
    s.walk_ll = [0.0, 0.0]


def _walk_step(
    s: Single,
    nis: float,
    logdet: float,
    nis_lo: float,
    logdet_lo: float,
    nis_hi: float,
    logdet_hi: float,
    h_s: float,
    prm: riccati.BankParams,
) -> None:
    """``riccati._walk_step`` for one run with one filter, on the :class:`Single`."""
    g = prm.outlier_nis
    if nis > g or nis_lo > g or nis_hi > g:  # a gross error: neutral
        diff_lo = diff_hi = 0.0
    else:
        ll0 = -0.5 * (nis + logdet)
        diff_lo = -0.5 * (nis_lo + logdet_lo) - ll0
        diff_hi = -0.5 * (nis_hi + logdet_hi) - ll0
    rho = math.exp(-max(h_s, 0.0) / prm.walk_memory_s)
    lead_lo = rho * s.walk_ll[0] + diff_lo
    lead_hi = rho * s.walk_ll[1] + diff_hi
    q = s.walk_q
    bar = prm.walk_up_nats if q > 0.0 else prm.walk_leave_nats
    if prm.walk_hold and q == 0.0:  # leaving 0 is held
        bar = max(bar, prm.walk_hold_nats)
    if q > 0.0:
        lo_bar = prm.walk_down_nats
    else:  # at 0 the lower probe is the jump
        lo_bar = prm.walk_leave_nats if prm.walk_jump > 0.0 and not prm.walk_hold else math.inf
    if lead_hi > bar and q < prm.walk_max and not (q <= 0.0 and lead_lo > max(lo_bar, lead_hi)):
        k = 1
    elif lead_lo > lo_bar:
        k = 0
    else:
        s.walk_ll = [lead_lo, lead_hi]
        return
    s.walk_q = walk_levels(q, prm)[k]
    s.x[0], s.a[0], s.p[0] = s.walk_x[k], s.walk_a[k], s.walk_p[k]
    _start_probes(s)
