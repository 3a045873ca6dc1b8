"""Where the shared real flight logs are: one answer for the tests and the benches."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: A log every copy of the shared logs has.
MARKER = "ardupilot_sitl_servo_mount_roi.tlog"


def find_tlogs() -> Path:
    """The shared real logs: ``$MAV_OBSERVER_TLOGS``, else ``../shared/tlogs`` beside the
    checkout (as the project keeps them), else the workplace's ``/work/shared/tlogs`` (a
    checkout elsewhere, as CI's fresh clone). Missing, a :class:`FileNotFoundError` naming
    where it looked: the tests that need the logs fail loudly, never skip."""
    candidates = [
        os.environ.get("MAV_OBSERVER_TLOGS"),
        ROOT.parent / "shared" / "tlogs",
        Path("/work/shared/tlogs"),
    ]
    for c in candidates:
        if c and (Path(c) / MARKER).is_file():
            return Path(c)
    raise FileNotFoundError(
        f"the shared real logs ({MARKER} and others) are not in any of "
        f"{[str(c) for c in candidates if c]}; set MAV_OBSERVER_TLOGS"
    )


__all__ = ["MARKER", "find_tlogs"]
