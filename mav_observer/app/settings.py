"""The service's settings: defaults, a TOML file, command-line overrides, validation.

Settings are a two-level table, ``section.key`` (``docs/service.md`` lists them all; ``mav-observer
run --print-config`` prints the effective ones as TOML that :func:`load_toml` reads back).
They are resolved in this order, later winning: the defaults in :data:`SCHEMA`, the TOML file,
then the command-line flags. Every value is checked here, at the boundary: an unknown key or a
bad value is a :class:`~mav_observer.errors.ConfigError` naming ``section.key``.

``None`` (unset) has no TOML spelling: an unset key is left out of the file (and printed as a
comment).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from mav_observer.app import setting_checks as checks
from mav_observer.core.config import ESTIMATORS, ObserverConfig
from mav_observer.errors import ConfigError
from mav_observer.tracking.tracker import SOURCES, TrackerConfig

DEFAULT_MAVLINK_URL = "udpin:127.0.0.1:14550"
DEFAULT_ZENOH_ENDPOINT = "tcp/127.0.0.1:7447"
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
ZENOH_MODES = ("peer", "client", "router")


#: Which estimator each observer setting belongs to (the others apply to both). A setting
#: of the other estimator given in a settings file or on the command line is an error.
ESTIMATOR_KEYS: dict[str, tuple[str, ...]] = {
    "riccati": (
        "bearing_noise_deg",
        "velocity_noise_mps",
        "bias_walk_mps_per_sqrt_s",
        "bearing_latency_s",
        "robust",
        "hypotheses",
        "range_span",
    ),
    "paper": ("k_per_s", "k_star_per_s", "static_hold", "hold_speed_mps", "hold_innovation_deg"),
}
OBSERVER_HELP = {
    "estimator": "riccati (default) or paper",
    "bearing_noise_deg": "bearing noise per direction, 1 sigma (deg); auto: learnt online",
    "velocity_noise_mps": "white velocity noise per axis, 1 sigma (m/s); auto: learnt online",
    "robust": "down-weight gross bearing errors (Huber, beyond the 99.9 % NIS quantile)",
    "bias_walk_mps_per_sqrt_s": "random walk of the bias a (m/s per sqrt s; 0 = constant); auto: "
    "learnt online from 0 (default, docs/tuning.md)",
    "bearing_latency_s": "how long the bearings trail the line of sight (s, within +-0.5); "
    "auto: learnt online (default)",
    "hypotheses": "filters in the bank",
    "range_span": "the bank spans guess/span to guess*span",
    "k_per_s": "gain k (1/s)",
    "k_star_per_s": "gain k* (1/s)",
    "mode": "biased or bias_free",
    "interpolation": "linear or hold",
    "max_bearing_age_s": "no correction past this (s)",
    "max_velocity_age_s": "a velocity older than this: stale (s)",
    "max_velocity_wait_s": "bearings wait this long for the velocity after a gap (s)",
    "window_s": "excitation window (s)",
    "window_buckets": "buckets of the excitation window",
    "excitation_min": "below: not observable",
    "converged_tol": "relative correction below which an estimate is converged",
    "initial_range_m": "first range guess (m)",
    "static_hold": "hold the state while the geometry is still",
    "hold_speed_mps": "static hold below this relative speed (m/s)",
    "hold_innovation_deg": "static hold while the bearing agrees within this (deg)",
    "max_buffer": "most samples of one stream kept waiting for the other",
}
#: Observer settings that are learnt online when ``"auto"`` (the default) or told as a number.
AUTO_KEYS = (
    "bearing_noise_deg",
    "velocity_noise_mps",
    "bias_walk_mps_per_sqrt_s",
    "bearing_latency_s",
)
#: Observer fields not set from the settings (the dimension; the paper's initial state).
_OBSERVER_FIXED = ("n", "xh1_0_m", "m_0_s", "zs_0_mps")


def _like(default: object) -> Callable[[object], Any]:
    """A type check for a setting whose default is ``default`` (the dataclass checks the
    range)."""
    if isinstance(default, bool):
        return checks.boolean
    if isinstance(default, int):
        return checks.integer(-(2**31), 2**31 - 1)
    if isinstance(default, float):
        return checks.number()
    if isinstance(default, str):
        return checks.string
    return checks.optional(checks.number())


def _checked_by(cls: type, key: str, check: Callable[[object], Any]) -> Callable[[object], Any]:
    """``check``, then the dataclass ``cls`` built with this one value (its own validation,
    whose message names the field) gives the clean value."""

    def run(v: object) -> Any:
        v = check(v)
        try:
            return getattr(cls(**{key: v}), key)
        except ConfigError as exc:
            text = str(exc)
            raise ValueError(text[len(key) + 1 :] if text.startswith(key + " ") else text) from None

    return run


def _observer_schema() -> dict[str, tuple[Any, Callable[[object], Any], str]]:
    """``[observer]``: every :class:`~mav_observer.core.observer.ObserverConfig` field, its default
    and validation the dataclass's own."""
    out: dict[str, tuple[Any, Callable[[object], Any], str]] = {}
    for f in fields(ObserverConfig):
        if f.name in _OBSERVER_FIXED:
            continue
        default = f.default
        if f.name == "estimator":
            check = checks.choice(*ESTIMATORS)
        elif f.name in AUTO_KEYS:
            check = checks.number_or_auto
        else:
            check = _like(default)
        side = next((e for e, keys in ESTIMATOR_KEYS.items() if f.name in keys), None)
        help_ = OBSERVER_HELP.get(f.name, "") + (f" ({side} only)" if side else "")
        out[f.name] = (default, _checked_by(ObserverConfig, f.name, check), help_)
    return out


def _tracker_schema() -> dict[str, tuple[Any, Callable[[object], Any], str]]:
    """``[tracker]``: the :class:`~mav_observer.tracking.tracker.TrackerConfig` fields a user
    sets, defaults from the dataclass."""
    d = TrackerConfig()

    def tc(key: str, check: Callable[[object], Any]) -> Callable[[object], Any]:
        def run(v: object) -> Any:
            v = check(v)
            arg = tuple(v) if isinstance(v, list) else v
            try:
                TrackerConfig(**{key: arg or (None if key == "sysids" else arg)})
            except ConfigError as exc:
                raise ValueError(str(exc).removeprefix(key + " ")) from None
            return v

        return run

    num = checks.number()
    return {
        "sources": (
            list(d.sources),
            tc("sources", checks.list_of(checks.choice("auto", *SOURCES), allow_empty=False)),
            "",
        ),
        "gimbal_angles": (
            d.gimbal_angles,
            tc("gimbal_angles", checks.string),
            "auto: flags until the data show body-relative angles; flags; body: servo mounts",
        ),
        "mount_status_yaw": (d.mount_status_yaw, tc("mount_status_yaw", checks.string), ""),
        "landing_target_orientation": (
            d.landing_target_orientation,
            tc("landing_target_orientation", checks.string),
            "PLND_ORIENT",
        ),
        "landing_target_yaw_align_deg": (
            d.landing_target_yaw_align_deg,
            checks.number(-360.0, hi=360.0),
            "PLND_YAW_ALIGN",
        ),
        "camera_hfov_deg": (None, tc("camera_hfov_deg", checks.optional(num)), ""),
        "camera_vfov_deg": (None, tc("camera_vfov_deg", checks.optional(num)), ""),
        "max_attitude_age_s": (d.max_attitude_age_s, tc("max_attitude_age_s", num), ""),
        "max_camera_attitude_age_s": (
            d.max_camera_attitude_age_s,
            tc("max_camera_attitude_age_s", num),
            "",
        ),
        "range_noise_m": (
            d.range_noise_m,
            tc("range_noise_m", num),
            "the noise of a range measured with a bearing, when its message gives none (m)",
        ),
        "max_range_age_s": (
            d.max_range_age_s,
            tc("max_range_age_s", num),
            "a gimbal's range is fused with a bearing at most this far from its time (s)",
        ),
        "attitude_wait_s": (
            d.attitude_wait_s,
            tc("attitude_wait_s", num),
            "a bearing waits this long for the attitude of its time (s)",
        ),
        "attitude_extrapolate_s": (
            d.attitude_extrapolate_s,
            tc("attitude_extrapolate_s", num),
            "a bearing this close past a dense attitude stream's latest does not wait (s)",
        ),
        "sysids": ([], checks.list_of(checks.integer(1, 255)), "only these vehicles (empty: all)"),
        "publish": (
            d.publish,
            tc("publish", checks.string),
            "auto: live in the service, committed in replay; live: each bearing's estimate at "
            "its arrival; committed: once the velocity after it is known",
        ),
        "local_frame": (
            d.local_frame,
            tc("local_frame", checks.string),
            "how the autopilot maps its local frame onto latitude and longitude: auto (wgs84 "
            "until its position pairs tell), wgs84, ardupilot, px4",
        ),
    }


#: ``section -> key -> (default, checker, help)``.
SCHEMA: dict[str, dict[str, tuple[Any, Callable[[object], Any], str]]] = {
    "mavlink": {
        "url": (
            DEFAULT_MAVLINK_URL,
            checks.mavlink_url,
            "where the autopilot's telemetry comes from: udpin:, udpout:, tcp:, tcpin:, "
            "DEVICE,BAUD",
        ),
        "heartbeat_period_s": (
            "auto",
            checks.heartbeat,
            'send our HEARTBEAT this often (s); "auto": only on udpout links; false: never',
        ),
        "stale_after_s": (
            2.0,
            checks.number(0.0, lo_open=True),
            "no message from a vehicle for this long (s): its status is stale",
        ),
        "signing_key_file": (
            None,
            checks.optional(checks.string),
            "MAVLink 2 signing key file (64 hex digits or a passphrase); when set, unsigned "
            "and wrongly signed messages are refused and counted",
        ),
        "signing_link_id": (0, checks.integer(0, 255), "link id in the signatures of what we send"),
        "out": (
            False,
            checks.boolean,
            "send the estimates back over MAVLink: LANDING_TARGET (position form) for converged "
            "targets and STATUSTEXT with their latitude and longitude (docs/geolocation.md)",
        ),
        "out_url": (
            None,
            checks.optional(checks.mavlink_url),
            "where to send them (unset: over the input connection)",
        ),
        "out_targets": (
            [],
            checks.list_of(checks.string),
            "the targets sent as LANDING_TARGET and STATUSTEXT (empty: every target)",
        ),
        "out_rate_hz": (
            4.0,
            checks.number(0.0, lo_open=True),
            "most LANDING_TARGET per s per target",
        ),
        "out_statustext": (
            True,
            checks.boolean,
            "also a STATUSTEXT when a target converges or moves",
        ),
        "out_frame": (
            "local_ned",
            checks.choice("local_ned", "body_frd"),
            "LANDING_TARGET's frame: local_ned (PX4) or body_frd (ArduPilot)",
        ),
    },
    "zenoh": {
        "config_file": (
            None,
            checks.optional(checks.string),
            "a standard Zenoh JSON5 configuration file (mode, endpoints, TLS, authentication)",
        ),
        "mode": (
            None,
            checks.optional(checks.choice(*ZENOH_MODES)),
            "peer, client or router (unset: the config file's, else peer)",
        ),
        "listen": (
            None,
            checks.optional(checks.list_of(checks.endpoint)),
            f"endpoints to listen on (unset: the config file's, else {DEFAULT_ZENOH_ENDPOINT})",
        ),
        "connect": (
            None,
            checks.optional(checks.list_of(checks.endpoint)),
            "endpoints to connect to: a router, other peers (unset: the config file's, else none)",
        ),
        "prefix": ("mav_observer", checks.prefix, "the first chunk(s) of every key expression"),
        "estimate_max_rate_hz": (
            50.0,
            checks.number(0.0),
            "most estimates per second per target (0: every bearing update)",
        ),
        "status_period_s": (1.0, checks.number(0.05), "status publication period (s)"),
        "rays": (
            True,
            checks.boolean,
            "also publish each bearing used as a geodetic ray, for `mav-observer fuse`",
        ),
        "congestion_control": (
            "drop",
            checks.choice("drop", "block"),
            "when the network is congested: drop an estimate, or block the estimator",
        ),
    },
    "tracker": _tracker_schema(),
    "observer": _observer_schema(),
    "state": {
        "file": (
            None,
            checks.optional(checks.string),
            "save observers here and restore them on start",
        ),
        "save_period_s": (10.0, checks.number(0.5), "save this often (s), and on stop"),
        "max_gap_s": (
            600.0,
            checks.number(0.0, lo_open=True),
            "a saved observer older than this (vehicle time, s) is not restored",
        ),
    },
    "log": {"level": ("INFO", checks.choice(*LOG_LEVELS), "DEBUG, INFO, WARNING or ERROR")},
}


def defaults() -> dict[str, dict[str, Any]]:
    """The default settings as a fresh nested dictionary."""
    return {sec: {k: _copy(v[0]) for k, v in keys.items()} for sec, keys in SCHEMA.items()}


def _copy(v: Any) -> Any:
    return list(v) if isinstance(v, list) else v


def merge(
    base: dict[str, dict[str, Any]],
    layer: Mapping[str, Any],
    origin: str,
    origins: dict[str, str] | None = None,
) -> None:
    """Check ``layer`` (``{section: {key: value}}``) and write it over ``base`` in place.
    ``origin`` names where the layer came from, for error messages; ``origins`` collects
    ``"section.key" -> origin`` of every value set."""
    if not isinstance(layer, Mapping):
        raise ConfigError(f"{origin}: settings must be a table of sections")
    for sec, table in layer.items():
        if sec not in SCHEMA:
            raise ConfigError(f"{origin}: unknown section [{sec}]; known: {sorted(SCHEMA)}")
        if not isinstance(table, Mapping):
            raise ConfigError(f"{origin}: [{sec}] must be a table, got {table!r}")
        for key, value in table.items():
            if key not in SCHEMA[sec]:
                raise ConfigError(
                    f"{origin}: unknown setting {sec}.{key}; known in [{sec}]: "
                    f"{sorted(SCHEMA[sec])}"
                )
            try:
                base[sec][key] = SCHEMA[sec][key][1](value)
            except ValueError as exc:
                raise ConfigError(f"{origin}: {sec}.{key} {exc}") from None
            if origins is not None:
                origins[f"{sec}.{key}"] = origin


def load_toml(path: Path) -> dict[str, Any]:
    """Read a TOML settings file (not yet checked: see :func:`resolve`)."""
    import tomllib  # (here: a run or replay without a file does not pay for its import)

    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the settings file: {exc.strerror}") from None


def resolve(
    config_file: Path | None = None,
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
    flags: Mapping[str, str] | None = None,
) -> Settings:
    """Defaults, then ``config_file``, then ``overrides`` (the flags), checked. ``flags``
    (``"section.key" -> "--flag"``) names the flag of each override in error messages
    (``command line (--k): ...``)."""
    d = defaults()
    origins: dict[str, str] = {}
    if config_file is not None:
        merge(d, load_toml(config_file), str(config_file), origins)
    if overrides:
        if not isinstance(overrides, Mapping):
            raise ConfigError("command line: settings must be a table of sections")
        for sec, table in overrides.items():
            if sec not in SCHEMA or not isinstance(table, Mapping):  # merge names it
                merge(d, {sec: table}, "command line", origins)
                continue
            for key, value in table.items():
                flag = (flags or {}).get(f"{sec}.{key}")
                origin = f"command line ({flag})" if flag else "command line"
                merge(d, {sec: {key: value}}, origin, origins)
    check_estimator_keys(d, origins)
    return Settings.from_dict(d)


def check_estimator_keys(d: Mapping[str, Mapping[str, Any]], origins: Mapping[str, str]) -> None:
    """A setting given (file or flag) for the estimator not chosen is an error saying so."""
    est = d["observer"]["estimator"]
    for other, keys in ESTIMATOR_KEYS.items():
        if other == est:
            continue
        for key in keys:
            origin = origins.get(f"observer.{key}")
            if origin is None:
                continue
            head = (
                f"{origin}: observer.{key} applies to the {other!r} estimator only (this one "
                f"is {est!r}"
            )
            est_origin = origins.get("observer.estimator")
            if est_origin is not None:
                head += f", from {est_origin}"
            if origin.startswith("command line (--"):
                flag = origin.removeprefix("command line (").removesuffix(")")
                hint = f"add --estimator {other}, or leave {flag} out"
            elif origin.startswith("command line"):
                hint = f"add --estimator {other}, or leave {key} out"
            elif est_origin is not None:
                hint = f"remove {key} from the file, or choose the {other!r} estimator"
            else:
                hint = (
                    f'set estimator = "{other}" in [observer] (or --estimator {other}), '
                    f"or remove {key} from the file"
                )
            raise ConfigError(f"{head}); {hint}")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def to_toml(d: Mapping[str, Mapping[str, Any]]) -> str:
    """Settings as TOML, with each key's help as a comment; unset keys are comments."""
    lines: list[str] = []
    est = d["observer"]["estimator"]
    other = {k for e, keys in ESTIMATOR_KEYS.items() if e != est for k in keys}
    for sec, keys in SCHEMA.items():
        lines.append(f"[{sec}]")
        for key, (_, _, help_) in keys.items():
            v = d[sec][key]
            comment = f"  # {help_}" if help_ else ""
            if sec == "observer" and key in other:  # not this estimator's: left out
                lines.append(f"# {key} = {_toml_value(v)}{comment}")
            elif v is None:
                lines.append(f"# {key} = (unset){comment}")
            else:
                lines.append(f"{key} = {_toml_value(v)}{comment}")
        lines.append("")
    return "\n".join(lines)


@dataclass(frozen=True)
class Settings:
    """Checked settings of the service (see :data:`SCHEMA`); ``values`` keeps the table."""

    values: Mapping[str, Mapping[str, Any]]

    @classmethod
    def from_dict(cls, d: dict[str, dict[str, Any]]) -> Settings:
        full = defaults()
        merge(full, d, "settings")
        s = cls(full)
        s.tracker_config()  # cross-field checks of the tracker and observer, named
        return s

    def __getitem__(self, section: str) -> Mapping[str, Any]:
        return self.values[section]

    def to_toml(self) -> str:
        return to_toml(self.values)

    def observer_config(self) -> ObserverConfig:
        try:
            return ObserverConfig(**self.values["observer"])
        except ConfigError as exc:
            raise ConfigError(f"[observer] {exc}") from None

    def tracker_config(self) -> TrackerConfig:
        t = self.values["tracker"]
        try:
            return TrackerConfig(
                sources=tuple(t["sources"]),
                gimbal_angles=t["gimbal_angles"],
                mount_status_yaw=t["mount_status_yaw"],
                landing_target_orientation=t["landing_target_orientation"],
                landing_target_yaw_align_deg=t["landing_target_yaw_align_deg"],
                camera_hfov_deg=t["camera_hfov_deg"],
                camera_vfov_deg=t["camera_vfov_deg"],
                max_attitude_age_s=t["max_attitude_age_s"],
                max_camera_attitude_age_s=t["max_camera_attitude_age_s"],
                attitude_wait_s=t["attitude_wait_s"],
                attitude_extrapolate_s=t["attitude_extrapolate_s"],
                range_noise_m=t["range_noise_m"],
                max_range_age_s=t["max_range_age_s"],
                publish=t["publish"],
                local_frame=t["local_frame"],
                sysids=tuple(t["sysids"]) or None,
                restore_max_gap_s=self.values["state"]["max_gap_s"],
                observer=self.observer_config(),
            )
        except ConfigError as exc:
            raise ConfigError(f"[tracker] {exc}") from None


__all__ = [
    "DEFAULT_MAVLINK_URL",
    "DEFAULT_ZENOH_ENDPOINT",
    "ESTIMATOR_KEYS",
    "SCHEMA",
    "Settings",
    "check_estimator_keys",
    "defaults",
    "load_toml",
    "merge",
    "resolve",
    "to_toml",
]
