"""Loading the compiled estimator (numba): imported on first use, compiled once per machine.

numba compiles the kernels (``mav_observer/core/kernels/``) the first time they run on a
machine and caches the machine code (``cache=True``: in the package's ``__pycache__``, or
the user's cache directory when that is read-only); later runs load it in a fraction of a
second. The first run prints one line to stderr saying so and how long it took.

numba checks a cached function against its own file only; the kernels share the layout's
constants, so a stamp of all the kernels' sources clears the cache when any changed (a
developer's edit; an installed package never changes): :func:`clear_stale_cache`.
"""

from __future__ import annotations

import hashlib
import os
import sys
import threading
import time
from pathlib import Path
from types import ModuleType

# LLVM's optimisation level for the kernels (numba reads it at each compile): at 1 they
# compile faster than at numba's default 3 and run as fast (docs/performance.md); a
# NUMBA_OPT set by the user wins. Code that compiles the kernels imports this module first.
os.environ.setdefault("NUMBA_OPT", "1")

_KERNELS_DIR = Path(__file__).resolve().parent / "kernels"
#: Seconds before the first-run line is printed where a cache seemed to be there (it
#: loads well within that; a stale one is compiled again).
_NOTICE_AFTER_S = 2.0
#: the loaded kernels module, once loaded
_loaded: dict[str, ModuleType] = {}
_lock = threading.Lock()


def kernels_digest() -> str:
    """A digest of every kernel module's source."""
    sources = sorted(_KERNELS_DIR.glob("*.py"))
    return hashlib.sha256(b"".join(p.read_bytes() for p in sources)).hexdigest()


def clear_stale_cache(module_file: str | Path, *, whole_folder: bool = False) -> None:
    """Clear numba's cached machine code of the module ``module_file`` (or of every module
    of its folder) when the kernels' sources changed since it was cached: numba checks a
    cached function against its own file only, and code that calls the kernels compiles
    them in. For the kernels themselves and for compiled code elsewhere that calls them
    (the Monte Carlo harness, the tests' shims)."""
    path = Path(module_file).resolve()
    cache = path.parent / "__pycache__"
    pattern = "*" if whole_folder else f"{path.stem}.*"
    stamp = cache / f"{'kernels' if whole_folder else path.stem}.stamp"
    digest = kernels_digest()
    try:
        if stamp.is_file() and stamp.read_text() == digest:
            return
        cache.mkdir(exist_ok=True)
        for f in [*cache.glob(f"{pattern}.nbi"), *cache.glob(f"{pattern}.nbc")]:
            f.unlink()
        stamp.write_text(digest)
    except OSError:
        pass  # a read-only package: numba uses the user's cache, and the sources never change


def _cold(dispatcher: object) -> bool:
    """Whether numba has no cached machine code of ``dispatcher`` (an ``@njit(cache=True)``
    function) to load: it will compile."""
    try:
        index = dispatcher._cache._cache_file._index_path  # type: ignore[attr-defined]
    except AttributeError:
        return False  # (another numba: the timer tells)
    return not Path(index).is_file()


def kernels() -> ModuleType:
    """The observer's compiled entry points (:mod:`mav_observer.core.kernels.observer`),
    loaded and ready (compiled on a machine's first run)."""
    module = _loaded.get("kernels")
    if module is not None:
        return module
    with _lock:
        if "kernels" not in _loaded:
            clear_stale_cache(_KERNELS_DIR / "observer.py", whole_folder=True)
            t0 = time.perf_counter()
            noticed = threading.Event()
            printing = threading.Lock()

            def notice() -> None:
                with printing:
                    noticed.set()
                    print(
                        "mav-observer: compiling the estimator for this machine (once, cached) ...",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )

            from mav_observer.core import warmup
            from mav_observer.core.kernels import observer

            timer = threading.Timer(0.0 if _cold(observer.run) else _NOTICE_AFTER_S, notice)
            timer.daemon = True
            timer.start()

            module = warmup.warm()
            timer.cancel()
            with printing:
                if noticed.is_set():
                    print(f" {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
            _loaded["kernels"] = module
    return _loaded["kernels"]
