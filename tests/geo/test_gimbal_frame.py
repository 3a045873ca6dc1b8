"""The gimbal frame detector: body-relative angles told from horizon-relative ones."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mav_observer.geo.frames import euler_to_dcm, rot_z
from mav_observer.geo.gimbal_frame import MIN_PAIRS, GimbalFrameDetector


def _flight(seed: int, tilt_deg: float, n: int = 600, dt_s: float = 0.1):
    """A vehicle circling a point 60 m away while it tilts (a smooth random roll and pitch
    of about ``tilt_deg``): per message its time, line of sight to the point (NED, unit) and
    ``T = R_nb Rz(yaw)^T``."""
    rng = np.random.default_rng(seed)
    target = np.array([40.0, 30.0, 0.0])
    f_roll, f_pitch = rng.uniform(0.1, 0.4, 2)
    ph = rng.uniform(0.0, 2.0 * math.pi, 2)
    out = []
    for k in range(n):
        t = k * dt_s
        ang = 0.1 * t
        pos = target + np.array([60.0 * math.cos(ang), 60.0 * math.sin(ang), -20.0])
        los = target - pos
        los /= np.linalg.norm(los)
        roll = math.radians(tilt_deg) * math.sin(2 * math.pi * f_roll * t + ph[0])
        pitch = math.radians(tilt_deg) * math.sin(2 * math.pi * f_pitch * t + ph[1])
        yaw = ang + math.pi / 2
        r_nb = np.array(euler_to_dcm(roll, pitch, yaw))
        t_fb = r_nb @ np.array(rot_z(yaw)).T
        out.append((t, los, t_fb))
    return out


def _run(flight, truth: str, noise_rad: float = 0.0, seed: int = 0) -> GimbalFrameDetector:
    """Feed the detector the flags' reading of a camera held on the point: a gimbal that
    reports horizon-relative angles (``truth="flags"``: that reading is the line of sight)
    or a servo mount reporting body angles (``"body"``: the flags' reading is ``T^T los``)."""
    rng = np.random.default_rng(seed)
    det = GimbalFrameDetector()
    for t, los, t_fb in flight:
        b = los if truth == "flags" else t_fb.T @ los
        b = b + rng.normal(0.0, noise_rad, 3)
        b /= np.linalg.norm(b)
        det.add(t, tuple(b), tuple(map(tuple, t_fb)))
    return det


@pytest.mark.parametrize("truth", ["flags", "body"])
def test_a_tilting_vehicle_tells_the_reading(truth: str) -> None:
    det = _run(_flight(1, tilt_deg=8.0), truth, noise_rad=math.radians(0.2), seed=2)
    assert det.decided == truth
    ev = det.evidence()
    assert ev.beta == pytest.approx(0.0 if truth == "flags" else 1.0, abs=0.2)


def test_a_level_vehicle_decides_nothing_and_the_flags_stand() -> None:
    det = _run(_flight(3, tilt_deg=0.0), "body")
    assert det.decided is None
    assert det.evidence().tilt_rad2 == pytest.approx(0.0, abs=1e-12)


def test_too_few_pairs_decide_nothing() -> None:
    det = _run(_flight(4, tilt_deg=15.0, n=MIN_PAIRS - 10), "body")
    assert det.decided is None
    assert det.evidence().beta == pytest.approx(1.0, abs=0.1)


def test_messages_far_apart_are_not_compared() -> None:
    flight = [(10.0 * k, los, t_fb) for k, (_, los, t_fb) in enumerate(_flight(5, 10.0))]
    det = _run(flight, "body")
    assert det.evidence().pairs == 0
    assert det.decided is None


def test_an_attitude_jump_is_skipped_not_taken_for_a_tilt() -> None:
    flight = _flight(6, tilt_deg=0.0, n=100)
    det = GimbalFrameDetector()
    jump = np.array(euler_to_dcm(math.radians(30.0), 0.0, 0.0))
    for k, (t, los, t_fb) in enumerate(flight):
        tilt = jump @ t_fb if k == 50 else t_fb  # a 30 deg roll reset for one message
        det.add(t, tuple(los), tuple(map(tuple, tilt)))
    assert det.evidence().tilt_rad2 == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**16),
    truth=st.sampled_from(["flags", "body"]),
    tilt=st.floats(3.0, 20.0),
)
def test_a_decision_is_right_and_never_changes(seed: int, truth: str, tilt: float) -> None:
    flight = _flight(seed, tilt_deg=tilt)
    det = GimbalFrameDetector()
    first = None
    rng = np.random.default_rng(seed)
    for t, los, t_fb in flight:
        b = los if truth == "flags" else t_fb.T @ los
        b = b + rng.normal(0.0, math.radians(0.3), 3)
        got = det.add(t, tuple(b / np.linalg.norm(b)), tuple(map(tuple, t_fb)))
        if first is None:
            first = got
        elif got is not None:
            assert got == first
    assert det.decided in (None, truth)
