"""The service's state file: the observers, saved so that a restart keeps what they learnt.

A JSON document (schema 1)::

    {"schema": 1, "kind": "mav-observer state", "saved_unix_s": 1767225600.0,
     "observers": [{"sysid": 1, "target": "gimbal", "source": "...", "vehicle": {...},
                    "observer": {...}}, ...]}

``observers`` is :meth:`Tracker.export_state <mav_observer.tracking.tracker.Tracker.export_state>`.
It is written atomically (a temporary file in the same folder, flushed, then renamed over the
old one), so a crash or a power cut leaves the previous file or the new one, never half of one.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

from mav_observer.errors import StateError

SCHEMA = 2  # 2: each buffered bearing carries its measured range
KIND = "mav-observer state"


def save(path: Path, observers: list[dict[str, Any]], *, saved_unix_s: float) -> None:
    """Write the state file atomically; raises ``OSError`` (disk full, no permission)."""
    doc = {"schema": SCHEMA, "kind": KIND, "saved_unix_s": saved_unix_s, "observers": observers}
    text = json.dumps(doc, separators=(",", ":"))
    folder = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def load(path: Path) -> tuple[float, list[dict[str, Any]]]:
    """Read a state file: ``(saved_unix_s, observers)``. The entries are checked when the
    tracker takes them (:meth:`Tracker.restore`); here the document's frame. Raises
    :class:`StateError` naming the bad key, ``FileNotFoundError`` if there is no file."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise StateError(f"{path}: not a state file (not UTF-8 text: {exc.reason})") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StateError(f"{path}: not a state file (not JSON: {exc})") from None
    if not isinstance(doc, dict) or doc.get("kind") != KIND:
        raise StateError(f"{path}: not a mav-observer state file (no kind {KIND!r})")
    if doc.get("schema") != SCHEMA:
        raise StateError(f"{path}: schema {doc.get('schema')!r}, this version reads {SCHEMA}")
    saved = doc.get("saved_unix_s")
    if isinstance(saved, bool) or not isinstance(saved, (int, float)) or not math.isfinite(saved):
        raise StateError(f"{path}: saved_unix_s must be a finite number, got {saved!r}")
    observers = doc.get("observers")
    if not isinstance(observers, list):
        raise StateError(f"{path}: observers must be a list, got {type(observers).__name__}")
    return float(saved), observers


__all__ = ["KIND", "SCHEMA", "load", "save"]
