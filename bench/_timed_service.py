"""The service with two timers, for ``bench/service_latency.py --breakdown``.

Run as ``python bench/_timed_service.py OUT.json run ARGS...``: ``mav-observer run ARGS``
with the wall time (``time.perf_counter``) of each bearing message's
:meth:`~mav_observer.app.service.Service.handle` (the tracker, the observer and the
publication of its estimate) and of each
:meth:`~mav_observer.outputs.zenoh_io.Publications.estimate` (the record's publication over Zenoh)
gathered, and written to ``OUT.json`` when the service stops (seconds, in order). The product
is not changed: the two public methods are wrapped in this process only.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mav_observer.app import cli, service
from mav_observer.mavlink.dialect import type_key
from mav_observer.outputs import zenoh_io

BEARING = "GIMBAL_DEVICE_ATTITUDE_STATUS"


def main() -> int:
    if len(sys.argv) < 3 or sys.argv[2] != "run":
        print(f"usage: python {sys.argv[0]} OUT.json run [mav-observer run options]")
        return 2
    out = Path(sys.argv[1])
    times: dict[str, list[float]] = {"handle_s": [], "publish_s": []}
    handle, publish = service.Service.handle, zenoh_io.Publications.estimate

    def timed_handle(self: Any, t_unix_s: float, msg: Any, now: float) -> None:
        t0 = time.perf_counter()
        handle(self, t_unix_s, msg, now)
        if type_key(msg) == BEARING:
            times["handle_s"].append(time.perf_counter() - t0)

    def timed_publish(self: Any, sysid: int, target: str, payload: str) -> None:
        t0 = time.perf_counter()
        publish(self, sysid, target, payload)
        times["publish_s"].append(time.perf_counter() - t0)

    service.Service.handle = timed_handle  # type: ignore[method-assign]
    zenoh_io.Publications.estimate = timed_publish  # type: ignore[method-assign]
    try:
        return cli.main(sys.argv[2:])
    finally:
        out.write_text(json.dumps(times))


if __name__ == "__main__":
    raise SystemExit(main())
