"""The estimate record: one JSON object per estimate (schema 1, ``docs/schema.md``).

Shared by replay (JSON Lines and CSV files) and the service (Zenoh). Fields:

========================  =========================================================================
``schema``                1
``t_unix_s``              tlog (or arrival) time of the sample that produced the estimate, s
``t_boot_s``              the same instant on the vehicle's autopilot clock (observer time), s
``sysid``                 MAVLink system id of the vehicle
``target``                which target: ``gimbal``, ``camera``, ``mount``, ``landing_target_<n>``...
``source``                the message the bearing came from
``rel_pos_ned_m``         estimated target minus vehicle position, NED, m
``range_m``               its norm, m
``bias_ned_mps``          the paper's ``a``: target velocity minus the vehicle's velocity error, m/s
``target_pos_ned_m``      target position in the LOCAL_POSITION_NED frame, m, or null if unknown
``vehicle_pos_ned_m``     the vehicle's position used for it, m, or null
``range_std_m``           1-sigma uncertainty of the range (along the bearing), m, or null
``rel_pos_std_ned_m``     1-sigma uncertainty of each component of ``rel_pos_ned_m``, m, or null
``bias_std_ned_mps``      1-sigma uncertainty of each component of ``bias_ned_mps``, m/s, or null
``pe``                    persistent-excitation level (monitor's excitation), dimensionless
``cond_m``                condition number of the observer matrix M (paper) or of the position
                          covariance (riccati)
``status``                ``converging``, ``converged``, ``not observable`` or ``stale``
``corrected``             false if the estimate is a prediction without a usable bearing
``target_lat_deg``        the target's WGS84 latitude, deg, or null until the local frame's origin
                          is known (``docs/geolocation.md``)
``target_lon_deg``        its longitude, deg, or null
``target_alt_m``          its altitude AMSL, m, or null
``target_h_std_m``        1-sigma horizontal uncertainty, ``sqrt(sd_n^2 + sd_e^2)`` of
                          ``rel_pos_std_ned_m`` (twice it holds about 95 % of errors), m, or null
``target_v_std_m``        1-sigma vertical uncertainty (``sd_d``), m, or null
========================  =========================================================================
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from mav_observer.core.samples import Estimate
from mav_observer.geo.geodesy import Origin, to_geodetic

SCHEMA_VERSION = 1

#: Version and top-level keys of a vehicle's status document (``docs/schema.md``, "The
#: status"), published by the service beside the estimate records.
STATUS_SCHEMA = 1
STATUS_KEYS = (
    "schema",
    "t_unix_s",
    "sysid",
    "service",
    "link",
    "rates_hz",
    "messages",
    "skipped",
    "link_skipped",
    "bearing_sources",
    "origin",
    "gimbal_angles",
    "observers",
    "events",
)

CSV_COLUMNS = (
    "t_unix_s",
    "t_boot_s",
    "sysid",
    "target",
    "source",
    "rel_pos_n_m",
    "rel_pos_e_m",
    "rel_pos_d_m",
    "range_m",
    "bias_n_mps",
    "bias_e_mps",
    "bias_d_mps",
    "target_pos_n_m",
    "target_pos_e_m",
    "target_pos_d_m",
    "range_std_m",
    "rel_pos_std_n_m",
    "rel_pos_std_e_m",
    "rel_pos_std_d_m",
    "bias_std_n_mps",
    "bias_std_e_mps",
    "bias_std_d_mps",
    "pe",
    "cond_m",
    "status",
    "corrected",
    "target_lat_deg",
    "target_lon_deg",
    "target_alt_m",
    "target_h_std_m",
    "target_v_std_m",
)


@dataclass(frozen=True, slots=True)
class EstimateRecord:
    """An estimate with its MAVLink context (what is published and written)."""

    t_unix_s: float
    t_boot_s: float
    sysid: int
    target: str
    source: str
    estimate: Estimate
    vehicle_pos_ned_m: tuple[float, float, float] | None
    #: the local frame's origin on WGS84, when known (:mod:`mav_observer.geo.geodesy`)
    origin: Origin | None = None

    @property
    def target_pos_ned_m(self) -> tuple[float, float, float] | None:
        if self.vehicle_pos_ned_m is None:
            return None
        x = self.estimate.x_m
        p = self.vehicle_pos_ned_m
        return (p[0] + float(x[0]), p[1] + float(x[1]), p[2] + float(x[2]))

    def target_geodetic(self) -> tuple[float, float, float, float | None, float | None] | None:
        """The target as (latitude deg, longitude deg, altitude m AMSL, horizontal and
        vertical 1-sigma m or ``None``), or ``None`` without an origin or a vehicle position."""
        tp = self.target_pos_ned_m
        if tp is None or self.origin is None:
            return None
        lat, lon, alt = to_geodetic(self.origin, tp)
        sd = self.estimate.x_std_m
        if sd is None or len(sd) != 3:
            return lat, lon, alt, None, None
        sn, se, sdd = (float(v) for v in sd)
        return lat, lon, alt, math.sqrt(sn * sn + se * se), sdd

    def to_dict(self) -> dict[str, Any]:
        e = self.estimate
        tp = self.target_pos_ned_m
        return {
            "schema": SCHEMA_VERSION,
            "t_unix_s": self.t_unix_s,
            "t_boot_s": self.t_boot_s,
            "sysid": self.sysid,
            "target": self.target,
            "source": self.source,
            "rel_pos_ned_m": [float(v) for v in e.x_m],
            "range_m": e.range_m,
            "bias_ned_mps": [float(v) for v in e.a_mps],
            "target_pos_ned_m": None if tp is None else list(tp),
            "vehicle_pos_ned_m": None
            if self.vehicle_pos_ned_m is None
            else list(self.vehicle_pos_ned_m),
            "range_std_m": e.range_std_m,
            "rel_pos_std_ned_m": None if e.x_std_m is None else [float(v) for v in e.x_std_m],
            "bias_std_ned_mps": None if e.a_std_mps is None else [float(v) for v in e.a_std_mps],
            "pe": e.excitation,
            "cond_m": e.cond_m,
            "status": str(e.status),
            "corrected": e.corrected,
            **dict(zip(_GEO_KEYS, self.target_geodetic() or _NO_GEO, strict=True)),
        }

    def to_json(self) -> str:
        """The record as one line of JSON (no trailing newline), numbers rounded to
        :data:`JSON_RESOLUTION` (far below the estimator's accuracy; printing shortest
        round-trip floats is slow). A non-finite number, which JSON cannot carry, is written
        as ``null``.

        The same text as formatting :meth:`to_dict`'s values one by one, each value
        computed once (the target's position and the position's sigmas serve the map
        fields too) and every number formatted by one template when all are finite."""
        e = self.estimate
        x0, x1, x2 = e.x_m.tolist()
        a0, a1, a2 = e.a_mps.tolist()
        vp = self.vehicle_pos_ned_m
        head = (float(self.t_unix_s), float(self.t_boot_s), self.sysid, self.target, self.source)
        nums = (x0, x1, x2, float(e.range_m), a0, a1, a2)
        sd = e.x_std_m
        sdl = None if sd is None else sd.tolist() if hasattr(sd, "tolist") else list(sd)
        stds = (
            _num_or_null(_P, e.range_std_m),
            "null" if sd is None else _vec_or_null(_P, sd, sdl),
            _vec_or_null(_V, e.a_std_mps),
        )
        tail = (
            *stds,
            float(e.excitation),
            float(e.cond_m),
            str(e.status),
            _BOOL[bool(e.corrected)],
        )
        origin = self.origin
        if vp is None:
            template, pos = _JSON_NO_POS, ()
            geo = _GEO_NULL
        else:
            v0, v1, v2 = (float(v) for v in vp)
            tp = (v0 + x0, v1 + x1, v2 + x2)  # target_pos_ned_m
            template, pos = _JSON_POS, (*tp, v0, v1, v2)
            if origin is None:
                geo = _GEO_NULL
            else:  # target_geodetic(), the target's position and sigmas as computed here
                lat, lon, alt = to_geodetic(origin, tp)
                if sdl is None or len(sdl) != 3:
                    geo = _geo_json((lat, lon, alt, None, None))
                else:
                    sn, se, sdd = sdl
                    geo = _geo_json((lat, lon, alt, math.sqrt(sn * sn + se * se), sdd))
        vals = (*head, *nums, *pos, *tail, geo)
        if math.isfinite(sum((*head[:2], *nums, *pos, *tail[3:5]))):  # all finite: fast path
            return template % vals
        return _format_checked(template, vals)

    def csv_row(self) -> list[object]:
        e = self.estimate
        tp = self.target_pos_ned_m or (None, None, None)
        return [
            self.t_unix_s,
            self.t_boot_s,
            self.sysid,
            self.target,
            self.source,
            *(float(v) for v in e.x_m),
            e.range_m,
            *(float(v) for v in e.a_mps),
            *tp,
            e.range_std_m,
            *(e.x_std_m if e.x_std_m is not None else (None, None, None)),
            *(e.a_std_mps if e.a_std_mps is not None else (None, None, None)),
            e.excitation,
            e.cond_m,
            str(e.status),
            int(e.corrected),
            *(self.target_geodetic() or _NO_GEO),
        ]


_BOOL = ("false", "true")
_T, _P, _V, _G = "%.6f", "%.4f", "%.5f", "%.6g"
JSON_RESOLUTION = {
    "t_unix_s, t_boot_s": "1 us (6 decimals)",
    "rel_pos_ned_m, range_m, target_pos_ned_m, vehicle_pos_ned_m": "0.1 mm (4 decimals)",
    "bias_ned_mps, bias_std_ned_mps": "0.01 mm/s (5 decimals)",
    "range_std_m, rel_pos_std_ned_m": "0.1 mm (4 decimals)",
    "pe, cond_m": "6 significant digits",
    "target_lat_deg, target_lon_deg": "1e-8 deg (8 decimals, about 1 mm)",
    "target_alt_m, target_h_std_m, target_v_std_m": "0.1 mm (4 decimals)",
}
"""How :meth:`EstimateRecord.to_json` rounds each number."""
_JSON_HEAD = (
    f'{{"schema": {SCHEMA_VERSION}, "t_unix_s": {_T}, "t_boot_s": {_T}, "sysid": %d, '
    f'"target": "%s", "source": "%s", "rel_pos_ned_m": [{_P}, {_P}, {_P}], "range_m": {_P}, '
    f'"bias_ned_mps": [{_V}, {_V}, {_V}], '
)
_JSON_TAIL = (
    '"range_std_m": %s, "rel_pos_std_ned_m": %s, "bias_std_ned_mps": %s, '
    f'"pe": {_G}, "cond_m": {_G}, "status": "%s", "corrected": %s, %s}}'
)
_GEO_KEYS = ("target_lat_deg", "target_lon_deg", "target_alt_m", "target_h_std_m", "target_v_std_m")
_NO_GEO = (None, None, None, None, None)
_GEO_FMT = ("%.8f", "%.8f", _P, _P, _P)  # 1e-8 deg: about a millimetre


_GEO_TEMPLATE = ", ".join(f'"{k}": {f}' for k, f in zip(_GEO_KEYS, _GEO_FMT, strict=True))


def _geo_json(geo: tuple[float, float, float, float | None, float | None] | None) -> str:
    """The geodetic fields of :meth:`EstimateRecord.to_json` (``null`` each when unknown)."""
    if geo is not None and geo[3] is not None and math.isfinite(sum(geo)):  # type: ignore[arg-type]
        return _GEO_TEMPLATE % geo  # every value known (the same text, one format)
    vals = geo or _NO_GEO
    return ", ".join(
        f'"{k}": {_num_or_null(f, v)}' for k, f, v in zip(_GEO_KEYS, _GEO_FMT, vals, strict=True)
    )


_JSON_POS = (
    _JSON_HEAD
    + f'"target_pos_ned_m": [{_P}, {_P}, {_P}], "vehicle_pos_ned_m": [{_P}, {_P}, {_P}], '
    + _JSON_TAIL
)
_JSON_NO_POS = _JSON_HEAD + '"target_pos_ned_m": null, "vehicle_pos_ned_m": null, ' + _JSON_TAIL


def _num_or_null(fmt: str, v: float | None) -> str:
    return "null" if v is None or not math.isfinite(v) else fmt % v


_GEO_NULL = _geo_json(None)  # (the map fields when the target's position is unknown)

_VEC3 = {f: f"[{f}, {f}, {f}]" for f in (_P, _V)}


def _vec_or_null(fmt: str, v: Any, c: list[float] | None = None) -> str:
    """``v`` (a vector, or ``None``) in JSON; ``c``: its values as a list, when known."""
    if v is None:
        return "null"
    if len(v) == 3:
        if c is None:
            c = v.tolist() if hasattr(v, "tolist") else list(v)
        if math.isfinite(c[0] + c[1] + c[2]):  # (the same text as term by term, one format)
            return _VEC3[fmt] % (c[0], c[1], c[2])
    return "[" + ", ".join(_num_or_null(fmt, float(c)) for c in v) + "]"


_PLACEHOLDER = re.compile(r"%(?:\.\d+)?[fgds]")


def _format_checked(template: str, vals: tuple[Any, ...]) -> str:
    """``template % vals`` with every non-finite number written as ``null``."""
    fmts = _PLACEHOLDER.findall(template)
    parts = tuple(
        "null" if f[-1] in "fg" and not math.isfinite(v) else f % v
        for f, v in zip(fmts, vals, strict=True)
    )
    return _PLACEHOLDER.sub("%s", template) % parts
