"""mav_observer.core.targets: one observer per target, fed, exported and resumed."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from mav_observer.core.observer import ObserverConfig
from mav_observer.core.targets import Targets, VehicleFix, check_saved
from mav_observer.errors import StateError

TARGET_NED_M = np.array([20.0, 5.0, 10.0])


def _flown(seconds: float = 60.0, seed: int = 3) -> tuple[Targets, VehicleFix]:
    """A vehicle circling a fixed target at 2 m/s, bearings at 10 Hz (0.2 deg)."""
    rng = np.random.default_rng(seed)
    tg = Targets(ObserverConfig())
    for k in range(int(seconds * 10)):
        t = k * 0.1
        w = 2.0 / 15.0
        pos = np.array([15.0 * math.cos(w * t), 15.0 * math.sin(w * t), 0.0])
        u = np.array([-2.0 * math.sin(w * t), 2.0 * math.cos(w * t), 0.0])
        assert tg.velocity(t, (-u).tolist(), None) == []
        y = TARGET_NED_M - pos
        y = y / np.linalg.norm(y) + rng.normal(0.0, math.radians(0.2), 3)
        tg.bearing("gimbal", "GIMBAL_DEVICE_ATTITUDE_STATUS", t, (y / np.linalg.norm(y)).tolist(),
                   (t, (-u).tolist()))  # fmt: skip
    return tg, VehicleFix(t, tuple(pos), tuple(u))


def test_the_first_bearing_makes_the_observer_and_waits_for_a_velocity() -> None:
    tg = Targets(ObserverConfig())
    est, new = tg.bearing("gimbal", "GIMBAL_DEVICE_ATTITUDE_STATUS", 1.0, [1.0, 0, 0], None)
    assert new and est is None and "gimbal" in tg and len(tg) == 1
    assert tg.sources() == {"gimbal": "GIMBAL_DEVICE_ATTITUDE_STATUS"}
    tg.velocity(1.1, [0.0, 1.0, 0.0], None)
    est, new = tg.bearing("gimbal", "GIMBAL_DEVICE_ATTITUDE_STATUS", 1.2, [1.0, 0, 0], None)
    assert not new and est is not None


def test_a_refused_velocity_is_returned_not_raised() -> None:
    tg = Targets(ObserverConfig())
    tg.bearing("gimbal", "G", 1.0, [1.0, 0, 0], (1.0, [0.0, 1.0, 0.0]))
    tg.velocity(3.0, [0.0, 1.0, 0.0], None)
    refused = tg.velocity(2.0, [0.0, 1.0, 0.0], None)  # time went backwards
    assert len(refused) == 1 and "backwards" in str(refused[0])


def test_an_exported_observer_resumes_moved_by_the_vehicles_displacement() -> None:
    tg, fix = _flown()
    before = tg.get("gimbal")
    x0 = before.predict(fix.t_boot_s).x_m
    assert np.linalg.norm(x0 - (TARGET_NED_M - fix.pos_ned_m)) < 1.0
    saved = tg.export(7, fix)
    assert [(e["sysid"], e["target"]) for e in saved] == [(7, "gimbal")]
    assert check_saved(saved) == {7: saved}
    moved = VehicleFix(fix.t_boot_s + 5.0, (fix.pos_ned_m[0] + 3.0, *fix.pos_ned_m[1:]),
                       (0.0, 0.0, 0.0))  # fmt: skip
    fresh = Targets(ObserverConfig())
    (r,) = fresh.resume(saved, moved, max_gap_s=60.0)
    assert r.restored and r.gap_s == pytest.approx(5.0, abs=0.2)
    x = fresh.get("gimbal").predict(moved.t_boot_s).x_m
    assert np.linalg.norm(x - (TARGET_NED_M - np.array(moved.pos_ned_m))) < 1.5


def test_resume_says_why_it_did_not() -> None:
    tg, fix = _flown(seconds=30.0)
    saved = tg.export(1, fix)
    later = VehicleFix(fix.t_boot_s + 100.0, fix.pos_ned_m, fix.vel_ned_mps)
    earlier = VehicleFix(1.0, fix.pos_ned_m, fix.vel_ned_mps)
    assert [r.outcome for r in Targets(ObserverConfig()).resume(saved, later, 60.0)] == ["too_old"]
    assert [r.outcome for r in Targets(ObserverConfig()).resume(saved, earlier, 60.0)] == [
        "clock_back"
    ]
    assert [r.outcome for r in tg.resume(saved, fix, 60.0)] == ["superseded"]


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda e: e.update(sysid=True), r"observers\[0\]\.sysid"),
        (lambda e: e.update(source=3), r"observers\[0\]\.source"),
        (lambda e: e["vehicle"].pop("t_boot_s"), r"observers\[0\]\.vehicle is malformed"),
        (lambda e: e["vehicle"].update(vel_ned_mps=[0, math.inf, 0]), r"finite 3-vectors"),
    ],
)
def test_check_saved_names_the_bad_field(mutate, match: str) -> None:
    tg, fix = _flown(seconds=30.0)
    saved = copy.deepcopy(tg.export(1, fix))
    mutate(saved[0])
    with pytest.raises(StateError, match=match):
        check_saved(saved)
    with pytest.raises(StateError, match=r"observers\[1\] must be a table"):
        check_saved([tg.export(1, fix)[0], "nonsense"])


def test_a_restarted_target_starts_afresh_on_its_next_bearing() -> None:
    tg, fix = _flown(30.0)
    before = tg.get("gimbal")
    assert before is not None and before.started
    assert tg.restart("gimbal") and "gimbal" not in tg
    assert not tg.restart("gimbal")  # nothing left to forget
    est, new = tg.bearing("gimbal", "GIMBAL_DEVICE_ATTITUDE_STATUS", fix.t_boot_s + 0.1,
                          [1.0, 0.0, 0.0], (fix.t_boot_s, [0.0, -2.0, 0.0]))  # fmt: skip
    after = tg.get("gimbal")
    assert new and after is not before and after is not None and after.counts["bearing"] == 1
    assert est is not None  # started from the latest velocity given
