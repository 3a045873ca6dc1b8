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


#: Each folder of mav_observer has one role, and every module in it takes its folder's: the
#: maths (numpy and numba at most: no I/O, no pymavlink), the tracking of MAVLink messages
#: into samples (pymavlink's message objects, no I/O), and the edges that do I/O (sockets,
#: files, Zenoh, the clock, the command line). A new folder must be given a role here.
ROLES = {
    "core": "maths", "core/kernels": "maths", "geo": "maths", "fleet": "maths",
    "tracking": "messages",
    "mavlink": "edges", "logs": "edges", "outputs": "edges", "app": "edges",
}  # fmt: skip
#: The package's own files, and the one module whose job is a file cache: the loader of the
#: compiled kernels, which clears numba's cache when the kernels' sources changed.
EXCEPTIONS = {"__init__.py": "maths", "errors.py": "maths", "__main__.py": "edges",
              "core/compiled.py": "edges"}  # fmt: skip


def role_of(relpath: str) -> str:
    if relpath in EXCEPTIONS:
        return EXCEPTIONS[relpath]
    folder = relpath.rpartition("/")[0]
    assert folder in ROLES, f"{relpath}: its folder {folder!r} has no role (tests/test_lint.py)"
    return ROLES[folder]


def modules() -> dict[str, str]:
    pkg = ROOT / "mav_observer"
    return {p.relative_to(pkg).as_posix(): role_of(p.relative_to(pkg).as_posix())
            for p in pkg.rglob("*.py")}  # fmt: skip


def test_every_module_has_a_role() -> None:
    roles = modules()
    assert {"maths", "messages", "edges"} == set(roles.values())
    assert roles["core/kernels/bank.py"] == "maths"
    assert roles["tracking/tracker.py"] == "messages"


def test_core_does_not_import_the_simulator_or_io() -> None:
    """The maths imports numpy and nothing that does I/O; the MAVLink adapters, clocks and
    tracker decode nothing and touch no socket, file or clock (pymavlink's message classes
    only); nothing in mav_observer imports sim."""
    io = ("import sim", "from sim", "socket", "zenoh", "time", "open(", "subprocess", "os")
    roles = modules()
    pure = {name: (*io, "pymavlink") for name, r in roles.items() if r == "maths"}
    pure |= {name: io for name, r in roles.items() if r == "messages"}
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


def test_no_module_is_over_600_lines() -> None:
    """One job per module: a module past about 600 lines is doing several."""
    sizes = {
        p.relative_to(ROOT).as_posix(): len(p.read_text().splitlines())
        for p in (ROOT / "mav_observer").rglob("*.py")
    }
    long = {name: n for name, n in sizes.items() if n > 600}
    assert not long, long
