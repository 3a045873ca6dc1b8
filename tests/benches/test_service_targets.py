"""The many-targets benchmark's stream (bench/service_targets.py): N copies of every
LANDING_TARGET, one per target_num, re-packed with continuous sequence numbers."""

from __future__ import annotations

import itertools
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
for p in (ROOT, ROOT / "bench"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import service_targets  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402


def test_every_landing_target_is_sent_once_per_target_with_continuous_sequence() -> None:
    frames = service_targets.plan(targets=5, bearing_hz=30.0, duration_s=1.0, seed=0)
    parser = mavlink.MAVLink(None)
    nums: Counter[int] = Counter()
    seqs: dict[tuple[int, int], list[int]] = {}
    times = [t for t, _ in frames]
    assert times == sorted(times)
    for _, frame in frames:
        (msg,) = parser.parse_buffer(frame)
        seqs.setdefault((msg.get_srcSystem(), msg.get_srcComponent()), []).append(msg.get_seq())
        if msg.get_type() == "LANDING_TARGET":
            nums[msg.target_num] += 1
    assert sorted(nums) == [0, 1, 2, 3, 4]
    assert len(set(nums.values())) == 1 and 25 <= nums[0] <= 31  # 30 Hz for 1 s, each
    for seq in seqs.values():  # one encoder per source: no gap a receiver would count
        assert all((b - a) % 256 == 1 for a, b in itertools.pairwise(seq))
