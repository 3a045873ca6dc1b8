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
    """The observer maths imports numpy and nothing that does I/O; mav_observer never
    imports sim."""
    pure = ["discrete.py", "monitor.py", "observer.py", "samples.py", "errors.py"]
    banned = ("import sim", "from sim", "socket", "zenoh", "pymavlink", "time", "open(")
    for name in pure:
        text = (ROOT / "mav_observer" / name).read_text()
        for line in text.splitlines():
            stripped = line.strip()
            if stripped.startswith(("import ", "from ")):
                assert not any(b in stripped for b in banned), f"{name}: {stripped}"
    for path in (ROOT / "mav_observer").glob("*.py"):
        for line in path.read_text().splitlines():
            assert not line.strip().startswith(("import sim", "from sim")), f"{path.name}: {line}"
