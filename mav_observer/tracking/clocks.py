"""One time base per vehicle: its autopilot's boot clock.

Policy (``docs/frames.md``, "Time"):

* Every sample of a vehicle goes on the **autopilot's boot clock** (seconds since it booted),
  the clock of its LOCAL_POSITION_NED and ATTITUDE. It is monotonic and free of network
  jitter, and a tlog whose own timestamps jump keeps a sane observer time.
* Each component clock (``time_boot_ms`` of a given sysid and compid) is related to the
  arrival clock (the tlog's timestamps on replay, the receive time live) by an offset,
  ``arrival - boot``, estimated as a *leaky minimum*: the smallest offset seen, allowed to
  grow by ``drift_ppm`` to follow clock drift. Latency only ever adds to ``arrival - boot``,
  so the minimum is its latency-free value.
* A message from another clock (a gimbal with its own ``time_boot_ms``) is moved onto the
  autopilot clock through the two offsets; a message with no time at all
  (CAMERA_TRACKING_IMAGE_STATUS, MOUNT_STATUS) gets its arrival time moved onto the autopilot
  clock (it then carries the link's latency).
* ``time_boot_ms`` going back by more than ``reboot_back_s`` may mean that component
  rebooted, or may be one corrupted or foreign message. A reboot is **confirmed** only once
  ``confirm_count`` messages over at least ``confirm_s`` of arrival time follow one another
  as a clock does (each later than the one before, by no more than the clock may advance,
  below); then its clock mapping restarts, and for the autopilot the caller resets the
  vehicle's observers. Until
  then such messages are refused (``clock_unconfirmed``) and the old clock goes on. A
  real reboot therefore costs its first ``confirm_s`` of messages; a stray message costs
  nothing. Going back by up to ``reorder_s`` (0.25 s) is another stream of the same
  component stamped a little earlier (an ATTITUDE sent after a LOCAL_POSITION_NED of a later
  time, or jitter between the two): accepted, the clock's latest time kept. Going back by
  more, less than ``reboot_back_s``, is a reordered or duplicated message, refused as
  ``out_of_order``.
* ``time_boot_ms`` may advance by at most ``jump_ahead_s`` plus ``max_rate`` times the arrival
  time since the previous message (``max_rate`` 100 leaves room for simulators run faster than
  real time); a message further ahead (a clock that jumps by hours, a corrupted field) is
  refused as ``time_jump``. If such messages are confirmed as above (the first message seen
  was the stray one, or a telemetry gap of a simulator run faster than real time whose
  recorder stalled: its stamps bunch while its clock went on), the mapping restarts from
  them (``clock_jump``, the step in ``jump_s``); a forward step of up to ``gap_max_s`` is a
  telemetry gap to the caller, not a new clock. A candidate ahead is confirmed only while it
  has at least twice the messages the current clock had beside it: a clock that goes on is
  not in a gap (stray frames that a bit flip put ahead of it form a run of their own).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ClockMap:
    """Offset ``arrival - boot`` (s) of one component's boot clock."""

    drift_ppm: float = 200.0
    reboot_back_s: float = 2.0
    #: a message this little behind the latest of its clock (s) is in order for the clock:
    #: one component's streams are stamped and sent in their own order (an ATTITUDE a few ms
    #: older than the LOCAL_POSITION_NED before it); each stream's own order is its reader's
    reorder_s: float = 0.25
    confirm_count: int = 5
    confirm_s: float = 0.5
    jump_ahead_s: float = 10.0
    max_rate: float = 100.0
    #: a confirmed forward step up to this (s) is a telemetry gap, not another clock
    gap_max_s: float = 600.0
    #: the step (s) of the latest ``reboot`` (negative) or ``clock_jump``
    jump_s: float = 0.0
    offset_s: float | None = None
    last_boot_s: float | None = None
    last_arrival_s: float | None = None
    #: candidate new clocks: [first arrival, count, last boot, last arrival, min arrival - boot,
    #: messages of the current clock since, when the candidate is ahead of it]
    pending: list[list[float]] = field(default_factory=list)
    #: most candidate clocks tracked at once (stray messages each start one)
    max_candidates: int = 8

    def update(self, boot_s: float, arrival_s: float) -> str | None:
        """Account one timed message. Returns ``"reboot"`` when a clock that went back by more
        than ``reboot_back_s`` is confirmed, ``"clock_jump"`` when one that jumped ahead by
        more than ``jump_ahead_s`` is (the mapping restarts from the new clock either way: a
        stray first message cannot hold the real clock off for ever); ``"clock_unconfirmed"``
        and ``"time_jump"`` for such messages before that, ``"out_of_order"`` if the clock went
        back by more than ``reorder_s`` and less than ``reboot_back_s`` (those three: refuse
        the message, nothing changed), else ``None`` (a message up to ``reorder_s`` behind the
        latest is accepted without moving the clock's latest time)."""
        if self.last_boot_s is not None and self.last_arrival_s is not None:
            back = self.last_boot_s - boot_s
            ahead = -back - self._advance_max(arrival_s - self.last_arrival_s)
            if back > self.reboot_back_s or ahead > 0.0:
                group = self._confirm(boot_s, arrival_s)
                if group is None:
                    return "clock_unconfirmed" if back > 0.0 else "time_jump"
                self.offset_s = group[4]
                self.jump_s = group[2] - self.last_boot_s
                self.last_boot_s, self.last_arrival_s = group[2], group[3]
                self.pending = []
                return "reboot" if back > 0.0 else "clock_jump"
            if back > self.reorder_s:
                return "out_of_order"
            if back > 0.0:  # another stream's older stamp: a valid sample of the offset
                if self.offset_s is not None:
                    self.offset_s = min(self.offset_s, arrival_s - boot_s)
                return None
        if self.pending:  # candidates not heard of for a while: the old clock went on
            fresh = arrival_s - 2 * self.confirm_s
            self.pending = [g for g in self.pending if g[3] >= fresh]
            for g in self.pending:  # this clock goes on beside a candidate ahead of it
                if g[2] > boot_s:
                    g[5] += 1
        candidate = arrival_s - boot_s
        if self.offset_s is None:
            self.offset_s = candidate
        else:
            grown = self.offset_s
            if self.last_arrival_s is not None and arrival_s > self.last_arrival_s:
                grown += (arrival_s - self.last_arrival_s) * self.drift_ppm * 1e-6
            self.offset_s = min(grown, candidate)
        self.last_boot_s = boot_s
        self.last_arrival_s = arrival_s
        return None

    def _advance_max(self, arrival_dt_s: float) -> float:
        """How far a boot clock may advance in ``arrival_dt_s`` of arrival time (s)."""
        return self.jump_ahead_s + self.max_rate * max(0.0, arrival_dt_s)

    def _confirm(self, boot_s: float, arrival_s: float) -> list[float] | None:
        """Add a message of a possible new clock to the candidate it follows (a boot time
        at most ``reorder_s`` earlier or later by no more than :meth:`_advance_max`), or start
        a new one; return that
        candidate once ``confirm_count`` messages of it span ``confirm_s`` of arrival time."""
        for group in self.pending:
            first_a, count, b0, a0, low, beside = group
            if b0 < boot_s <= b0 + self._advance_max(arrival_s - a0):
                group[1:5] = [count + 1, boot_s, arrival_s, min(low, arrival_s - boot_s)]
                span = arrival_s - first_a
                # a clock ahead that the current one goes on beside is a run of stray frames
                # (a bit flip), unless it outnumbers it (the current one was the stray)
                if (
                    group[1] >= self.confirm_count
                    and span >= self.confirm_s
                    and count >= 2 * beside
                ):
                    return group
                return None
        self.pending.append([arrival_s, 1, boot_s, arrival_s, arrival_s - boot_s, 0])
        if len(self.pending) > self.max_candidates:
            self.pending.sort(key=lambda g: g[1])  # forget the least supported candidate
            del self.pending[0]
        return None

    def to_arrival(self, boot_s: float) -> float:
        """The arrival-clock time of ``boot_s`` (requires at least one update)."""
        if self.offset_s is None:
            raise ValueError("clock offset not known yet")
        return boot_s + self.offset_s

    def to_boot(self, arrival_s: float) -> float:
        """The boot-clock time of an arrival time (requires at least one update)."""
        if self.offset_s is None:
            raise ValueError("clock offset not known yet")
        return arrival_s - self.offset_s
