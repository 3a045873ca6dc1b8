"""Checks of setting values: each returns the clean value or raises ValueError with the
reason (:mod:`~mav_observer.app.settings` names the key)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from mav_observer.mavlink.sources import URL_PREFIXES


def number(lo: float | None = None, *, lo_open: bool = False, hi: float | None = None):
    def check(v: object) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f"must be a number, got {v!r}")
        f = float(v)
        if not math.isfinite(f):
            raise ValueError(f"must be finite, got {v!r}")
        if lo is not None and (f <= lo if lo_open else f < lo):
            raise ValueError(f"must be {'>' if lo_open else '>='} {lo:g}, got {v!r}")
        if hi is not None and f > hi:
            raise ValueError(f"must be <= {hi:g}, got {v!r}")
        return f

    return check


def number_or_auto(v: object) -> float | str:
    """A noise setting: ``"auto"`` (learnt online) or a number (told)."""
    if v == "auto":
        return "auto"
    if isinstance(v, str):
        try:
            v = float(v)
        except ValueError:
            raise ValueError(f'must be "auto" or a number, got {v!r}') from None
    return number()(v)


def optional(check: Callable[[object], Any]) -> Callable[[object], Any]:
    def opt(v: object) -> Any:
        return None if v is None else check(v)

    return opt


def choice(*options: str):
    def check(v: object) -> str:
        if v not in options:
            raise ValueError(f"must be one of {list(options)}, got {v!r}")
        return str(v)

    return check


def string(v: object) -> str:
    if not isinstance(v, str) or not v:
        raise ValueError(f"must be a non-empty string, got {v!r}")
    return v


def boolean(v: object) -> bool:
    if not isinstance(v, bool):
        raise ValueError(f"must be true or false, got {v!r}")
    return v


def integer(lo: int, hi: int):
    def check(v: object) -> int:
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise ValueError(f"must be an integer in {lo}..{hi}, got {v!r}")
        return v

    return check


def list_of(check: Callable[[object], Any], *, allow_empty: bool = True):
    def check_list(v: object) -> list[Any]:
        if isinstance(v, str) or not isinstance(v, (list, tuple)):
            raise ValueError(f"must be a list, got {v!r}")
        if not v and not allow_empty:
            raise ValueError("must not be empty")
        out = []
        for i, item in enumerate(v):
            try:
                out.append(check(item))
            except ValueError as exc:
                raise ValueError(f"item {i}: {exc}") from None
        return out

    return check_list


def endpoint(v: object) -> str:
    s = string(v)
    if "/" not in s:
        raise ValueError(f"must be a Zenoh endpoint such as 'tcp/127.0.0.1:7447', got {v!r}")
    return s


def mavlink_url(v: object) -> str:
    s = string(v)
    if s.startswith(URL_PREFIXES):
        parts = s.split(":")
        port = parts[-1] if len(parts) >= 3 else ""
        if not port.isdigit() or not 0 < int(port) < 65536 or not parts[1]:
            raise ValueError(
                f"must be PREFIX:HOST:PORT with a port in 1..65535, such as "
                f"'udpin:127.0.0.1:14550', got {v!r}"
            )
    return s


def heartbeat(v: object) -> float | str | None:
    if v == "auto" or v is None:
        return v
    if v is False:
        return None
    return number(0.0, lo_open=True)(v)


def prefix(v: object) -> str:
    s = string(v)
    if any(c in s for c in "*$?#") or s.startswith("/") or s.endswith("/") or "//" in s:
        raise ValueError(f"must be a plain key expression without wildcards, got {v!r}")
    return s
