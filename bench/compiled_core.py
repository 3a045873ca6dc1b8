"""What compiling the pure core would give: this checkout against a copy of it whose estimator
core is compiled with mypyc, the same source.

Run: ``python bench/compiled_core.py`` (about three minutes). Needs mypy, which carries mypyc
(``pip install mypy``; not a dependency of the project), and a C compiler. It is a measurement
for a decision (issue 13: the per-bearing goals need the work about halved), not a way of
installing the project.

What it does:

1. copies the checkout's tracked files to a temporary directory and compiles :data:`MODULES`
   there in place with mypyc. The source is this checkout's with the edits in :data:`EDITS`
   only, each checked to apply: two ``copy`` methods that make an object without running its
   ``__init__`` (a compiled class has no ``__dict__``);
2. runs ``bench/observer_update.py --json`` in each tree, alternating, ``--repeat`` times, and
   reports the medians: the default estimator's converged step and acquisition step and the
   paper's observer's, each also as a ratio against the 3x3 inverse timed in that run;
3. replays each shared tlog (and the emitter's figure-8 of ``bench/replay_throughput.py``, if
   it was generated) as a whole process, ``mav-observer replay LOG -o out.jsonl``, in each
   tree, alternating, best of ``--repeat``; and compares the two trees' records byte for byte.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sim.tlogs import find_tlogs  # noqa: E402

#: The modules compiled: the per-sample path of the default estimator and the observer.
MODULES = (
    "mav_observer/single.py",
    "mav_observer/observer.py",
    "mav_observer/streams.py",
    "mav_observer/monitor.py",
    "mav_observer/estimators/riccati.py",
)
#: (file, text, replacement): what a compiled class needs that the source does not do.
EDITS = (
    (
        "mav_observer/single.py",
        """        other = object.__new__(Single)
        d = other.__dict__
        d.update(self.__dict__)
        d["x"], d["a"], d["p"], d["logw"] = self.x[:], self.a[:], self.p[:], self.logw[:]
        d["walk_ll"], d["walk_x"] = self.walk_ll[:], self.walk_x[:]
        d["walk_a"], d["walk_p"] = self.walk_a[:], self.walk_p[:]
""",
        """        other = Single(self.x[:], self.a[:], self.p[:], self.logw[:], self.r0, self.xp,
            self.ap, self.pp, self.nis_avg, self.age_s, self.reseeds, self.noise_alpha,
            self.noise_beta, self.outliers, self.bearings, self.inlier_avg, self.walk_q,
            self.walk_on, self.walk_ll[:], self.walk_x[:], self.walk_a[:], self.walk_p[:])
""",
    ),
    (
        "mav_observer/estimators/riccati.py",
        "\nclass RiccatiEstimator:",
        "\nfrom mypy_extensions import mypyc_attr\n\n\n"
        "@mypyc_attr(native_class=False)\nclass RiccatiEstimator:",
    ),
)
FIG8 = ROOT / "bench" / ".cache" / "figure8_25hz_240s.tlog"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as bench/replay_throughput.py
    return env


def build(tmp: Path) -> Path:
    """The compiled copy of the checkout under ``tmp``."""
    tree = tmp / "compiled"
    files = subprocess.run(
        ["git", "ls-files"], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout.split()
    for f in files:
        if f.startswith(("mav_observer/", "sim/", "bench/")) and (ROOT / f).is_file():
            (tree / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / f, tree / f)
    for name, old, new in EDITS:
        path = tree / name
        text = path.read_text()
        if old not in text:
            raise SystemExit(f"{name}: the text to edit for mypyc is not there any more")
        path.write_text(text.replace(old, new, 1))
    mypyc = shutil.which("mypyc", path=str(Path(sys.executable).parent)) or shutil.which("mypyc")
    if mypyc is None:
        raise SystemExit("mypyc not found: pip install mypy (it carries mypyc)")
    print(f"compiling {len(MODULES)} modules with mypyc ...", flush=True)
    t0 = time.perf_counter()
    done = subprocess.run(
        [mypyc, *MODULES], cwd=tree, env=_env(), capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"mypyc failed:\n{done.stdout[-3000:]}{done.stderr[-3000:]}")
    built = sorted(p.name for p in (tree / "mav_observer").rglob("*.so"))
    print(f"compiled in {time.perf_counter() - t0:.0f} s: {', '.join(built)}")
    return tree


def observer_figures(trees: dict[str, Path], repeat: int) -> dict[str, dict[str, float]]:
    keys = (
        "default.step_us", "default.step_ratio_interleaved", "default.acquisition_step_us",
        "paper02.step_us", "paper02.step_ratio_interleaved", "filter_arithmetic_us",
    )  # fmt: skip
    runs: dict[str, list[dict[str, float]]] = {k: [] for k in trees}
    for _ in range(repeat):
        for label, tree in trees.items():
            out = subprocess.run(
                [sys.executable, str(tree / "bench" / "observer_update.py"), "--json"],
                cwd=tree, env=_env(), check=True, capture_output=True, text=True,
            ).stdout  # fmt: skip
            r = json.loads(out)
            flat = {}
            for key in keys:
                head, _, tail = key.partition(".")
                flat[key] = r[head][tail] if tail else r[head]
            runs[label].append(flat)
    return {
        label: {k: statistics.median(r[k] for r in rs) for k in keys} for label, rs in runs.items()
    }


def replay_once(tree: Path, log: Path, out: Path) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "mav_observer", "replay", str(log), "-o", str(out)],
        cwd=tree, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, check=False,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    if done.returncode not in (0, 3):
        raise SystemExit(f"replay of {log.name} in {tree} exited {done.returncode}")
    return wall


def replays(trees: dict[str, Path], logs: list[Path], repeat: int, tmp: Path) -> list[dict]:
    rows = []
    for log in logs:
        walls: dict[str, list[float]] = {k: [] for k in trees}
        digests = {}
        for label, tree in trees.items():  # one untimed run each: the records compared
            out = tmp / f"{label}.jsonl"
            replay_once(tree, log, out)
            digests[label] = hashlib.sha256(out.read_bytes()).hexdigest() if out.exists() else ""
        for _ in range(repeat):
            for label, tree in trees.items():
                walls[label].append(replay_once(tree, log, tmp / "timed.jsonl"))
        rows.append(
            {
                "file": log.name,
                **{f"{k}_s": min(v) for k, v in walls.items()},
                "same_records": len(set(digests.values())) == 1,
            }
        )
    return rows


def _positive(text: str) -> int:
    n = int(text)
    if n < 1:
        raise argparse.ArgumentTypeError(f"--repeat {n}: must be at least 1")
    return n


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=_positive, default=3, help="alternating runs (>= 1)")
    parser.add_argument("--json", type=Path, help="also write the results as JSON")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        trees = {"python": ROOT, "compiled": build(tmp)}
        obs = observer_figures(trees, args.repeat)
        print(f"\nbench/observer_update.py, median of {args.repeat} alternating runs")
        print(f"{'':38s} {'python':>9s} {'compiled':>9s} {'ratio':>6s}")
        for key in obs["python"]:
            p, c = obs["python"][key], obs["compiled"][key]
            print(f"{key:38s} {p:9.2f} {c:9.2f} {p / c:6.2f}")
        logs = sorted(find_tlogs().glob("*.tlog"))
        if FIG8.exists():
            logs.append(FIG8)
        rows = replays(trees, logs, args.repeat, tmp)
        print(f"\nmav-observer replay LOG -o out.jsonl, whole processes, best of {args.repeat}")
        print(f"{'file':40s} {'python_s':>8s} {'compiled_s':>10s} {'ratio':>6s}  records")
        for r in rows:
            same = "the same" if r["same_records"] else "DIFFER"
            ratio = r["python_s"] / r["compiled_s"]
            print(
                f"{r['file']:40s} {r['python_s']:8.3f} {r['compiled_s']:10.3f} {ratio:6.2f}  {same}"
            )
        if args.json:
            args.json.write_text(json.dumps({"observer": obs, "replay": rows}, indent=1))
        return 0 if all(r["same_records"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
