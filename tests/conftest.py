"""Shared fixtures: a pair of Zenoh sessions on 127.0.0.1 (multicast scouting off)."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from mav_observer.outputs.zenoh_io import open_session, session_config


def free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def http_json(url: str) -> Any:
    """The JSON at ``url`` (a page on 127.0.0.1), ``None`` while nothing answers there."""
    import json
    import urllib.request

    try:
        with urllib.request.urlopen(url, timeout=2) as r:
            return json.loads(r.read())
    except OSError:
        return None


def wait_for(cond: Callable[[], object], timeout_s: float = 3.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture
def pair() -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    """A listening peer and a peer connected to it."""
    port = free_tcp_port()
    server = open_session(session_config(listen=[f"tcp/127.0.0.1:{port}"]))
    client = open_session(session_config(listen=[], connect=[f"tcp/127.0.0.1:{port}"]))
    wait_for(lambda: list(client.info.peers_zid()), 5.0)
    yield server, client
    client.close()
    server.close()


@pytest.fixture(scope="session")
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One emitted gimbal flight as a tlog and its DataFlash and ULog twins."""
    from flightlogs import make_flight

    return make_flight(tmp_path_factory.mktemp("flight"))
