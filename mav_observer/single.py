"""The riccati bank's most common case in plain floats: one run whose bank is down to one
filter, in three dimensions (pure).

Once the hypotheses of :mod:`mav_observer.riccati` have been pruned and merged to one, a
step is four small Kalman filters (the filter, its Riccati observer and, while the bias's
random walk is learnt, two probes) on 6-vectors. numpy's per-call overhead is most of what
numpy costs there (a 6x6 product of lists is faster than the array call that does it), so
this module repeats :func:`~mav_observer.riccati.bank_predict` and
:func:`~mav_observer.riccati.bank_update` for that case on lists: the same arithmetic, the
same decisions, equal to rounding (``tests/test_single.py`` runs both on the same streams
and compares every estimate). :func:`from_bank` and :func:`to_bank` convert; a step that
needs more than one filter (a re-acquisition) goes back to the bank.

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
#: the offsets of the covariance's rows, and its upper triangle ``(i, j, 6 i + j, 6 j + i)``
_ROWS = tuple(range(0, 4 * N * N, 2 * N))
_UPPER = tuple((i, j, 6 * i + j, 6 * j + i) for i in range(2 * N) for j in range(i, 2 * N))


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
    p2 = p[:]
    for i in range(N):
        r = 6 * i
        s = 6 * (3 + i)
        for j in range(N):
            paa = p[s + 3 + j]
            pxa = p[r + 3 + j]
            pax = p[s + j]
            p2[r + j] = p[r + j] + h * (pxa + pax) + hh * paa
            p2[r + 3 + j] = pxa + h * paa
            p2[s + j] = pax + h * paa
    for i in range(N):
        p2[7 * i] += q0
        p2[7 * i + 3] += q1
        p2[7 * i + 18] += q1
        p2[7 * i + 21] += q2
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
    e = (
        (-bu0 * d1, 1.0 - bu1 * d1, -bu2 * d1),
        (-bu0 * d2, -bu1 * d2, 1.0 - bu2 * d2),
    )
    ea, eb = e
    ha0, ha1, ha2 = ea[0] / rw, ea[1] / rw, ea[2] / rw
    hb0, hb1, hb2 = eb[0] / rw, eb[1] / rw, eb[2] / rw
    if trk:
        z0 = ea[0] * y[0] + ea[1] * y[1] + ea[2] * y[2]
        z1 = eb[0] * y[0] + eb[1] * y[1] + eb[2] * y[2]
    else:
        z0 = -(ha0 * x0 + ha1 * x1 + ha2 * x2)
        z1 = -(hb0 * x0 + hb1 * x1 + hb2 * x2)
    # the columns of P H^T (6 x 2); H P H^T (2 x 2)
    pht0 = [p[r] * ha0 + p[r + 1] * ha1 + p[r + 2] * ha2 for r in _ROWS]
    pht1 = [p[r] * hb0 + p[r + 1] * hb1 + p[r + 2] * hb2 for r in _ROWS]
    h00 = ha0 * pht0[0] + ha1 * pht0[1] + ha2 * pht0[2]
    h01 = ha0 * pht1[0] + ha1 * pht1[1] + ha2 * pht1[2]
    h11 = hb0 * pht1[0] + hb1 * pht1[1] + hb2 * pht1[2]
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
    # K = P H^T S^-1 by columns; P - K (P H^T)^T, its upper triangle mirrored
    k0 = [u * i00 + v * i01 for u, v in zip(pht0, pht1, strict=True)]
    k1 = [u * i01 + v * i11 for u, v in zip(pht0, pht1, strict=True)]
    ds = [u * z0 + v * z1 for u, v in zip(k0, k1, strict=True)]
    p2 = p[:]
    for i, j, ij, ji in _UPPER:
        v = p[ij] - (k0[i] * pht0[j] + k1[i] * pht1[j])
        p2[ij] = v
        p2[ji] = v
    si0 = i00 * z0 + i01 * z1
    si1 = i01 * z0 + i11 * z1
    stat = r_eff * (M - r_eff * ((i00 + i11) - (si0 * si0 + si1 * si1)))
    return (
        [x0 + ds[0], x1 + ds[1], x2 + ds[2]],
        [a[0] + ds[3], a[1] + ds[4], a[2] + ds[5]],
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


def predict(s: Single, dx_m: list[float], h_s: float, prm: riccati.BankParams) -> None:
    """:func:`~mav_observer.riccati.bank_predict` of the :class:`Single`. In place."""
    probes = prm.learn_walk and s.walk_on > 0.0
    q = s.walk_q if probes else prm.q_a
    s.x, s.a, s.p = predict_one(s.x, s.a, s.p, dx_m, h_s, prm.q_x, q)
    s.xp, s.ap, s.pp = predict_one(s.xp, s.ap, s.pp, dx_m, h_s, prm.q_x, q)
    if probes:
        for k, qk in enumerate(walk_levels(q, prm)):
            s.walk_x[k], s.walk_a[k], s.walk_p[k] = predict_one(
                s.walk_x[k], s.walk_a[k], s.walk_p[k], dx_m, h_s, prm.q_x, qk
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
    if prm.walk_hold:
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
