"""Reference solution of the *continuous* observer equations by fixed-step RK4 (pure).

This is deliberately independent of the product's discretisation
(:mod:`mav_observer.core.kernels.paper`): it integrates the paper's
state ``(xh1, M, zs)`` exactly as written (corrected sign), with the scenario's true,
continuous bearing ``y(t)`` and velocity ``v(t)``::

    xh1' = v - k Pi_y xh1
    M'   = I - k Pi_y M
    zs'  = M^-1 (v - M^-1 xh1) - k* Pi_{y*} zs,   y* = M^-1 y / |M^-1 y|
    xhat = M zs,  ahat = zs - M^-1 xh1

It is the yardstick the discrete observer is tested against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.scenarios import Scenario


@dataclass(frozen=True)
class ReferenceRun:
    """RK4 solution sampled at ``t_s`` (shape (T,)); ``xhat_m``, ``ahat_mps`` (T, n);
    ``cond_m`` (T,)."""

    t_s: np.ndarray
    xhat_m: np.ndarray
    ahat_mps: np.ndarray
    cond_m: np.ndarray


def _rhs(
    xh1: np.ndarray,
    m: np.ndarray,
    zs: np.ndarray,
    y: np.ndarray,
    v: np.ndarray,
    k: float,
    ks: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = y.shape[0]
    pi_y = np.eye(n) - np.outer(y, y)
    sol = np.linalg.solve(m, np.column_stack((y, xh1)))
    m_inv_y, w = sol[:, 0], sol[:, 1]
    y_star = m_inv_y / np.linalg.norm(m_inv_y)
    v_star = np.linalg.solve(m, v - w)
    d_xh1 = v - k * (pi_y @ xh1)
    d_m = np.eye(n) - k * (pi_y @ m)
    d_zs = v_star - ks * (zs - (y_star @ zs) * y_star)
    return d_xh1, d_m, d_zs


def rk4_reference(
    scenario: Scenario,
    *,
    k: float,
    k_star: float,
    t_out_s: np.ndarray,
    dt_s: float = 0.01,
    xh1_0: np.ndarray | None = None,
    m_0: np.ndarray | None = None,
    zs_0: np.ndarray | None = None,
) -> ReferenceRun:
    """Integrate from ``t_out_s[0]`` with step ``dt_s`` and report at ``t_out_s`` (each output
    time must be a whole number of steps from the first). Initial state defaults to the
    paper's: ``xh1 = 0``, ``M = I``, ``zs = 0``."""
    n = scenario.n
    xh1 = np.zeros(n) if xh1_0 is None else np.array(xh1_0, dtype=float)
    m = np.eye(n) if m_0 is None else np.array(m_0, dtype=float)
    zs = np.zeros(n) if zs_0 is None else np.array(zs_0, dtype=float)
    t0 = float(t_out_s[0])
    steps_out = np.rint((np.asarray(t_out_s) - t0) / dt_s).astype(int)
    if np.any(np.abs(steps_out * dt_s + t0 - t_out_s) > 1e-9) or np.any(np.diff(steps_out) < 0):
        raise ValueError("t_out_s must be increasing multiples of dt_s from t_out_s[0]")
    n_steps = int(steps_out[-1])
    grid = t0 + 0.5 * dt_s * np.arange(2 * n_steps + 1)
    ys = scenario.y(grid)
    vs = scenario.v(grid)
    out_x, out_a, out_c = [], [], []
    j = 0
    for i in range(n_steps + 1):
        while j < len(steps_out) and steps_out[j] == i:
            out_x.append(m @ zs)
            out_a.append(zs - np.linalg.solve(m, xh1))
            out_c.append(np.linalg.cond(m))
            j += 1
        if i == n_steps:
            break
        y0, y1, y2 = ys[2 * i], ys[2 * i + 1], ys[2 * i + 2]
        v0, v1, v2 = vs[2 * i], vs[2 * i + 1], vs[2 * i + 2]
        h = dt_s
        k1 = _rhs(xh1, m, zs, y0, v0, k, k_star)
        k2 = _rhs(
            xh1 + 0.5 * h * k1[0], m + 0.5 * h * k1[1], zs + 0.5 * h * k1[2], y1, v1, k, k_star
        )
        k3 = _rhs(
            xh1 + 0.5 * h * k2[0], m + 0.5 * h * k2[1], zs + 0.5 * h * k2[2], y1, v1, k, k_star
        )
        k4 = _rhs(xh1 + h * k3[0], m + h * k3[1], zs + h * k3[2], y2, v2, k, k_star)
        xh1 = xh1 + h / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        m = m + h / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        zs = zs + h / 6.0 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
    return ReferenceRun(
        np.asarray(t_out_s, dtype=float), np.array(out_x), np.array(out_a), np.array(out_c)
    )
