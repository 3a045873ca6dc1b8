"""Zenoh at the edge: the session's configuration and the service's publications.

Configuration (:func:`session_config`): the embedded default is a peer listening on
``tcp/127.0.0.1:7447`` only, connecting nowhere, with multicast scouting off, so it needs no
router and opens nothing beyond loopback. A standard Zenoh JSON5 file (TLS, authentication,
any mode) replaces it; what the file leaves unset still gets the safe defaults (listen on
loopback, no multicast scouting), and the shortcuts (mode, listen, connect) override it.

Publications (:class:`Publications`), under a prefix (default ``mav_observer``), documented in
``docs/schema.md``:

* ``{prefix}/{sysid}/{target}/estimate``: estimate records (JSON);
* ``{prefix}/{sysid}/{target}/ray``: each bearing used, as a geodetic ray (JSON,
  ``docs/fleet.md``);
* ``{prefix}/{sysid}/status``: the vehicle's status (JSON);
* ``{prefix}/{sysid}/alive``: a liveliness token while the service runs;
* a queryable on ``{prefix}/{sysid}/**`` answering with the latest estimate(s) and status.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import zenoh

from mav_observer.errors import ConfigError

log = logging.getLogger(__name__)

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
JSON = zenoh.Encoding.APPLICATION_JSON
#: How a peer retries its connect endpoints (Zenoh's default starts at 1 s and grows to 4 s):
#: a subscriber finds a restarted service, or the service a restarted router, within 0.1-2 s.
CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 2000, "period_increase_factor": 2}


def session_config(
    *,
    config_file: str | None = None,
    mode: str | None = None,
    listen: Sequence[str] | None = None,
    connect: Sequence[str] | None = None,
    default_listen: Sequence[str] = (DEFAULT_ENDPOINT,),
) -> zenoh.Config:
    """The Zenoh configuration of one session.

    Without ``config_file``: ``mode`` (default peer), listening on ``listen`` (default
    ``default_listen``; nothing for a client), connecting to ``connect`` (default none),
    multicast scouting off, connect endpoints retried from every 0.1 s up to every 2 s
    (:data:`CONNECT_RETRY`). With ``config_file`` (JSON5): the file, with the same defaults
    for what it leaves unset, and ``mode``/``listen``/``connect`` overriding it when given.
    Raises :class:`ConfigError` naming the file or the value Zenoh refused.
    """
    if config_file is not None:
        try:
            conf = zenoh.Config.from_file(config_file)
        except zenoh.ZError as exc:
            raise ConfigError(f"zenoh.config_file {config_file}: {exc}") from None
    else:
        conf = zenoh.Config()
    eff_mode = mode or json.loads(conf.get_json("mode") or "null") or "peer"
    _insert(conf, "mode", eff_mode)
    if listen is None:
        current = json.loads(conf.get_json("listen/endpoints"))
        if isinstance(current, dict):  # unset: Zenoh's per-mode default, all interfaces
            listen = [] if eff_mode == "client" else list(default_listen)
    if listen is not None:
        _insert(conf, "listen/endpoints", list(listen))
    if connect is not None:
        _insert(conf, "connect/endpoints", list(connect))
    if json.loads(conf.get_json("scouting/multicast/enabled") or "null") is None:
        _insert(conf, "scouting/multicast/enabled", False)
    if json.loads(conf.get_json("connect/retry") or "null") is None:
        _insert(conf, "connect/retry", CONNECT_RETRY)
    return conf


def _insert(conf: zenoh.Config, key: str, value: object) -> None:
    try:
        conf.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise ConfigError(f"zenoh {key}={value!r}: {exc}") from None


def open_session(conf: zenoh.Config, *, retry_s: float = 0.0) -> zenoh.Session:
    """Open the session; a refusal (a client with no reachable router, a port in use) is a
    :class:`ConfigError` saying which endpoints were tried. ``retry_s``: keep trying for
    this long first (a client started before its router; Zenoh clients do not wait)."""
    end = time.monotonic() + retry_s
    delay = 0.05
    while True:
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            if time.monotonic() + delay < end:
                time.sleep(delay)
                delay = min(1.0, 2 * delay)
                continue
            error = exc
            break
    raise ConfigError(
        f"cannot open the Zenoh session (mode {conf.get_json('mode')}, listen "
        f"{conf.get_json('listen/endpoints')}, connect {conf.get_json('connect/endpoints')})"
        f": {error}"
    ) from None


class Publications:
    """The service's keys on one session (see the module docstring).

    Thread-safety: :meth:`estimate`, :meth:`status` and :meth:`vehicle` are called from the
    service's loop; the queryable answers from Zenoh's threads, reading the latest payloads
    under a lock.
    """

    def __init__(
        self,
        session: zenoh.Session,
        prefix: str = "mav_observer",
        *,
        congestion_control: str = "drop",
    ) -> None:
        self.session = session
        self.prefix = prefix
        self._cc = (
            zenoh.CongestionControl.BLOCK
            if congestion_control == "block"
            else zenoh.CongestionControl.DROP
        )
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._vehicles: dict[int, tuple[Any, Any]] = {}  # sysid -> (token, queryable)
        self._latest: dict[str, str] = {}
        self._lock = threading.Lock()
        #: a subscriber wants the rays (:meth:`watch_rays`; read by the service's thread)
        self.rays_listened = False
        self._ray_probe: Any = None
        self._ray_listener: Any = None

    # -- keys ---------------------------------------------------------------------------
    def estimate_key(self, sysid: int, target: str) -> str:
        return f"{self.prefix}/{sysid}/{target}/estimate"

    def status_key(self, sysid: int) -> str:
        return f"{self.prefix}/{sysid}/status"

    def ray_key(self, sysid: int, target: str) -> str:
        return f"{self.prefix}/{sysid}/{target}/ray"

    def alive_key(self, sysid: int) -> str:
        return f"{self.prefix}/{sysid}/alive"

    # -- publishing ---------------------------------------------------------------------
    def vehicle(self, sysid: int) -> None:
        """Declare the vehicle's liveliness token and queryable (once)."""
        if sysid in self._vehicles:
            return
        token = self.session.liveliness().declare_token(self.alive_key(sysid))
        queryable = self.session.declare_queryable(f"{self.prefix}/{sysid}/**", self._on_query)
        self._vehicles[sysid] = (token, queryable)

    def _put(self, key: str, payload: str, *, keep: bool = True) -> None:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.session.declare_publisher(
                key, encoding=JSON, congestion_control=self._cc
            )
        if keep:
            with self._lock:
                self._latest[key] = payload
        pub.put(payload)

    def watch_rays(self) -> None:
        """Keep :attr:`rays_listened` true while some subscriber (a ``fuse`` node, a listener)
        matches ``{prefix}/*/*/ray``: a ray nobody receives is not worth making (it costs
        about as much as the estimate it comes with)."""
        self._ray_probe = self.session.declare_publisher(f"{self.prefix}/*/*/ray")
        self.rays_listened = bool(self._ray_probe.matching_status.matching)

        def on_matching(status: Any) -> None:
            self.rays_listened = bool(status.matching)

        self._ray_listener = self._ray_probe.declare_matching_listener(on_matching)

    def ray(self, sysid: int, target: str, payload: str) -> None:
        """A bearing as a geodetic ray (not kept for queries: a stream, not a state)."""
        self._put(self.ray_key(sysid, target), payload, keep=False)

    def estimate(self, sysid: int, target: str, payload: str) -> None:
        self._put(self.estimate_key(sysid, target), payload)

    def status(self, sysid: int, payload: str) -> None:
        self._put(self.status_key(sysid), payload)

    def latest(self) -> Mapping[str, str]:
        with self._lock:
            return dict(self._latest)

    def _on_query(self, query: zenoh.Query) -> None:
        asked = query.key_expr
        for key, payload in self.latest().items():
            if asked.intersects(zenoh.KeyExpr(key)):
                query.reply(key, payload, encoding=JSON)

    def close(self) -> None:
        """Undeclare everything (the liveliness tokens disappear)."""
        for decl in (self._ray_listener, self._ray_probe):
            if decl is not None:
                decl.undeclare()
        self._ray_listener = self._ray_probe = None
        for token, queryable in self._vehicles.values():
            token.undeclare()
            queryable.undeclare()
        self._vehicles.clear()
        for pub in self._publishers.values():
            pub.undeclare()
        self._publishers.clear()


__all__ = ["DEFAULT_ENDPOINT", "Publications", "open_session", "session_config"]
