"""Timestamped, noisy sample streams from a :class:`~sim.scenarios.Scenario` (pure, seeded).

:func:`generate` samples a scenario's bearing and velocity at their own rates (optionally
jittered and with dropped samples), adds the chosen noise, and returns a :class:`Stream`:
arrays of sample times and values, plus the truth at the bearing times. ``Stream.events()``
yields :class:`mav_observer.core.samples.VelocitySample` and
:class:`~mav_observer.core.samples.BearingSample` in time order (velocity first on equal times).

Noise models (all off by default, combinable):

* ``bearing_sigma_deg``: isotropic Gaussian angular noise: the bearing is rotated by a
  tangent vector with independent N(0, sigma^2) components (radians) in the plane
  orthogonal to it.
* ``position_noise_m``: the paper's model: uniform noise in [-s, s] on every component of
  ``x`` before ``y = x/|x|`` is formed.
* ``velocity_sigma_mps``: Gaussian noise on every component of ``v``.
* ``drop_prob``: each sample of either stream is dropped independently.
* ``jitter_frac``: each sample time moves by a uniform fraction of its period, keeping the
  order (irregular sampling).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from mav_observer.core.samples import BearingSample, VelocitySample
from sim.scenarios import Scenario


@dataclass(frozen=True)
class Noise:
    """Noise applied to a stream; see the module docstring."""

    bearing_sigma_deg: float = 0.0
    position_noise_m: float = 0.0
    velocity_sigma_mps: float = 0.0
    drop_prob: float = 0.0
    jitter_frac: float = 0.0

    def __post_init__(self) -> None:
        for name in ("bearing_sigma_deg", "position_noise_m", "velocity_sigma_mps"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.drop_prob < 1.0:
            raise ValueError(f"drop_prob must be in [0, 1), got {self.drop_prob}")
        if not 0.0 <= self.jitter_frac < 0.5:
            raise ValueError(f"jitter_frac must be in [0, 0.5), got {self.jitter_frac}")


PAPER_NOISE = Noise(position_noise_m=0.5)
"""The paper's noisy case: uniform +-0.5 m on each component of x before y is formed."""


def paper_noise(scale: float = 1.0) -> Noise:
    """The paper's noise model scaled: uniform +-(0.5 * scale) m on each component of x."""
    if not scale >= 0.0:
        raise ValueError(f"scale must be >= 0, got {scale}")
    return Noise(position_noise_m=0.5 * scale)


@dataclass(frozen=True)
class Stream:
    """Sampled data of one run. Shapes: times (T,), vectors (T, n)."""

    scenario: Scenario
    t_bearing_s: np.ndarray
    y: np.ndarray
    x_true_m: np.ndarray
    t_velocity_s: np.ndarray
    v_mps: np.ndarray

    def events(self) -> Iterator[VelocitySample | BearingSample]:
        """Samples in time order; a velocity sample comes before a bearing of the same time."""
        tb, tv = self.t_bearing_s, self.t_velocity_s
        i = j = 0
        while i < len(tb) or j < len(tv):
            if j < len(tv) and (i >= len(tb) or tv[j] <= tb[i]):
                yield VelocitySample(float(tv[j]), self.v_mps[j])
                j += 1
            else:
                yield BearingSample(float(tb[i]), self.y[i])
                i += 1

    def rotated(self, r: np.ndarray) -> Stream:
        """The same run seen in a frame rotated by ``r`` (an n x n rotation matrix)."""
        return Stream(
            self.scenario,
            self.t_bearing_s,
            self.y @ r.T,
            self.x_true_m @ r.T,
            self.t_velocity_s,
            self.v_mps @ r.T,
        )


def sample_times(
    rate_hz: float, duration_s: float, rng: np.random.Generator, noise: Noise, t0_s: float = 0.0
) -> np.ndarray:
    """Sample instants at ``rate_hz`` over ``[t0_s, t0_s + duration_s]`` with jitter and drops."""
    if not rate_hz > 0.0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    period = 1.0 / rate_hz
    t = t0_s + np.arange(int(np.floor(duration_s * rate_hz + 1e-9)) + 1) * period
    if noise.jitter_frac > 0.0:
        t = t + rng.uniform(-noise.jitter_frac, noise.jitter_frac, t.shape) * period
        t[0] = t0_s
    if noise.drop_prob > 0.0:
        keep = rng.random(t.shape) >= noise.drop_prob
        keep[0] = True
        t = t[keep]
    return t


def perturb_bearings(y: np.ndarray, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Rotate each unit row of ``y`` by an isotropic Gaussian tangent vector (radians)."""
    if sigma_rad == 0.0:
        return y
    eps = rng.normal(0.0, sigma_rad, y.shape)
    tangent = eps - np.sum(eps * y, axis=1, keepdims=True) * y
    theta = np.linalg.norm(tangent, axis=1, keepdims=True)
    safe = np.where(theta > 0.0, theta, 1.0)
    out = np.cos(theta) * y + np.sin(theta) * tangent / safe
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def generate(
    scenario: Scenario,
    *,
    seed: int = 0,
    bearing_rate_hz: float = 20.0,
    velocity_rate_hz: float = 20.0,
    duration_s: float | None = None,
    noise: Noise = Noise(),
    t0_s: float = 0.0,
) -> Stream:
    """Sample ``scenario`` into a :class:`Stream`; the same ``seed`` gives the same stream."""
    rng = np.random.default_rng(seed)
    dur = scenario.duration_s if duration_s is None else duration_s
    tb = sample_times(bearing_rate_hz, dur, rng, noise, t0_s)
    tv = sample_times(velocity_rate_hz, dur, rng, noise, t0_s)
    x = scenario.x(tb)
    x_meas = x
    if noise.position_noise_m > 0.0:
        x_meas = x + rng.uniform(-noise.position_noise_m, noise.position_noise_m, x.shape)
    y = x_meas / np.linalg.norm(x_meas, axis=1, keepdims=True)
    y = perturb_bearings(y, np.deg2rad(noise.bearing_sigma_deg), rng)
    v = scenario.v(tv)
    if noise.velocity_sigma_mps > 0.0:
        v = v + rng.normal(0.0, noise.velocity_sigma_mps, v.shape)
    return Stream(scenario, tb, y, x, tv, v)
