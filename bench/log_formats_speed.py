"""Replay of DataFlash and ULog files against the libraries' plain read of the same file.

Run: ``python bench/log_formats_speed.py [--repeat N] [--json FILE]`` (about two minutes).

Whole processes, start-up included, runs alternating (replay, baseline, replay, ...), the
median of ``--repeat`` pairs, each after one untimed run:

* ``.bin``: ``mav-observer replay LOG.bin`` against a plain DFReader loop,
  ``DFReader_binary(path)`` then ``recv_msg()`` until None (it decodes every record);
* ``.ulg``: ``mav-observer replay LOG.ulg`` against a plain pyulog load, ``ULog(path)``.

The files: a public ArduSub log's first 512 KiB and pyulog's PX4 SITL log (``tests/data/logs``;
the latter has no gimbal topic, so replay reads it and ends in "no usable bearing"), and a
30-minute figure-8 gimbal flight (10 Hz gimbal and position, 20 Hz attitude) written by
``sim convert`` with the inertial records that make most of a real log (``IMU`` of two IMUs at
200 Hz; ``sensor_combined`` at 400 Hz), generated once into ``bench/.cache/``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "bench" / ".cache"
DATA = ROOT / "tests" / "data" / "logs"
DFREADER = (
    "import sys\nfrom pymavlink import DFReader\nd = DFReader.DFReader_binary(sys.argv[1])\n"
    "while d.recv_msg() is not None:\n    pass\n"
)
PYULOG = "import sys\nfrom pyulog import ULog\nULog(sys.argv[1])\n"


def long_logs() -> tuple[Path, Path]:
    """The 30-minute flight as ``.bin`` and ``.ulg`` (made once)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    tlog, binf, ulg = CACHE / "fig8_30min.tlog", CACHE / "fig8_30min.bin", CACHE / "fig8_30min.ulg"
    if not (binf.exists() and ulg.exists()):
        subprocess.run(
            [sys.executable, "-m", "sim", "emit", "--scenario", "figure8", "--bearing", "gimbal",
             "--tlog", str(tlog), "--duration", "1800", "--bearing-noise-deg", "0.5"],
            cwd=ROOT, check=True, capture_output=True,
        )  # fmt: skip
        from sim.logwriters import convert

        convert(tlog, binf, imu_hz=200.0)
        convert(tlog, ulg, imu_hz=400.0)
    return binf, ulg


def _wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=ROOT, capture_output=True, check=False)
    return time.perf_counter() - t0


def measure(path: Path, baseline: str, repeat: int) -> dict[str, object]:
    replay = [sys.executable, "-m", "mav_observer", "replay", str(path), "-q"]
    base = [sys.executable, "-c", baseline, str(path)]
    _wall(replay)
    _wall(base)
    pairs = [(_wall(replay), _wall(base)) for _ in range(repeat)]
    ratios = [b / a for a, b in pairs]
    return {
        "file": path.name,
        "bytes": path.stat().st_size,
        "replay_s": statistics.median(a for a, _ in pairs),
        "baseline_s": statistics.median(b for _, b in pairs),
        "speedup": statistics.median(ratios),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    binf, ulg = long_logs()
    res = {
        "bin": [
            measure(DATA / "ardusub48_sitl_mnt_mode_first512k.bin", DFREADER, args.repeat),
            measure(binf, DFREADER, args.repeat),
        ],
        "ulg": [
            measure(DATA / "pyulog_sample_px4_events.ulg", PYULOG, args.repeat),
            measure(ulg, PYULOG, args.repeat),
        ],
    }
    for kind, rows in res.items():
        for r in rows:
            print(
                f"{kind} {r['file']:42s} {r['bytes'] / 1e6:6.1f} MB  replay {r['replay_s']:.2f} s"
                f"  baseline {r['baseline_s']:.2f} s  replay is {r['speedup']:.2f}x as fast"
            )
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
