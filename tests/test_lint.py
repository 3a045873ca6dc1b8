"""The code base is ruff clean (the project's configured rules)."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_is_clean() -> None:
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    proc = subprocess.run(
        [ruff, "check", "mav_observer", "sim", "tests", "bench"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_core_does_not_import_the_simulator_or_io() -> None:
    """The maths imports numpy and nothing that does I/O; the MAVLink adapters, clocks and
    tracker decode nothing and touch no socket, file or clock (pymavlink's message classes
    only); nothing in mav_observer imports sim."""
    io = ("import sim", "from sim", "socket", "zenoh", "time", "open(", "subprocess", "os")
    pure = {
        name: (*io, "pymavlink")
        for name in (
            "discrete.py", "monitor.py", "observer.py", "samples.py", "errors.py",
            "riccati.py", "frames.py", "records.py",
        )
    }  # fmt: skip
    for name in ("adapters.py", "timebase.py", "tracker.py"):
        pure[f"mavlink/{name}"] = io
    for name, banned in pure.items():
        text = (ROOT / "mav_observer" / name).read_text()
        for line in text.splitlines():
            stripped = line.strip()
            if stripped.startswith(("import ", "from ")):
                words = stripped.replace(",", " ").replace(".", " ").split()
                bad = [b for b in banned if b in words or (b.endswith("(") and b in stripped)]
                assert not bad, f"{name}: {stripped}"
            assert "open(" not in stripped or stripped.startswith("#"), f"{name}: {stripped}"
    for path in (ROOT / "mav_observer").rglob("*.py"):
        for line in path.read_text().splitlines():
            assert not line.strip().startswith(("import sim", "from sim")), f"{path.name}: {line}"
