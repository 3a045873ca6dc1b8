"""Service settings: defaults, TOML file, flags, validation naming the key, printing."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from mav_observer.app import settings as st
from mav_observer.errors import ConfigError


def test_defaults_suit_a_companion_computer() -> None:
    s = st.resolve()
    assert s["mavlink"]["url"] == "udpin:127.0.0.1:14550"
    assert s["zenoh"]["mode"] is None and s["zenoh"]["listen"] is None  # embedded default
    assert s["zenoh"]["prefix"] == "mav_observer"
    assert s["state"]["file"] is None
    tc = s.tracker_config()
    assert tc.sources == ("auto",) and tc.sysids is None
    assert tc.observer.k_per_s == 0.2


def test_file_then_flags_override_in_that_order(tmp_path: Path) -> None:
    f = tmp_path / "svc.toml"
    f.write_text(
        '[mavlink]\nurl = "tcp:127.0.0.1:5760"\n[observer]\nestimator = "paper"\n'
        'k_per_s = 0.5\n[zenoh]\nlisten = ["tcp/127.0.0.1:7500"]\n[tracker]\nsysids = [1, 2]\n'
    )
    s = st.resolve(f, {"observer": {"k_per_s": 0.3}})
    assert s["mavlink"]["url"] == "tcp:127.0.0.1:5760"
    assert s["observer"]["k_per_s"] == 0.3
    assert s["zenoh"]["listen"] == ["tcp/127.0.0.1:7500"]
    assert s.tracker_config().sysids == (1, 2)


def test_the_noise_is_auto_by_default_and_a_number_is_told(tmp_path: Path) -> None:
    assert st.resolve(None)["observer"]["bearing_noise_deg"] == "auto"
    cfg = st.resolve(None).observer_config()
    assert cfg.bearing_noise_deg == "auto" and cfg.velocity_noise_mps == "auto"
    f = tmp_path / "told.toml"
    f.write_text('[observer]\nbearing_noise_deg = 0.3\nvelocity_noise_mps = "auto"\n')
    cfg = st.resolve(f, {"observer": {"velocity_noise_mps": 0.02}}).observer_config()
    assert (cfg.bearing_noise_deg, cfg.velocity_noise_mps) == (0.3, 0.02)
    assert cfg.bank_params(0.1).learn_noise is False
    assert st.resolve(None).observer_config().bank_params(0.1).learn_noise is True


@pytest.mark.parametrize(
    ("layer", "match"),
    [
        ({"zenoh": {"lisen": []}}, r"unknown setting zenoh\.lisen"),
        ({"zeno": {}}, r"unknown section \[zeno\]"),
        ({"observer": {"k_per_s": -1}}, r"observer\.k_per_s must be a finite number > 0"),
        ({"observer": {"k_per_s": "fast"}}, r"observer\.k_per_s must be a number"),
        (
            {"observer": {"hold_innovation_deg": 120}},
            r"observer\.hold_innovation_deg must be at most 90",
        ),
        ({"observer": {"hypotheses": 40}}, r"observer\.hypotheses must be an integer in \[1, 31\]"),
        (
            {"observer": {"k_per_s": 0.5}},
            r"observer\.k_per_s applies to the 'paper' estimator only",
        ),
        (
            {"observer": {"estimator": "paper", "bearing_noise_deg": 1.0}},
            r"observer\.bearing_noise_deg applies to the 'riccati' estimator only",
        ),
        ({"observer": {"n": 2}}, r"unknown setting observer\.n"),
        (
            {"observer": {"bearing_noise_deg": "learn"}},
            r'observer\.bearing_noise_deg must be "auto" or a number',
        ),
        ({"observer": {"velocity_noise_mps": -0.1}}, r"observer\.velocity_noise_mps must be"),
        ({"observer": {"robust": "yes"}}, r"observer\.robust must be true or false"),
        (
            {"tracker": {"attitude_wait_s": 9}},
            r"tracker\.attitude_wait_s must be a number in \[0, 5\]",
        ),
        ({"zenoh": {"mode": "server"}}, r"zenoh\.mode must be one of"),
        ({"zenoh": {"listen": ["127.0.0.1:7447"]}}, r"zenoh\.listen item 0: must be a Zenoh"),
        ({"zenoh": {"prefix": "a/*"}}, r"zenoh\.prefix must be a plain key"),
        ({"tracker": {"sysids": [0]}}, r"tracker\.sysids item 0: must be an integer in 1\.\.255"),
        ({"tracker": {"sources": []}}, r"tracker\.sources must not be empty"),
        ({"mavlink": {"stale_after_s": 0}}, r"mavlink\.stale_after_s must be > 0"),
        ({"observer": {"static_hold": 1}}, r"observer\.static_hold must be true or false"),
        ({"log": {"level": "LOUD"}}, r"log\.level must be one of"),
        ({"mavlink": {"url": "udpin:127.0.0.1:99999"}}, r"mavlink\.url must be PREFIX:HOST:PORT"),
        ({"mavlink": {"url": "tcp:127.0.0.1"}}, r"mavlink\.url must be PREFIX:HOST:PORT"),
    ],
)
def test_a_bad_value_is_an_error_naming_the_key(layer: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        st.resolve(None, layer)


def test_a_broken_file_is_named(tmp_path: Path) -> None:
    f = tmp_path / "bad.toml"
    f.write_text("[mavlink\nurl = 1")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML"):
        st.resolve(f)
    with pytest.raises(ConfigError, match="cannot read the settings file"):
        st.resolve(tmp_path / "missing.toml")
    f.write_text('[observer]\nestimator = "paper"\nk_per_s = -3\n')
    with pytest.raises(ConfigError, match=r"bad\.toml: observer\.k_per_s"):
        st.resolve(f)
    f.write_text("[observer]\nk_star_per_s = 3\n")  # the default estimator has no k*
    with pytest.raises(ConfigError, match=r"bad\.toml: observer\.k_star_per_s applies to"):
        st.resolve(f)


def test_printed_settings_read_back_to_the_same(tmp_path: Path) -> None:
    s = st.resolve(None, {"zenoh": {"connect": ["tcp/127.0.0.1:7448"]}, "state": {"file": "s"}})
    text = s.to_toml()
    assert "# config_file = (unset)" in text
    f = tmp_path / "printed.toml"
    f.write_text(text)
    assert tomllib.loads(text)["zenoh"]["connect"] == ["tcp/127.0.0.1:7448"]
    assert st.resolve(f).values == s.values


def test_the_observer_settings_are_the_dataclass_fields_with_its_defaults() -> None:
    from dataclasses import fields

    from mav_observer.core.observer import ObserverConfig

    d = st.defaults()["observer"]
    ours = {f.name: f.default for f in fields(ObserverConfig)}
    assert set(d) == set(ours) - {"n", "xh1_0_m", "m_0_s", "zs_0_mps"}
    assert all(d[k] == ours[k] for k in d)
    assert st.resolve().observer_config() == ObserverConfig()


def test_the_tracker_settings_are_the_dataclass_fields_with_its_defaults() -> None:
    from dataclasses import fields

    from mav_observer.tracking.tracker import TrackerConfig

    d = st.defaults()["tracker"]
    ours = {f.name: f.default for f in fields(TrackerConfig)}
    # the observer's have their own table, the restore gap is [state] max_gap_s
    assert set(d) == set(ours) - {"observer", "restore_max_gap_s"}
    assert all(d[k] == (list(v) if isinstance(v, tuple) else v) for k, v in ours.items() if k in d
               and k != "sysids")  # fmt: skip
    assert d["sysids"] == [] and ours["sysids"] is None  # none listed: every vehicle
    assert st.resolve().tracker_config() == TrackerConfig(
        restore_max_gap_s=st.defaults()["state"]["max_gap_s"]
    )
    changed = st.resolve(None, {"tracker": {"attitude_wait_s": 0.1, "sources": ["gimbal"]}})
    assert changed.tracker_config().attitude_wait_s == 0.1
    assert changed.tracker_config().sources == ("gimbal",)
    px4 = st.resolve(None, {"tracker": {"local_frame": "px4"}})
    assert px4.tracker_config().local_frame == "px4"
    with pytest.raises(ConfigError, match=r"tracker\.local_frame must be .* got 'utm'"):
        st.resolve(None, {"tracker": {"local_frame": "utm"}})


def test_printed_settings_leave_the_other_estimators_keys_as_comments(tmp_path: Path) -> None:
    for est, hidden, shown in (
        ("riccati", "k_per_s", "bearing_noise_deg"),
        ("paper", "bearing_noise_deg", "k_per_s"),
    ):
        s = st.resolve(None, {"observer": {"estimator": est}})
        text = s.to_toml()
        doc = tomllib.loads(text)
        assert hidden not in doc["observer"] and shown in doc["observer"]
        f = tmp_path / f"{est}.toml"
        f.write_text(text)
        assert st.resolve(f).values == s.values


def test_an_error_names_the_flag_or_file_it_came_from(tmp_path: Path) -> None:
    flags = {"observer.bias_walk_mps_per_sqrt_s": "--bias-walk", "observer.k_per_s": "--k"}
    with pytest.raises(
        ConfigError,
        match=r"command line \(--bias-walk\): observer\.bias_walk_mps_per_sqrt_s applies to "
        r"the 'riccati' estimator only \(this one is 'paper', from command line\); add "
        r"--estimator riccati, or leave --bias-walk out",
    ):
        st.resolve(
            None,
            {"observer": {"estimator": "paper", "bias_walk_mps_per_sqrt_s": 0.1}},
            {"observer.bias_walk_mps_per_sqrt_s": "--bias-walk"},
        )
    with pytest.raises(ConfigError, match=r"command line \(--k\): observer\.k_per_s must be a"):
        st.resolve(None, {"observer": {"estimator": "paper", "k_per_s": -1.0}}, flags)
    f = tmp_path / "svc.toml"
    f.write_text("[observer]\nhypotheses = 3\n")
    with pytest.raises(
        ConfigError,
        match=r"svc\.toml: observer\.hypotheses applies to the 'riccati' estimator only \(this "
        r"one is 'paper', from command line \(--estimator\)\); remove hypotheses from the file",
    ):
        st.resolve(f, {"observer": {"estimator": "paper"}}, {"observer.estimator": "--estimator"})


def test_the_estimator_table_in_the_docs_is_the_settings_table() -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "service.md").read_text()
    for est, keys in st.ESTIMATOR_KEYS.items():
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| `{est}`"))
        assert {k.strip(" `") for k in row.split("|")[2].split(",")} == set(keys), row
