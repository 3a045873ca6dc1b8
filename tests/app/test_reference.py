"""mav_observer.app.reference: a reference track read, and a series' errors against it."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from mav_observer.app import reference
from sim import truth as truth_file


@dataclass
class _Series:
    t_boot_s: list[float] = field(default_factory=list)
    rel_pos: list[list[float]] = field(default_factory=list)
    bias: list[list[float]] = field(default_factory=list)
    pos_std: list[list[float]] = field(default_factory=list)
    status: list[str] = field(default_factory=list)


def _truth_line(t: float, x: list[float], a: list[float]) -> dict:
    return truth_file.record(
        t_unix_s=1e9 + t,
        t_boot_s=t,
        sysid=3,
        target="gimbal",
        rel_pos_ned_m=x,
        bias_ned_mps=a,
        target_pos_ned_m=x,
        vehicle_pos_ned_m=[0.0, 0.0, 0.0],
        vehicle_vel_meas_ned_mps=[0.0, 0.0, 0.0],
        attitude_rpy_rad=[0.0, 0.0, 0.0],
    )


def test_a_simulator_truth_file_is_a_reference_track(tmp_path: Path) -> None:
    path = tmp_path / "truth.jsonl"
    truth_file.write(path, [_truth_line(t, [10.0 + t, 0.0, 0.0], [0.5, 0, 0]) for t in range(9)])
    assert set(reference.KEYS) <= set(truth_file.KEYS)
    track = reference.read(path)
    assert list(track) == ["3/gimbal"]
    assert track["3/gimbal"]["t_boot_s"] == [float(t) for t in range(9)]
    assert track["3/gimbal"]["rel_pos_ned_m"][4] == [14.0, 0.0, 0.0]


def test_errors_interpolate_the_track_at_the_estimates_times(tmp_path: Path) -> None:
    track = {
        "t_boot_s": [0.0, 10.0],
        "rel_pos_ned_m": [[10.0, 0, 0], [20.0, 0, 0]],
        "bias_ned_mps": [[1.0, 0, 0], [1.0, 0, 0]],
    }
    s = _Series()
    for t in np.linspace(0.0, 12.0, 13):  # the last two outside the track: not scored
        s.t_boot_s.append(float(t))
        s.rel_pos.append([10.0 + t, 3.0, 4.0])  # 5 m off, everywhere
        s.bias.append([1.0, 0.0, 0.0])
        s.pos_std.append([2.0, 2.0, 1.0])  # a 1-sigma radius of 3 m
        s.status.append("converged" if t >= 4.0 else "converging")
    e = reference.errors(s, track)
    assert len(e["t_boot_s"]) == 11
    np.testing.assert_allclose(e["pos_err_m"], 5.0)
    np.testing.assert_allclose(e["range_true_m"], 10.0 + e["t_boot_s"])
    np.testing.assert_allclose(e["bias_err_mps"], 0.0)
    last = reference.last_third(e)
    assert last["samples"] == 4  # t = 7..10
    assert last["max_rel_pos_err"] == pytest.approx(5.0 / 17.0)
    # from the first converged estimate (t = 4) on: 7 estimates, each 5 m off with a 3 m
    # sigma (inside twice it), and above 5 % of the range all along, 6 s of the 10 s span
    h = reference.honesty(e)
    assert h["after_convergence"] == 7 and h["uncovered"] == 0
    assert h["worst_sigma_ratio"] == pytest.approx(5.0 / 3.0)
    assert h["time_above_s"] == pytest.approx(6.0) and h["time_above_share"] == pytest.approx(0.6)
    assert reference.honesty(e, rel_threshold=0.5)["time_above_s"] == 0.0


def test_a_bad_line_names_the_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "ref.jsonl"
    good = json.dumps(
        {"t_boot_s": 1.0, "sysid": 1, "target": "gimbal", "rel_pos_ned_m": [1, 2, 3],
         "bias_ned_mps": [0, 0, 0]}
    )  # fmt: skip
    path.write_text(good + "\n" + good.replace('"sysid": 1, ', "") + "\n")
    with pytest.raises(reference.ReferenceError, match=r"ref.jsonl:2: .*sysid"):
        reference.read(path)
    path.write_text(good.replace("[1, 2, 3]", "[1, 2]") + "\n")
    with pytest.raises(reference.ReferenceError, match=r":1: rel_pos_ned_m and bias_ned_mps"):
        reference.read(path)
    path.write_text(good.replace("[1, 2, 3]", "[1, NaN, 3]") + "\n")
    with pytest.raises(reference.ReferenceError, match="non-finite"):
        reference.read(path)
    with pytest.raises(reference.ReferenceError, match="cannot read the reference track"):
        reference.read(tmp_path / "missing.jsonl")
