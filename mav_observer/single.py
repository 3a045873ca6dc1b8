"""The riccati bank's most common case in plain floats: one run whose bank is down to one
filter, in three dimensions (pure).

Once the hypotheses of :mod:`mav_observer.riccati` have been pruned and merged to one, a
step is four small Kalman filters (the filter, its Riccati observer and, while the bias's
random walk is learnt, two probes) on 6-vectors. numpy's per-call overhead is most of what
numpy costs there, so this module repeats :func:`~mav_observer.riccati.bank_predict` and
:func:`~mav_observer.riccati.bank_update` for that case on lists: the same arithmetic, the
same decisions, equal to rounding (``tests/test_single.py`` runs both on the same streams
and compares every estimate). :func:`from_bank` and :func:`to_bank` convert; a step that
needs more than one filter (a re-acquisition) goes back to the bank. The covariance
updates are straight-line code on the upper triangle, mirrored (loops over the entries cost
twice as much).

The state: ``x``, ``a`` (lists of 3, m and m/s), ``p`` (the 6x6 covariance of ``[x, a]``,
a flat row-major list of 36: m^2, m^2/s, m^2/s^2). No I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mav_observer import riccati

N = 3
#: tangent directions per bearing
M = N - 1


@dataclass
class Single:
    """One run of :class:`~mav_observer.riccati.Bank` with one filter, the fields of the
    bank as floats and lists (see there): the filter ``x``, ``a``, ``p``; the Riccati
    observer ``xp``, ``ap``, ``pp``; the probes ``walk_x``, ``walk_a``, ``walk_p`` (two
    each) and the run's scalars."""

    x: list[float]
    a: list[float]
    p: list[float]
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
        """A copy that shares no list with this one."""
        return Single(
            self.x[:], self.a[:], self.p[:], self.r0, self.xp[:], self.ap[:], self.pp[:],
            self.nis_avg, self.age_s, self.reseeds, self.noise_alpha, self.noise_beta,
            self.outliers, self.bearings, self.inlier_avg, self.walk_q, self.walk_on,
            self.walk_ll[:], [v[:] for v in self.walk_x], [v[:] for v in self.walk_a],
            [v[:] for v in self.walk_p],
        )  # fmt: skip

    def shift(self, dx_m: list[float]) -> None:
        """Move every position (filter, observer, probes) by ``dx_m`` (m). In place."""
        for v in (self.x, self.xp, *self.walk_x):
            for i in range(N):
                v[i] += dx_m[i]


def applies(bank: riccati.Bank) -> bool:
    """Whether ``bank`` is this module's case: one run, one filter, three dimensions."""
    return bank.runs == 1 and len(bank.owner) == 1 and bank.x.shape[-1] == N


def from_bank(bank: riccati.Bank) -> Single:
    """The bank (see :func:`applies`) as a :class:`Single`."""
    return Single(
        bank.x[0].tolist(), bank.a[0].tolist(), bank.p[0].ravel().tolist(), float(bank.r0[0]),
        bank.xp[0].tolist(), bank.ap[0].tolist(), bank.pp[0].ravel().tolist(),
        float(bank.nis_avg[0]), float(bank.age_s[0]), int(bank.reseeds[0]),
        float(bank.noise_alpha[0]), float(bank.noise_beta[0]), int(bank.outliers[0]),
        int(bank.bearings[0]), float(bank.inlier_avg[0]), float(bank.walk_q[0]),
        float(bank.walk_on[0]), bank.walk_ll[0].tolist(), bank.walk_x[0].tolist(),
        bank.walk_a[0].tolist(), bank.walk_p[0].reshape(2, -1).tolist(),
    )  # fmt: skip


def to_bank(s: Single) -> riccati.Bank:
    """The :class:`Single` as a bank of one run with one filter."""
    d = 2 * N

    def one(v: list[float] | float) -> np.ndarray:
        return np.array([v], dtype=float)

    return riccati.Bank(
        x=one(s.x), a=one(s.a), p=np.array(s.p).reshape(1, d, d), logw=np.zeros(1),
        owner=np.zeros(1, dtype=int), r0=one(s.r0), xp=one(s.xp), ap=one(s.ap),
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
    (
        p00, p01, p02, p03, p04, p05,
        _, p11, p12, p13, p14, p15,
        _, _, p22, p23, p24, p25,
        _, _, _, p33, p34, p35,
        _, _, _, _, p44, p45,
        _, _, _, _, _, p55,
    ) = p
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
    (
        p00, p01, p02, p03, p04, p05,
        _, p11, p12, p13, p14, p15,
        _, _, p22, p23, p24, p25,
        _, _, _, p33, p34, p35,
        _, _, _, _, p44, p45,
        _, _, _, _, _, p55,
    ) = p
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
    return (0.0 if lo < prm.walk_min else lo), hi


def predict(
    s: Single, dx_m: list[float], h_s: float, prm: riccati.BankParams, q_x: float | None = None
) -> None:
    """:func:`~mav_observer.riccati.bank_predict` of the :class:`Single`. In place."""
    q_x = prm.q_x if q_x is None else q_x
    probes = prm.learn_walk and s.walk_on > 0.0
    q = s.walk_q if probes else prm.q_a
    s.x, s.a, s.p = predict_one(s.x, s.a, s.p, dx_m, h_s, q_x, q)
    s.xp, s.ap, s.pp = predict_one(s.xp, s.ap, s.pp, dx_m, h_s, q_x, q)
    if probes:
        for k, qk in enumerate(walk_levels(q, prm)):
            s.walk_x[k], s.walk_a[k], s.walk_p[k] = predict_one(
                s.walk_x[k], s.walk_a[k], s.walk_p[k], dx_m, h_s, q_x, qk
            )
    s.age_s += h_s


def update(s: Single, y: list[float], h_s: float, prm: riccati.BankParams) -> bool:
    """:func:`~mav_observer.riccati.bank_update` of the :class:`Single` with the bearing
    ``y``, ``h_s`` after the previous one. In place; returns whether the run's innovations
    are inconsistent: the bank must then re-seed (:func:`~mav_observer.riccati.reseed` on
    :func:`to_bank`), with this update applied."""
    g = prm.outlier_nis
    var = s.noise_var_rad2(prm)
    x, a, p, nis, logdet, weight, stat = update_one(s.x, s.a, s.p, y, var, True, 1.0, g)
    s.x, s.a, s.p = x, a, p
    s.xp, s.ap, s.pp, *_ = update_one(s.xp, s.ap, s.pp, y, var, False, s.r0, g)
    probes = prm.learn_walk and s.walk_on > 0.0
    if probes:
        res = [
            update_one(s.walk_x[k], s.walk_a[k], s.walk_p[k], y, var, True, 1.0, g) for k in (0, 1)
        ]
        for k in (0, 1):
            s.walk_x[k], s.walk_a[k], s.walk_p[k] = res[k][:3]
    if prm.learn_walk:
        off = prm.walk_hold and not math.isfinite(prm.walk_hold_nats)
        if off or not s.age_s > prm.walk_warmup_s:
            s.walk_on = 0.0
        elif probes:
            _walk_step(s, nis, logdet, res[0][3], res[0][4], res[1][3], res[1][4], h_s, prm)
        else:  # start the probes as copies of the filter
            _start_probes(s)
            s.walk_on = 1.0
    s.nis_avg += min(riccati.NIS_MAX_WEIGHT, h_s / prm.nis_window_s) * (min(nis, g) - s.nis_avg)
    s.bearings += 1
    if weight < 0.5:
        s.outliers += 1
    if prm.learn_noise:
        inlier = weight >= 1.0
        s.inlier_avg += min(1.0, max(h_s, 0.0) / prm.nis_window_s) * (
            (1.0 if inlier else 0.0) - s.inlier_avg
        )
        if not inlier and s.inlier_avg >= riccati.INLIER_SHARE_MIN:
            stat = M * var
        stat = min(stat, riccati.NOISE_CLIP * M * var)
        rho = math.exp(-max(h_s, 0.0) / prm.noise_memory_s)
        s.noise_alpha = rho * s.noise_alpha + 0.5 * M
        s.noise_beta = rho * s.noise_beta + 0.5 * stat
    return s.nis_avg > prm.nis_gate * M and s.age_s > 2.0 * prm.nis_window_s


def _start_probes(s: Single) -> None:
    s.walk_x = [s.x[:], s.x[:]]
    s.walk_a = [s.a[:], s.a[:]]
    s.walk_p = [s.p[:], s.p[:]]
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
    """``riccati._walk_step_one`` on the :class:`Single`."""
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
    if lead_hi > bar and q < prm.walk_max:
        k = 1
    elif lead_lo > prm.walk_down_nats and q > 0.0:
        k = 0
    else:
        s.walk_ll = [lead_lo, lead_hi]
        return
    s.walk_q = walk_levels(q, prm)[k]
    s.x, s.a, s.p = s.walk_x[k], s.walk_a[k], s.walk_p[k]
    _start_probes(s)
