"""The live map: a local web page beside the service (``mav-observer run --web HOST:PORT``).

The service hands each estimate it publishes to :class:`MapFeed` (an append to its inbox:
never a wait, whatever the pages do, and nothing computed in the service's thread);
:class:`MapServer` takes them in every BATCH_S and serves, from its own threads:

* ``/``: the page (``web/index.html``, ``web/map.js`` and Leaflet, vendored with its licence:
  nothing is fetched from elsewhere). Offline first: the local frame's metric grid; a tile
  layer only when a tile URL is set (``--web-tiles``) and the origin is known;
* ``/state``: the latest of everything as JSON (each vehicle's origin, position, heading and
  recent track; each target's latest record and its recent estimates);
* ``/events``: server-sent events, one every BATCH_S at most, each a JSON array of the latest
  estimate of each target that had one, ``{"key", "yaw_deg", "sent_ms", "origin", "record"}``
  (``record`` as ``docs/schema.md``); a page too slow to keep up loses the oldest batches
  (it redraws from the latest), counted in ``/state``'s ``dropped``;
* ``/vehicle/N``, ``/target/N/NAME``, ``/fused/NAME``: one vehicle's, target's or fused
  target's part of ``/state`` (404 for one not seen).

Fused targets (``mav-observer fuse``'s records, ``PREFIX/fused/NAME``) come in through
:meth:`MapFeed.add_fused`, as events keyed ``fused/NAME``.

Loopback by default; another address is the user's explicit choice.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections import deque
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Any

from mav_observer.outputs.records import EstimateRecord

log = logging.getLogger(__name__)

#: Points of a vehicle's track and of a target's estimates kept for the page, one per
#: TRACK_STEP_S of the autopilot's clock at most (as the page keeps them: ``web/map.js``).
TRACK_POINTS = 600
TRACK_STEP_S = 1.0
#: Pages served at once (more are refused with 503).
MAX_CLIENTS = 16
#: Batches of events queued for one page (20 s of them); beyond, the oldest go.
QUEUE_LEN = 100
#: The feed takes in the service's estimates and sends the pages a batch this often (s): the
#: rate the page redraws at, at most (5 Hz: a browser beside the service takes little of its CPU).
BATCH_S = 0.2
#: Estimates waiting for the feed's next batch, at most.
INBOX_LEN = 100_000
STATIC = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/map.js": ("map.js", "text/javascript; charset=utf-8"),
    "/leaflet.js": ("leaflet.js", "text/javascript; charset=utf-8"),
    "/leaflet.css": ("leaflet.css", "text/css; charset=utf-8"),
    "/LICENSE-leaflet.txt": ("LICENSE-leaflet.txt", "text/plain; charset=utf-8"),
}


def static_file(name: str) -> bytes:
    """One of the page's files (``mav_observer/outputs/web/``)."""
    return resources.files("mav_observer.outputs").joinpath("web", name).read_bytes()


def _step_due(entry: dict[str, Any], t_boot_s: float) -> bool:
    """Whether a track gains a point at ``t_boot_s``: TRACK_STEP_S after its last one (or its
    clock went back, a reboot), noting the time in ``entry``."""
    last = entry.get("last_t")
    if last is not None and 0.0 <= t_boot_s - last < TRACK_STEP_S:
        return False
    entry["last_t"] = t_boot_s
    return True


class MapFeed:
    """What the page shows, fed by the service: thread-safe. :meth:`add` is an append to an
    inbox, so the service's estimates are not delayed by the page's bookkeeping: that runs in
    :meth:`pump` (every BATCH_S, from :class:`MapServer`'s thread, and before a snapshot)."""

    def __init__(self, max_clients: int = MAX_CLIENTS, queue_len: int = QUEUE_LEN) -> None:
        self._lock = threading.Lock()
        # (the bound only matters should the pump stall: the oldest updates go first)
        # each entry the method that takes it in, then its arguments
        self._inbox: deque[tuple[Any, ...]] = deque(maxlen=INBOX_LEN)
        self._take_record = self._take  # (bound once: ``add`` is the service's hot path)
        self._vehicles: dict[int, dict[str, Any]] = {}
        self._targets: dict[str, dict[str, Any]] = {}
        self._fused: dict[str, dict[str, Any]] = {}
        self._clients: list[queue.Queue[bytes]] = []
        self.max_clients = max_clients
        self.queue_len = queue_len
        #: batches a page was too slow to take (the oldest go)
        self.dropped = 0
        #: estimates taken in
        self.events = 0
        #: published texts that were not estimate records (``add_published``)
        self.bad = 0

    def add(
        self,
        rec: EstimateRecord,
        yaw_rad: float | None = None,
        origin: dict[str, Any] | None = None,
        rec_json: str | None = None,
    ) -> None:
        """An estimate the service published (``rec_json``: its JSON, when already made), the
        vehicle's heading at its time, its origin. An append: never a wait, nothing computed."""
        self._inbox.append((self._take_record, rec, yaw_rad, origin, rec_json, time.time()))

    def add_published(self, text: str) -> None:
        """An estimate record as a service published it (its JSON, ``docs/schema.md``:
        ``mav-observer map``); one that is not such a record is counted in :attr:`bad`."""
        self._inbox.append((self._take_published, text, time.time()))

    def add_fused(self, text: str) -> None:
        """A fused target's record as ``mav-observer fuse`` published it (``docs/schema.md``);
        one that is not such a record is counted in :attr:`bad`."""
        self._inbox.append((self._take_fused, text, time.time()))

    def add_status(self, text: str) -> None:
        """A vehicle's status as a service published it (``docs/schema.md``): its origin, for
        ``mav-observer map`` (whose estimate records carry none); one that is not a status is
        counted in :attr:`bad`."""
        self._inbox.append((self._take_status, text, time.time()))

    def pump(self) -> None:
        """Take in what was added: the state, and to each page one batch of events, the
        latest estimate of each target that had one."""
        with self._lock:
            latest: dict[str, tuple[float | None, float, str, str]] = {}
            inbox = self._inbox
            while inbox:
                item = inbox.popleft()
                taken = item[0](*item[1:])
                if taken is not None:
                    latest[taken[0]] = taken[1:]
            clients = list(self._clients)
        if not clients or not latest:
            return
        events = ",".join(
            f'{{"key":{json.dumps(key)},"yaw_deg":{"null" if yaw is None else repr(yaw)},'
            f'"sent_ms":{sent_ms!r},"origin":{origin_json},"record":{text}}}'
            for key, (yaw, sent_ms, origin_json, text) in latest.items()
        )
        batch = b"data: [" + events.encode() + b"]\n\n"
        for q in clients:
            _put_dropping_oldest(q, batch, self)

    def _take(
        self,
        rec: EstimateRecord,
        yaw_rad: float | None,
        origin: dict[str, Any] | None,
        text: str | None,
        sent_s: float,
    ) -> tuple[str, float | None, float, str, str]:
        """One estimate the service added into the state (under the lock): ``(key, yaw_deg,
        sent_ms, origin JSON, record JSON)``."""
        yaw = None if yaw_rad is None or not math.isfinite(yaw_rad) else math.degrees(yaw_rad)
        return self._take_parts(rec.sysid, rec.target, rec.t_boot_s, rec.vehicle_pos_ned_m,
                                rec.target_pos_ned_m, str(rec.estimate.status), yaw, origin,
                                rec.to_json() if text is None else text, sent_s)  # fmt: skip

    def _take_published(
        self, text: str, sent_s: float
    ) -> tuple[str, float | None, float, str, str] | None:
        """A published estimate record into the state, as :meth:`_take`; ``None`` for a text
        that is not one (its numbers checked here: nothing after this may raise)."""
        try:
            d = json.loads(text)
            sysid, target = int(d["sysid"]), str(d["target"])
            t_boot_s, status = float(d["t_boot_s"]), str(d["status"])
            vp, tp = _vector(d.get("vehicle_pos_ned_m")), _vector(d.get("target_pos_ned_m"))
        except (ValueError, KeyError, TypeError) as exc:
            self._refuse("estimate record", text, exc)
            return None
        return self._take_parts(sysid, target, t_boot_s, vp, tp, status, None, None, text, sent_s)

    def _take_parts(
        self,
        sysid: int,
        target: str,
        t_boot_s: float,
        vp: Any,
        tp: Any,
        status: str,
        yaw: float | None,
        origin: dict[str, Any] | None,
        text: str,
        sent_s: float,
    ) -> tuple[str, float | None, float, str, str]:
        """An estimate's parts, checked, into the state: as :meth:`_take`."""
        key = f"{sysid}/{target}"
        veh = self._vehicle(sysid, origin)
        if vp is not None:
            veh["pos_ned_m"] = [float(v) for v in vp]
            veh["yaw_deg"] = yaw
            veh["t_boot_s"] = t_boot_s
            if _step_due(veh, t_boot_s):
                veh["track"].append([float(vp[0]), float(vp[1])])
        tgt = self._targets.get(key)
        if tgt is None:
            tgt = self._targets[key] = {"history": deque(maxlen=TRACK_POINTS)}
        tgt["record_json"] = text
        if tp is not None and _step_due(tgt, t_boot_s):
            tgt["history"].append([float(tp[0]), float(tp[1]), status])
        self.events += 1
        return key, yaw, sent_s * 1000.0, veh.get("origin_json", "null"), text

    def _refuse(self, what: str, text: str | None, exc: Exception) -> None:
        """A published text that is not a ``what``: counted in :attr:`bad`, logged (a warning
        the first time, then at debug level: a stream of them must not flood the log)."""
        self.bad += 1
        level = logging.WARNING if self.bad == 1 else logging.DEBUG
        log.log(level, "live map: not a %s (%s: %s), left out: %.80r", what,
                type(exc).__name__, exc, text)  # fmt: skip

    def _vehicle(self, sysid: int, origin: dict[str, Any] | None) -> dict[str, Any]:
        """Vehicle ``sysid``'s part of the state (made on its first data), its origin noted."""
        veh = self._vehicles.get(sysid)
        if veh is None:
            veh = self._vehicles[sysid] = {"track": deque(maxlen=TRACK_POINTS)}
        if origin is not None and veh.get("origin") is not origin and veh.get("origin") != origin:
            veh["origin"] = origin
            veh["origin_json"] = json.dumps(origin)
        return veh

    def _take_status(self, text: str, sent_s: float) -> None:
        """A vehicle's status into the state (under the lock): its origin, when known."""
        try:
            d = json.loads(text)
            sysid, origin = int(d["sysid"]), d.get("origin")
            if origin is not None:
                _vector([origin["lat_deg"], origin["lon_deg"]])
        except (ValueError, KeyError, TypeError) as exc:
            self._refuse("status", text, exc)
            return
        self._vehicle(sysid, origin)

    def _take_fused(self, text: str, sent_s: float) -> tuple[str, None, float, str, str] | None:
        """A fused target's record into the state (under the lock), as :meth:`_take`."""
        try:
            d = json.loads(text)
            name, t_unix_s = str(d["target"]), float(d["t_unix_s"])
            lat, lon, status = d.get("lat_deg"), d.get("lon_deg"), str(d["status"])
            if lat is not None and lon is not None:
                lat, lon = _vector([lat, lon])
        except (ValueError, KeyError, TypeError) as exc:
            self._refuse("fused target", text, exc)
            return None
        if "NaN" in text or "Infinity" in text:  # the page's JSON.parse takes no NaN
            text = json.dumps(_no_nan(d))
        entry = self._fused.get(name)
        if entry is None:
            entry = self._fused[name] = {"history": deque(maxlen=TRACK_POINTS)}
        entry["record_json"] = text
        if lat is not None and lon is not None and _step_due(entry, t_unix_s):
            entry["history"].append([lat, lon, status])
        self.events += 1
        return f"fused/{name}", None, sent_s * 1000.0, "null", text

    def snapshot(self) -> dict[str, Any]:
        self.pump()
        with self._lock:
            return {
                "vehicles": {
                    str(s): {
                        **{k: x for k, x in v.items() if k != "origin_json"},
                        "track": list(v["track"]),
                    }
                    for s, v in self._vehicles.items()
                },
                "targets": {
                    k: {"record": json.loads(t["record_json"]), "history": list(t["history"])}
                    for k, t in self._targets.items()
                },
                "fused": {
                    k: {"record": json.loads(f["record_json"]), "history": list(f["history"])}
                    for k, f in self._fused.items()
                },
                "events": self.events,
                "dropped": self.dropped,
                "bad": self.bad,
                "clients": len(self._clients),
            }

    def subscribe(self) -> queue.Queue[bytes] | None:
        """A new page's queue of event batches, ``None`` when :attr:`max_clients` are served."""
        with self._lock:
            if len(self._clients) >= self.max_clients:
                return None
            q: queue.Queue[bytes] = queue.Queue(maxsize=self.queue_len)
            self._clients.append(q)
            return q

    def unsubscribe(self, q: queue.Queue[bytes]) -> None:
        with self._lock:
            if q in self._clients:
                self._clients.remove(q)


def _vector(v: Any) -> list[float] | None:
    """A published vector's numbers (north and east first), or ``None``; ``ValueError`` or
    ``TypeError`` for one that is not a list of numbers."""
    if v is None:
        return None
    if not isinstance(v, list) or len(v) < 2:
        raise TypeError(f"{v!r} is not a list of at least a north and an east")
    return [float(x) for x in v]


def _no_nan(v: Any) -> Any:
    """``v`` with every non-finite number ``None`` (JSON's null)."""
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _no_nan(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_no_nan(x) for x in v]
    return v


def _finite(v: Any) -> Any:
    raise TypeError(f"not JSON: {v!r}")


def _put_dropping_oldest(q: queue.Queue[bytes], batch: bytes, feed: MapFeed) -> None:
    while True:
        try:
            q.put_nowait(batch)
            return
        except queue.Full:
            try:
                q.get_nowait()
                feed.dropped += 1
            except queue.Empty:
                pass


class _Handler(BaseHTTPRequestHandler):
    server: _Server

    def log_message(self, format: str, *args: Any) -> None:
        log.debug("web: " + format, *args)

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, obj: Any, code: int = 200) -> None:
        self._send(code, json.dumps(obj, default=_finite).encode(), "application/json")

    def do_GET(self) -> None:
        path = self.path.split("?", 1)[0]
        feed = self.server.feed
        if path in STATIC:
            name, ctype = STATIC[path]
            body = static_file(name)
            if path == "/":
                config = json.dumps({"tiles": self.server.tiles})
                body = body.replace(b"/*CONFIG*/{}", config.encode())
            self._send(200, body, ctype)
        elif path == "/state":
            self._json(feed.snapshot())
        elif path == "/events":
            self._events(feed)
        elif path.startswith("/vehicle/"):
            snap = feed.snapshot()["vehicles"].get(path[len("/vehicle/") :])
            self._json(snap if snap is not None else {"error": "no such vehicle"},
                       200 if snap is not None else 404)  # fmt: skip
        elif path.startswith("/target/"):
            key = path[len("/target/") :]
            snap = feed.snapshot()["targets"].get(key)
            self._json(snap if snap is not None else {"error": "no such target"},
                       200 if snap is not None else 404)  # fmt: skip
        elif path.startswith("/fused/"):
            snap = feed.snapshot()["fused"].get(path[len("/fused/") :])
            self._json(snap if snap is not None else {"error": "no such fused target"},
                       200 if snap is not None else 404)  # fmt: skip
        else:
            self._json({"error": f"no page {path}"}, 404)

    def _events(self, feed: MapFeed) -> None:
        q = feed.subscribe()
        if q is None:
            self._json({"error": "too many pages open"}, 503)
            return
        try:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(b": connected\n\n")
            self.wfile.flush()
            while not self.server.closing.is_set():
                try:
                    batches = [q.get(timeout=0.5)]
                except queue.Empty:
                    self.wfile.write(b": keep-alive\n\n")
                    self.wfile.flush()
                    continue
                while True:  # a page that fell behind catches up in one write
                    try:
                        batches.append(q.get_nowait())
                    except queue.Empty:
                        break
                self.wfile.write(b"".join(batches))
                self.wfile.flush()
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            pass  # the page went away
        finally:
            feed.unsubscribe(q)


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    feed: MapFeed
    tiles: str | None
    closing: threading.Event


class MapServer:
    """The page's HTTP server on ``host:port`` (0: any free port), in its own threads."""

    def __init__(
        self, feed: MapFeed, host: str = "127.0.0.1", port: int = 0, tiles: str | None = None
    ) -> None:
        self.feed = feed
        self._httpd = _Server((host, port), _Handler)
        self._httpd.feed = feed
        self._httpd.tiles = tiles
        self._httpd.closing = threading.Event()
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True
        )
        self._pump = threading.Thread(target=self._pump_loop, name="map-feed", daemon=True)

    @property
    def url(self) -> str:
        host, port = self._httpd.server_address[:2]
        return f"http://{host}:{port}/"

    def _pump_loop(self) -> None:
        closing = self._httpd.closing
        while not closing.wait(BATCH_S):
            try:
                self.feed.pump()
            except Exception:  # a bug in the page's bookkeeping must not end the feed
                log.exception("live map: a batch failed")

    def start(self) -> MapServer:
        self._thread.start()
        self._pump.start()
        log.info("live map on %s", self.url)
        return self

    def close(self) -> None:
        self._httpd.closing.set()
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=2.0)
        self._pump.join(timeout=2.0)
