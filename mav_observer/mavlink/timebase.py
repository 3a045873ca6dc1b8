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
* ``time_boot_ms`` going back by more than ``reboot_back_s`` means that component rebooted:
  its clock mapping restarts; for the autopilot the caller resets the vehicle's observers.
  Going back by less is a reordered or duplicated message, refused as ``out_of_order``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ClockMap:
    """Offset ``arrival - boot`` (s) of one component's boot clock."""

    drift_ppm: float = 200.0
    reboot_back_s: float = 2.0
    offset_s: float | None = None
    last_boot_s: float | None = None
    last_arrival_s: float | None = None

    def update(self, boot_s: float, arrival_s: float) -> str | None:
        """Account one timed message. Returns ``"reboot"`` if the clock went back by more than
        ``reboot_back_s`` (the mapping restarts from this message), ``"out_of_order"`` if it went
        back by less (the message should be refused), else ``None``."""
        event = None
        if self.last_boot_s is not None and boot_s < self.last_boot_s:
            if self.last_boot_s - boot_s > self.reboot_back_s:
                event = "reboot"
                self.offset_s = None
            else:
                return "out_of_order"
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
        return event

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
