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
  ``confirm_count`` messages over at least ``confirm_s`` of arrival time agree on the new
  clock (their ``arrival - boot`` within ``confirm_tol_s`` of each other); then its clock
  mapping restarts, and for the autopilot the caller resets the vehicle's observers. Until
  then such messages are refused (``clock_unconfirmed``) and the old clock goes on. A
  real reboot therefore costs its first ``confirm_s`` of messages; a stray message costs
  nothing. Going back by less than ``reboot_back_s`` is a reordered or duplicated message,
  refused as ``out_of_order``.
* ``time_boot_ms`` ahead of what the arrival clock predicts by more than ``jump_ahead_s``
  (a clock that jumps by hours, a corrupted field) is refused as ``time_jump``: the boot clock
  cannot run faster than the arrival clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class ClockMap:
    """Offset ``arrival - boot`` (s) of one component's boot clock."""

    drift_ppm: float = 200.0
    reboot_back_s: float = 2.0
    confirm_count: int = 5
    confirm_s: float = 0.5
    confirm_tol_s: float = 0.5
    jump_ahead_s: float = 10.0
    offset_s: float | None = None
    last_boot_s: float | None = None
    last_arrival_s: float | None = None
    #: messages of a possible new clock (boot_s, arrival_s), waiting for confirmation
    pending: list[tuple[float, float]] = field(default_factory=list)

    def update(self, boot_s: float, arrival_s: float) -> str | None:
        """Account one timed message. Returns ``"reboot"`` when a clock that went back by more
        than ``reboot_back_s`` is confirmed (the mapping restarts from the new clock),
        ``"clock_unconfirmed"`` for such a message before that, ``"out_of_order"`` if it went
        back by less, ``"time_jump"`` if it is too far ahead (those three: refuse the message;
        nothing changed), else ``None``."""
        if self.last_boot_s is not None and boot_s < self.last_boot_s:
            if self.last_boot_s - boot_s <= self.reboot_back_s:
                return "out_of_order"
            if not self._confirm(boot_s, arrival_s):
                return "clock_unconfirmed"
            self.offset_s = min(a - b for b, a in self.pending)
            self.last_boot_s, self.last_arrival_s = self.pending[-1]
            self.pending = []
            return "reboot"
        if self.offset_s is not None and boot_s - (arrival_s - self.offset_s) > self.jump_ahead_s:
            return "time_jump"
        if self.pending and arrival_s - self.pending[-1][1] > self.confirm_s:
            self.pending = []  # the old clock went on: what looked like a reboot was not
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

    def _confirm(self, boot_s: float, arrival_s: float) -> bool:
        """Add a message of a possible new clock; True once enough of them agree."""
        offset = arrival_s - boot_s
        agree = [
            (b, a)
            for b, a in self.pending
            if b < boot_s and abs((a - b) - offset) <= self.confirm_tol_s
        ]
        self.pending = [*agree, (boot_s, arrival_s)]
        span = arrival_s - self.pending[0][1]
        return len(self.pending) >= self.confirm_count and span >= self.confirm_s

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
