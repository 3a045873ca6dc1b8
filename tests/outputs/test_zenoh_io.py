"""Zenoh configuration and the service's publications, on two in-process sessions over
127.0.0.1 (multicast scouting off everywhere)."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest
import zenoh
from conftest import free_tcp_port, wait_for

from mav_observer.errors import ConfigError
from mav_observer.outputs.zenoh_io import Publications, open_session, session_config


def get(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


def test_the_embedded_default_is_a_loopback_peer_without_multicast() -> None:
    conf = session_config()
    assert get(conf, "mode") == "peer"
    assert get(conf, "listen/endpoints") == ["tcp/127.0.0.1:7447"]
    assert get(conf, "connect/endpoints") == []
    assert get(conf, "scouting/multicast/enabled") is False
    assert get(conf, "connect/retry")["period_init_ms"] == 100  # type: ignore[index]


def test_a_config_file_is_honoured_and_gaps_get_safe_defaults(tmp_path: Path) -> None:
    f = tmp_path / "z.json5"
    f.write_text('{mode: "router", connect: {endpoints: ["tcp/127.0.0.1:7999"]}}')
    conf = session_config(config_file=str(f))
    assert get(conf, "mode") == "router"
    assert get(conf, "connect/endpoints") == ["tcp/127.0.0.1:7999"]
    assert get(conf, "listen/endpoints") == ["tcp/127.0.0.1:7447"]  # not every interface
    assert get(conf, "scouting/multicast/enabled") is False
    f.write_text('{mode: "peer", scouting: {multicast: {enabled: true}}}')
    assert get(session_config(config_file=str(f)), "scouting/multicast/enabled") is True
    # shortcuts win over the file
    conf = session_config(config_file=str(f), mode="client", connect=["tcp/127.0.0.1:1234"])
    assert get(conf, "mode") == "client" and get(conf, "listen/endpoints") == []


def test_bad_zenoh_configuration_is_a_named_error(tmp_path: Path) -> None:
    f = tmp_path / "z.json5"
    f.write_text('{mode: "peer", bogus: 1}')
    with pytest.raises(ConfigError, match=r"zenoh\.config_file .*z\.json5.*bogus"):
        session_config(config_file=str(f))
    with pytest.raises(ConfigError, match="No such file"):
        session_config(config_file=str(tmp_path / "missing.json5"))
    port = free_tcp_port()
    conf = session_config(mode="client", listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    with pytest.raises(ConfigError, match="cannot open the Zenoh session"):
        open_session(conf)


def test_publications_keys_encoding_queryable_and_liveliness(pair) -> None:
    server, client = pair
    got: list[tuple[str, str, str]] = []
    alive: list[tuple[str, str]] = []
    sub = client.declare_subscriber(
        "mav_observer/**",
        lambda s: got.append((str(s.key_expr), s.payload.to_string(), str(s.encoding))),
    )
    lsub = client.liveliness().declare_subscriber(
        "mav_observer/**", lambda s: alive.append((str(s.key_expr), str(s.kind)))
    )
    pubs = Publications(server, "mav_observer")
    pubs.vehicle(3)
    assert wait_for(lambda: alive == [("mav_observer/3/alive", "SampleKind.PUT")])
    time.sleep(0.2)
    pubs.estimate(3, "gimbal", '{"range_m": 12.5}')
    pubs.status(3, '{"sysid": 3}')
    assert wait_for(lambda: len(got) == 2)
    assert got[0] == ("mav_observer/3/gimbal/estimate", '{"range_m": 12.5}', "application/json")
    assert got[1][0] == "mav_observer/3/status"
    replies = {
        str(r.ok.key_expr): r.ok.payload.to_string()
        for r in client.get("mav_observer/3/**", timeout=2.0)
    }
    assert replies == {
        "mav_observer/3/gimbal/estimate": '{"range_m": 12.5}',
        "mav_observer/3/status": '{"sysid": 3}',
    }
    only = [str(r.ok.key_expr) for r in client.get("mav_observer/3/status", timeout=2.0)]
    assert only == ["mav_observer/3/status"]
    pubs.close()
    assert wait_for(lambda: ("mav_observer/3/alive", "SampleKind.DELETE") in alive)
    sub.undeclare()
    lsub.undeclare()


# -- TLS and user/password authentication, through the standard configuration file --------


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A throw-away certificate authority and a server certificate for 127.0.0.1 (rustls
    refuses a self-signed CA certificate used as the server's own)."""
    d = tmp_path_factory.mktemp("pki")
    _openssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out",
             "ca.pem", "-days", "1", "-subj", "/CN=mav-observer test CA", cwd=d)  # fmt: skip
    _openssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "key.pem", "-out", "srv.csr",
             "-subj", "/CN=localhost", cwd=d)  # fmt: skip
    (d / "ext.cnf").write_text(
        "basicConstraints=CA:FALSE\nsubjectAltName=DNS:localhost,IP:127.0.0.1\n"
        "extendedKeyUsage=serverAuth\n"
    )
    _openssl("x509", "-req", "-in", "srv.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
             "-CAcreateserial", "-out", "cert.pem", "-days", "1", "-extfile", "ext.cnf",
             cwd=d)  # fmt: skip
    (d / "users.txt").write_text("alice:correct horse\n")
    return d


def _write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


def _service_file(pki: Path, port: int) -> str:
    """What docs/service.md gives for a service that only TLS clients with a password reach."""
    return _write(
        pki / f"service-{port}.json5",
        f"""{{
  mode: "peer",
  listen: {{ endpoints: ["tls/127.0.0.1:{port}"] }},
  transport: {{
    link: {{ tls: {{ listen_certificate: "{pki}/cert.pem",
                     listen_private_key: "{pki}/key.pem" }} }},
    auth: {{ usrpwd: {{ user: "mav-observer", password: "its own",
                        dictionary_file: "{pki}/users.txt" }} }},
  }},
}}""",
    )


def _client_file(pki: Path, port: int, *, proto: str = "tls", ca: bool = True,
                 user: str | None = "alice", password: str = "correct horse") -> str:  # fmt: skip
    tls = f'link: {{ tls: {{ root_ca_certificate: "{pki}/ca.pem" }} }},' if ca else ""
    auth = f'auth: {{ usrpwd: {{ user: "{user}", password: "{password}" }} }},' if user else ""
    name = f"client-{port}-{proto}-{ca}-{user}-{password.replace(' ', '_')}.json5"
    return _write(
        pki / name,
        f'{{ mode: "client", connect: {{ endpoints: ["{proto}/127.0.0.1:{port}"] }}, '
        f"transport: {{ {tls} {auth} }} }}",
    )


def test_tls_with_a_password_lets_the_right_client_in_and_no_one_else(pki: Path) -> None:
    port = free_tcp_port()
    service = open_session(session_config(config_file=_service_file(pki, port)))
    try:
        pubs = Publications(service, "mav_observer")
        good = open_session(session_config(config_file=_client_file(pki, port)))
        got: list[str] = []
        try:
            good.declare_subscriber("mav_observer/**", lambda s: got.append(str(s.key_expr)))
            assert wait_for(lambda: _published(pubs, got), timeout_s=5.0)
        finally:
            good.close()
        refused = {
            "wrong password": _client_file(pki, port, password="guess"),
            "no credentials": _client_file(pki, port, user=None),
            "plain TCP": _client_file(pki, port, proto="tcp"),
            "untrusted certificate": _client_file(pki, port, ca=False),
        }
        for conf_file in refused.values():  # refused at open: it gets nothing at all
            with pytest.raises(ConfigError, match=r"cannot open the Zenoh session"):
                open_session(session_config(config_file=conf_file))
    finally:
        service.close()


def _published(pubs: Publications, got: list[str]) -> bool:
    pubs.session.put("mav_observer/1/status", "{}")
    time.sleep(0.05)
    return "mav_observer/1/status" in got


@pytest.mark.slow
def test_a_router_restart_is_rejoined() -> None:
    """The service (a peer) and a subscriber (a client) connect to a router; the router stops
    and a new one starts on the same port: with our connect retry (from every 0.1 s) both
    rejoin it and the estimates flow again within 2 s."""
    port = free_tcp_port()
    router_conf = session_config(mode="router", listen=[f"tcp/127.0.0.1:{port}"])
    peer = session_config(mode="peer", listen=[], connect=[f"tcp/127.0.0.1:{port}"])
    router = open_session(router_conf)
    service = open_session(peer)
    sub = open_session(session_config(mode="client", connect=[f"tcp/127.0.0.1:{port}"]))
    got: list[float] = []
    sub.declare_subscriber("mav_observer/1/status", lambda s: got.append(time.monotonic()))
    try:
        assert wait_for(lambda: service.put("mav_observer/1/status", "{}") or got, 5.0)
        router.close()
        time.sleep(0.5)
        router = open_session(router_conf)
        t_back = time.monotonic()
        assert wait_for(
            lambda: service.put("mav_observer/1/status", "{}") or (got and got[-1] > t_back), 5.0
        )
        print(f"router restart: receiving again {1000 * (got[-1] - t_back):.1f} ms later")
        assert got[-1] - t_back < 2.0
    finally:
        for s in (sub, service, router):
            s.close()


def test_rays_are_listened_to_while_a_subscriber_matches_them(pair) -> None:
    server, client = pair
    pubs = Publications(server, "mav_observer")
    pubs.watch_rays()
    assert not pubs.rays_listened
    sub = client.declare_subscriber("mav_observer/2/gimbal/ray", lambda s: None)
    assert wait_for(lambda: pubs.rays_listened, 5.0)
    sub.undeclare()
    assert wait_for(lambda: not pubs.rays_listened, 5.0)
    pubs.close()
