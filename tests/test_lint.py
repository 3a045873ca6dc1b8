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


#: Every module of mav_observer, by role: the maths (numpy at most, no I/O, no pymavlink),
#: the MAVLink adapters, clocks and tracker (pymavlink's message classes, no I/O), and the
#: edges that do I/O (files, sockets, Zenoh, the clock, the command line). A new module must
#: be placed here, so the purity rule cannot miss it.
MATHS = {
    "__init__.py", "errors.py", "frames.py", "records.py", "batch.py", "targets.py",
    "mavlink/attitude.py", "smoother.py", "geodesy.py", "mapexport.py", "gimbalframe.py",
    "core/__init__.py", "core/config.py", "core/observer.py", "core/samples.py",
    "core/state.py", "core/warmup.py", "core/kernels/__init__.py", "core/kernels/algebra.py",
    "core/kernels/bank.py", "core/kernels/estimator.py", "core/kernels/layout.py",
    "core/kernels/learners.py", "core/kernels/monitor.py", "core/kernels/observer.py",
    "core/kernels/paper.py", "core/kernels/streams.py",
}  # fmt: skip
MESSAGES = {"mavlink/__init__.py", "mavlink/adapters.py", "mavlink/timebase.py",
            "mavlink/tracker.py", "mavlink/out.py"}  # fmt: skip
EDGES = {
    "__main__.py", "cli.py", "listen.py", "reference.py", "replay.py", "report.py",
    "service.py", "settings.py", "statefile.py", "zenoh_io.py", "mavlink/connection.py",
    "mavlink/dialect.py", "mavlink/fastdecode.py", "mavlink/signing.py", "mavlink/tlog.py",
    "mavlink/_dialect_table.py", "mavlink/sources.py", "core/compiled.py",
}  # fmt: skip


def test_every_module_has_a_role() -> None:
    pkg = ROOT / "mav_observer"
    found = {p.relative_to(pkg).as_posix() for p in pkg.rglob("*.py")}
    assert found == MATHS | MESSAGES | EDGES, found ^ (MATHS | MESSAGES | EDGES)
    assert not (MATHS & MESSAGES or MATHS & EDGES or MESSAGES & EDGES)


def test_core_does_not_import_the_simulator_or_io() -> None:
    """The maths imports numpy and nothing that does I/O; the MAVLink adapters, clocks and
    tracker decode nothing and touch no socket, file or clock (pymavlink's message classes
    only); nothing in mav_observer imports sim."""
    io = ("import sim", "from sim", "socket", "zenoh", "time", "open(", "subprocess", "os")
    pure = {name: (*io, "pymavlink") for name in MATHS}
    for name in MESSAGES:
        pure[name] = io
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
