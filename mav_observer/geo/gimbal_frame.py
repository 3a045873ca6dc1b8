"""Which frame a gimbal's reported roll and pitch are in, told from the data (pure: plain
floats, no I/O).

GIMBAL_DEVICE_ATTITUDE_STATUS's roll and pitch are relative to the horizon by the message's
definition, and ArduPilot flags them so (ROLL_LOCK | PITCH_LOCK) for every mount type; its
servo mount (MNT1_TYPE 1) nevertheless reports the servo demands, which are relative to the
vehicle's body (``docs/frames.md``, "Servo mounts"). The two readings of one message give two
boresights in NED::

    b_flags = R_F R(q) e1            R_F = Rz(vehicle yaw), or I for a yaw in the earth frame
    b_body  = R_nb R(q) e1 = T b_flags,    T = R_nb R_F^T

A camera kept on something holds its boresight still in NED while the vehicle tilts (a
stabilising gimbal by itself, a servo mount by the autopilot's stabilisation): in the right
reading the boresight moves only with the geometry, in the wrong one it also turns with the
tilt. Between consecutive messages ``k`` and ``k+1`` the tilt's change moves ``b_flags`` by
``g = T_{k+1}^T b_body,k - b_flags,k`` when the body reading is right (``b_body`` still), and
not at all when the flags are. So the change of ``b_flags`` is regressed on ``g`` through the
origin: slope ``beta`` 0 when the flags are right, 1 when the angles are body-relative. The
geometry's own motion is the regression's noise; ``beta``'s standard error comes from the
residuals.

:class:`GimbalFrameDetector` decides once the tilt has moved enough
(:data:`MIN_TILT_EVIDENCE_RAD2`, over at least :data:`MIN_PAIRS` pairs) and ``beta`` stands
:data:`DECISION_SIGMAS` standard errors from 1/2 on one side. Until then the flags are
believed (the message's definition). How it fares on logs: ``docs/frames.md``,
"GIMBAL_DEVICE_ATTITUDE_STATUS".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mav_observer.geo.frames import Mat3, Vec3

#: Consecutive messages further apart than this (s) are not compared.
MAX_PAIR_GAP_S = 0.5
#: The sum over message pairs of ``|g|^2`` (rad^2) before anything is decided: about 6 deg of
#: tilt change, root-sum-square (a take-off and one turn).
MIN_TILT_EVIDENCE_RAD2 = 0.01
#: How many standard errors ``beta`` must stand from 1/2 to decide.
DECISION_SIGMAS = 3.0
#: Message pairs compared before anything is decided.
MIN_PAIRS = 50
#: A pair whose tilt moved the boresight further than this (rad) is skipped: an attitude
#: reset or a glitch, not a manoeuvre (0.2 rad between two messages).
MAX_PAIR_TILT_RAD = 0.2
#: A pair that neither reading explains within this (rad: the boresight moved this far in
#: both, ``|d|`` and ``|d - g|``) is skipped: the gimbal slewing to a new target, whose
#: motion says nothing of the reading but would swamp the regression's scatter and delay
#: the decision (``docs/frames.md``, "GIMBAL_DEVICE_ATTITUDE_STATUS").
MAX_SLEW_RAD = 0.03


@dataclass(frozen=True, slots=True)
class FrameEvidence:
    """What the detector has seen: ``beta`` (0: the flags' reading, 1: body-relative),
    its standard error ``beta_se``, the tilt evidence ``tilt_rad2`` (sum of ``|g|^2``,
    rad^2), the message pairs compared, and the decision (``"flags"``, ``"body"`` or
    ``None`` while undecided)."""

    beta: float
    beta_se: float
    tilt_rad2: float
    pairs: int
    decided: str | None


class GimbalFrameDetector:
    """Tells body-relative gimbal angles from horizon-relative ones for one gimbal stream
    (see the module docstring). Feed every message with :meth:`add`; :attr:`decided` is
    ``None``, ``"flags"`` or ``"body"``, and never changes once set."""

    __slots__ = ("_n", "_prev", "_sdd", "_sgd", "_sgg", "decided")

    def __init__(self, decided: str | None = None) -> None:
        """``decided``: a reading already known (a saved decision), else ``None``."""
        if decided not in (None, "flags", "body"):
            raise ValueError(f"decided must be None, 'flags' or 'body', got {decided!r}")
        self._prev: tuple[float, Vec3, Vec3] | None = None
        self._sgg = 0.0
        self._sgd = 0.0
        self._sdd = 0.0
        self._n = 0
        #: ``None`` while undecided, then ``"flags"`` or ``"body"``
        self.decided: str | None = decided

    def add(self, t_s: float, b_flags: Vec3, t_flags_body: Mat3) -> str | None:
        """One message at ``t_s`` (s): its boresight in NED read as the flags say
        (``b_flags``, unit) and ``T = R_nb R_F^T`` (``t_flags_body``, rotation matrix, rows)
        that turns it into the body reading. Returns :attr:`decided`."""
        if self.decided is not None:
            return self.decided
        t = t_flags_body
        b_body = (
            t[0][0] * b_flags[0] + t[0][1] * b_flags[1] + t[0][2] * b_flags[2],
            t[1][0] * b_flags[0] + t[1][1] * b_flags[1] + t[1][2] * b_flags[2],
            t[2][0] * b_flags[0] + t[2][1] * b_flags[1] + t[2][2] * b_flags[2],
        )
        prev = self._prev
        self._prev = (t_s, b_flags, b_body)
        if prev is None or not 0.0 < t_s - prev[0] <= MAX_PAIR_GAP_S:
            return None
        _, pf, pb = prev
        # g = T^T b_body(previous) - b_flags(previous); d = the change of b_flags
        g = [t[0][i] * pb[0] + t[1][i] * pb[1] + t[2][i] * pb[2] - pf[i] for i in range(3)]
        gg = g[0] * g[0] + g[1] * g[1] + g[2] * g[2]
        if gg > MAX_PAIR_TILT_RAD * MAX_PAIR_TILT_RAD:
            return None
        d = [b_flags[i] - pf[i] for i in range(3)]
        dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        rr = (d[0] - g[0]) ** 2 + (d[1] - g[1]) ** 2 + (d[2] - g[2]) ** 2
        if min(dd, rr) > MAX_SLEW_RAD * MAX_SLEW_RAD:
            return None
        self._sgg += gg
        self._sgd += g[0] * d[0] + g[1] * d[1] + g[2] * d[2]
        self._sdd += dd
        self._n += 1
        if self._sgg < MIN_TILT_EVIDENCE_RAD2 or self._n < MIN_PAIRS:
            return None  # (a level vehicle stays here: nothing to tell the readings apart)
        ev = self.evidence()
        if ev.beta - DECISION_SIGMAS * ev.beta_se > 0.5:
            self.decided = "body"
        elif ev.beta + DECISION_SIGMAS * ev.beta_se < 0.5:
            self.decided = "flags"
        return self.decided

    def evidence(self) -> FrameEvidence:
        """The regression so far (see :class:`FrameEvidence`)."""
        sgg, n = self._sgg, self._n
        if sgg <= 0.0:
            return FrameEvidence(math.nan, math.inf, 0.0, n, self.decided)
        beta = self._sgd / sgg
        res = max(self._sdd - 2.0 * beta * self._sgd + beta * beta * sgg, 0.0)
        se = math.sqrt(res / max(2 * n - 1, 1) / sgg)
        return FrameEvidence(beta, se, sgg, n, self.decided)
