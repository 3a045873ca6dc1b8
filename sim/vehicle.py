"""The vehicle behind a scenario: position, velocities and attitude (pure, for the emitter).

From a :class:`~sim.scenarios.Scenario` (relative position ``x(t)``, target velocity ``w``,
velocity error ``b = w - a``) and where the target starts in the local NED frame:

* target position ``p_t(t) = p_t0 + w t``; vehicle position ``p(t) = p_t(t) - x(t)``;
* true vehicle velocity ``w - x'(t)``; measured velocity (LOCAL_POSITION_NED) ``u = true - b``
  (so the paper's ``v = -u``);
* attitude of a multirotor: the nose toward the target (as when pointing at a region of
  interest), roll and pitch tilting the thrust to produce the acceleration against gravity,
  plus an optional slow wobble (``wobble_deg``) so that body-frame conversions are exercised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mav_observer.geo.frames import Mat3, euler_from_dcm, euler_to_dcm
from sim.scenarios import Scenario

GRAVITY_MPS2 = 9.80665


@dataclass(frozen=True)
class VehicleState:
    """Truth at one instant (NED, SI units)."""

    t_s: float
    pos_ned_m: np.ndarray
    vel_true_ned_mps: np.ndarray
    vel_meas_ned_mps: np.ndarray
    rel_pos_ned_m: np.ndarray  # target minus vehicle
    target_pos_ned_m: np.ndarray
    roll: float
    pitch: float
    yaw: float

    @property
    def dcm(self) -> Mat3:
        return euler_to_dcm(self.roll, self.pitch, self.yaw)


@dataclass(frozen=True)
class Vehicle:
    """See the module docstring. ``target_pos0_ned_m``: where the target is at ``t = 0``."""

    scenario: Scenario
    target_pos0_ned_m: tuple[float, float, float] = (40.0, 30.0, 0.0)
    wobble_deg: float = 2.0
    wobble_period_s: float = 7.0

    def __post_init__(self) -> None:
        if self.scenario.n != 3:
            raise ValueError(
                f"the vehicle needs a 3-D scenario, {self.scenario.name} has n={self.scenario.n}"
            )

    def _vel_true(self, t: float) -> np.ndarray:
        return self.scenario.w_mps - self.scenario.xdot(t)

    def yaw_offset(self, t: float) -> float:
        """Heading (rad) added to the nose-toward-the-target yaw at ``t``; 0 here (see
        :class:`sim.realism.SwingVehicle`)."""
        return 0.0

    def state(self, t: float) -> VehicleState:
        sc = self.scenario
        x = sc.x(t)
        target = np.asarray(self.target_pos0_ned_m, dtype=float) + sc.w_mps * t
        vel = self._vel_true(t)
        h = 1e-3
        acc = (self._vel_true(t + h) - self._vel_true(t - h)) / (2 * h)
        # thrust along -z_body produces acc - g
        thrust = acc - np.array([0.0, 0.0, GRAVITY_MPS2])
        z_b = -thrust / np.linalg.norm(thrust)
        yaw = math.atan2(x[1], x[0]) if math.hypot(x[0], x[1]) > 1e-6 else 0.0
        yaw += self.yaw_offset(t)
        x_c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        y_b = np.cross(z_b, x_c)
        y_b /= np.linalg.norm(y_b)
        x_b = np.cross(y_b, z_b)
        r = np.column_stack((x_b, y_b, z_b))
        roll, pitch, yaw = euler_from_dcm(tuple(map(tuple, r)))  # type: ignore[arg-type]
        if self.wobble_deg:
            w = math.radians(self.wobble_deg)
            ph = 2 * math.pi * t / self.wobble_period_s
            roll += w * math.sin(ph)
            pitch += w * math.sin(1.3 * ph + 1.0)
        return VehicleState(
            t_s=t,
            pos_ned_m=target - x,
            vel_true_ned_mps=vel,
            vel_meas_ned_mps=vel - sc.vel_error_mps,
            rel_pos_ned_m=x,
            target_pos_ned_m=target,
            roll=roll,
            pitch=pitch,
            yaw=yaw,
        )
