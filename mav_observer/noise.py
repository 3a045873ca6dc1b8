"""The white noise of the measured velocity, learnt from the velocity samples (pure).

The riccati estimator turns the velocity's white noise into a random walk of ``x``
(``q_x = sigma_v^2 dt``, :func:`mav_observer.riccati.predict`). Told too much, it forgets
too fast (2x to 2.5x the Cramer-Rao bound on exact velocity with the old 0.05 m/s default);
told too little, it is over-confident. The samples themselves say how much there is: the
third divided difference of four consecutive samples, ``f = sum_i v_i c_i`` with
``c_i = 1 / prod_{j != i} (t_i - t_j)``, is zero for any motion whose velocity is a
quadratic in time, and for white noise of ``sigma`` per axis its variance is
``sigma^2 sum_i c_i^2``. What is left of the motion is of the order of the snap times
``h^3``, negligible at the rates where the noise matters (a figure-8 at 10 Hz leaves
0.0002 m/s; a hard manoeuvre makes it a conservative over-estimate). Only dense streams
(intervals up to :data:`MAX_INTERVAL_S`, the longest at most 4 times the shortest) are
used: between samples seconds apart the motion dominates, and the prior stays.

The estimate is an exponentially forgetting mean of the per-sample variances (time constant
``memory_s``), each clipped to :data:`CLIP` times the current estimate (a glitch in the
stream moves it little), started from the prior weighing ``prior_samples`` samples; the
prior's weight decays ten times faster than the samples' (``memory_s / 10``) and is gone
after a minute, so exact velocity is learnt as exact (an estimate of the noise whose prior
lingered would cost its random walk: 0.001 m/s at 10 Hz is 1.35x the bound). No I/O, no clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

#: The order of the differences: 3 (four samples) removes any quadratic motion.
ORDER = 3
#: Longest interval (s) between velocity samples whose second differences are used.
MAX_INTERVAL_S = 0.5
#: A prior weighing less than this many samples is dropped.
PRIOR_GONE = 1e-6
#: A single sample's variance counts at most this many times the current estimate.
CLIP = 25.0
#: The floor of the per-sample clip (m^2/s^2): from zero, the estimate can still grow.
CLIP_FLOOR = 1e-4


class NoiseStateError(ValueError):
    """A saved velocity-noise state is malformed (the message names the field)."""


@dataclass
class VelocityNoise:
    """Learns the white velocity noise per axis (m/s, 1 sigma) from the velocity samples.

    ``prior_mps``: the estimate before any sample; ``prior_samples``: how many samples it
    weighs; ``memory_s``: the forgetting time constant (s)."""

    prior_mps: float = 0.05
    prior_samples: float = 20.0
    memory_s: float = 60.0
    _w: float = field(init=False)
    _s: float = field(init=False)
    _wp: float = field(init=False)
    _sp: float = field(init=False)
    _last: list[tuple[float, list[float]]] = field(init=False, default_factory=list)

    def __post_init__(self) -> None:
        for name in ("prior_mps", "prior_samples", "memory_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        self._w = self._s = 0.0
        self._wp = float(self.prior_samples)
        self._sp = self._wp * self.prior_mps**2

    @property
    def sigma_mps(self) -> float:
        """The current estimate (m/s per axis)."""
        w = self._w + self._wp
        return math.sqrt((self._s + self._sp) / w) if w > 0.0 else self.prior_mps

    def update(self, t_s: float, v_mps: list[float]) -> None:
        """Take a velocity sample (s, m/s); samples come in time order (a repeated or older
        time starts the run of samples again)."""
        last = self._last
        if last and t_s <= last[-1][0]:
            last.clear()
        last.append((t_s, v_mps))
        if len(last) > ORDER + 1:
            del last[0]
        if len(last) < ORDER + 1:
            return
        (t0, v0), (t1, v1), (t2, v2), (t3, v3) = last
        h1, h2, h3 = t1 - t0, t2 - t1, t3 - t2
        lo, hi = min(h1, h2, h3), max(h1, h2, h3)
        if hi > MAX_INTERVAL_S or hi > 4.0 * lo:
            return
        # c_i = 1 / prod_{j != i} (t_i - t_j), the third divided difference's weights
        c0 = -1.0 / (h1 * (h1 + h2) * (h1 + h2 + h3))
        c1 = 1.0 / (h1 * h2 * (h2 + h3))
        c2 = -1.0 / ((h1 + h2) * h2 * h3)
        c3 = 1.0 / ((h1 + h2 + h3) * (h2 + h3) * h3)
        if len(v3) == 3:  # unrolled (the per-sample path): the same arithmetic
            e0 = c0 * v0[0] + c1 * v1[0] + c2 * v2[0] + c3 * v3[0]
            e1 = c0 * v0[1] + c1 * v1[1] + c2 * v2[1] + c3 * v3[1]
            e2 = c0 * v0[2] + c1 * v1[2] + c2 * v2[2] + c3 * v3[2]
            d2 = 0.0 + e0 * e0 + e1 * e1 + e2 * e2
        else:
            d2 = 0.0
            for k in range(len(v3)):
                d = c0 * v0[k] + c1 * v1[k] + c2 * v2[k] + c3 * v3[k]
                d2 += d * d
        sample = d2 / ((c0 * c0 + c1 * c1 + c2 * c2 + c3 * c3) * len(v3))
        cap = max(CLIP * self.sigma_mps**2, CLIP_FLOOR)
        rho = math.exp(-h3 / self.memory_s) if self.memory_s > 0.0 else 0.0
        self._w = rho * self._w + 1.0
        self._s = rho * self._s + min(sample, cap)
        rho_p = rho**10
        self._wp = rho_p * self._wp if self._wp > PRIOR_GONE else 0.0
        self._sp = rho_p * self._sp if self._wp > 0.0 else 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "w": self._w,
            "s": self._s,
            "w_prior": self._wp,
            "s_prior": self._sp,
            "last": [[t, [float(c) for c in v]] for t, v in self._last],
        }

    def restore(self, d: Any) -> None:
        """Restore what :meth:`to_dict` saved (settings from the constructor)."""
        try:
            w, s = float(d["w"]), float(d["s"])
            wp, sp = float(d["w_prior"]), float(d["s_prior"])
            last = [(float(t), [float(c) for c in v]) for t, v in d["last"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise NoiseStateError(f"velocity noise state is malformed: {exc!r}") from exc
        for name, v in (("w", w), ("s", s), ("w_prior", wp), ("s_prior", sp)):
            if not (math.isfinite(v) and v >= 0.0):
                raise NoiseStateError(f"velocity noise state {name}={v!r} must be finite >= 0")
        if len(last) > ORDER + 1:
            raise NoiseStateError(
                f"velocity noise state keeps {len(last)} samples, at most {ORDER + 1}"
            )
        self._w, self._s, self._wp, self._sp, self._last = w, s, wp, sp, last
