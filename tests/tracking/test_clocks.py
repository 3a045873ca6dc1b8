"""The clock mapping of mav_observer/tracking/clocks.py."""

import numpy as np
import pytest

from mav_observer.tracking.clocks import ClockMap


def test_offset_is_the_latency_free_minimum() -> None:
    rng = np.random.default_rng(4)
    c = ClockMap()
    for i in range(500):
        boot = 100.0 + 0.05 * i
        arrival = 1_767_000_000.0 + boot + 0.01 + rng.exponential(0.02)  # latency >= 10 ms
        assert c.update(boot, arrival) is None
    assert c.offset_s == pytest.approx(1_767_000_000.0 + 0.01, abs=2e-3)
    assert c.to_boot(c.to_arrival(123.0)) == pytest.approx(123.0)


def test_offset_follows_drift() -> None:
    c = ClockMap(drift_ppm=200.0)
    for i in range(2000):
        boot = 0.1 * i
        c.update(boot, 1000.0 + boot * (1 + 100e-6))  # arrival clock 100 ppm fast
    assert c.offset_s == pytest.approx(1000.0 + 199.9 * 100e-6, abs=1e-3)


def test_reboot_and_reordering() -> None:
    c = ClockMap()
    c.update(500.0, 1500.0)
    assert c.update(499.5, 1500.1) == "out_of_order"
    assert c.last_boot_s == 500.0  # refused: nothing changed
    # a reboot is believed once 5 messages over 0.5 s agree on the new clock
    assert [c.update(3.0 + 0.1 * i, 1501.0 + 0.1 * i) for i in range(6)] == [
        "clock_unconfirmed"
    ] * 5 + ["reboot"]
    assert c.offset_s == pytest.approx(1498.0)
    assert c.last_boot_s == pytest.approx(3.5)


def test_a_stray_message_from_the_past_or_the_future_is_refused_and_changes_nothing() -> None:
    c = ClockMap()
    for i in range(50):
        c.update(500.0 + 0.1 * i, 1500.0 + 0.1 * i)
    before = (c.offset_s, c.last_boot_s)
    # stray messages with an old time (corrupted, or a foreign sender) spread over time
    for i in range(20):
        assert c.update(1.0, 1505.0 + 0.02 * i) == "clock_unconfirmed"
        assert c.update(505.0 + 0.1 * i, 1505.0 + 0.1 * i) is None  # the real clock goes on
    assert c.update(505.0 + 3600.0, 1507.0) == "time_jump"  # an hour ahead in 0.1 s
    assert c.offset_s == before[0]
    assert c.update(507.1, 1507.1) is None


def test_no_offset_yet_is_an_error() -> None:
    with pytest.raises(ValueError, match="not known yet"):
        ClockMap().to_boot(1.0)


def test_a_stray_first_message_cannot_hold_the_real_clock_off() -> None:
    """The first message seen had a bogus time (1 s while the autopilot is at 500 s): the real
    clock, ahead of the mapping it made, is refused until 5 messages over 0.5 s agree, then
    the mapping restarts from it."""
    c = ClockMap()
    c.update(1.0, 1500.0)
    events = [c.update(500.0 + 0.1 * i, 1500.0 + 0.1 * i) for i in range(8)]
    assert events == ["time_jump"] * 5 + ["clock_jump", None, None]
    assert c.offset_s == pytest.approx(1000.0)


def test_another_streams_slightly_older_stamp_is_in_order() -> None:
    # one component's ATTITUDE stamped 15 ms before the LOCAL_POSITION_NED it follows
    c = ClockMap()
    assert c.update(500.000, 1500.010) is None
    assert c.update(499.985, 1500.011) is None  # 15 ms back: used
    assert c.last_boot_s == 500.0  # the clock's latest time kept
    assert c.offset_s == pytest.approx(1000.010)
    assert c.update(499.990, 1499.995) is None  # a lower arrival - boot lowers the offset
    assert c.offset_s == pytest.approx(1000.005)
    assert c.update(499.7, 1500.02) == "out_of_order"  # 0.3 s back: refused


def test_a_sped_up_clock_across_a_recorder_stall_is_one_clock_with_a_gap() -> None:
    """A simulator at 4x: the boot clock runs 4 s per arrival second; the recorder stalls and
    loses 100 s of the clock while its stamps do not advance. The messages after the stall
    are refused until 5 of them span 0.5 s of arrival time (their clock running on, the old
    one not), then the clock goes on with ``jump_s`` the step: a telemetry gap to the caller,
    up to ``gap_max_s``."""
    c = ClockMap()
    for i in range(200):  # 20 s of boot, 5 s of arrival: no event
        assert c.update(100.0 + 0.1 * i, 1000.0 + 0.025 * i) is None
    events = [c.update(220.0 + 0.02 * i, 1004.98 + 0.005 * i) for i in range(110)]
    k = events.index("clock_jump")
    assert set(events[:k]) == {"time_jump"} and set(events[k + 1 :]) == {None}
    assert 100.0 <= c.jump_s <= c.gap_max_s


def test_a_run_of_frames_ahead_while_the_clock_goes_on_is_no_gap() -> None:
    """Copies of the real clock's messages whose time a bit flip put 65.5 s ahead, one beside
    each real message for seconds: a clock ahead that the current one goes on beside is never
    confirmed (it would need twice the current clock's messages)."""
    c = ClockMap()
    events = []
    for i in range(100):
        t = 100.0 + 0.1 * i
        events.append(c.update(t, 1000.0 + 0.1 * i))
        events.append(c.update(t + 65.536, 1000.0 + 0.1 * i + 0.001))
    assert "clock_jump" not in events and c.last_boot_s == pytest.approx(109.9)
    assert events.count("time_jump") == 100
