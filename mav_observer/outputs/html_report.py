"""The map report of a replay (``mav-observer replay LOG --html report.html``): one HTML file
that opens from disk with no server and nothing fetched.

Leaflet (vendored), the page's script and the data are inlined: every target's estimates over
time (north, east, their 1-sigma, status, range) and each vehicle's track with its heading,
thinned to one point per :data:`EVERY_S` of the autopilot's clock; a time slider shows each
target's estimate and sigma ellipses at that time and how it got there; the summary's text and
the report plot (when matplotlib is installed) below.

The same page shows a fleet's fusion after a flight (``mav-observer fuse --rays ... --html``):
:class:`FusedReportData` keeps each vehicle's positions from its rays and each fused target's
estimates, in the north-east-down frame of the first ray's position, on the rays' Unix clock.
"""

from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mav_observer.outputs.records import EstimateRecord
from mav_observer.outputs.web import static_file

#: The report keeps one estimate per target and one vehicle position per this long (s).
EVERY_S = 0.2


@dataclass
class ReportData:
    """What the report shows, collected from the estimate records as replay writes them."""

    targets: dict[str, list[list[Any]]] = field(default_factory=dict)
    vehicles: dict[int, list[list[Any]]] = field(default_factory=dict)
    origins: dict[int, dict[str, Any]] = field(default_factory=dict)
    _last: dict[str, float] = field(default_factory=dict)

    def add(self, r: EstimateRecord, yaw_rad: float | None = None) -> None:
        key = f"{r.sysid}/{r.target}"
        t = r.t_boot_s
        if r.origin is not None and r.sysid not in self.origins:
            self.origins[r.sysid] = r.origin.to_dict()
        tp = r.target_pos_ned_m
        if tp is not None and _due(self._last, key, t):
            sd = r.estimate.x_std_m
            sn, se = (None, None) if sd is None else (_r(sd[0]), _r(sd[1]))
            row = [_r(t), _r(tp[0]), _r(tp[1]), sn, se, str(r.estimate.status),
                   _r(r.estimate.range_m)]  # fmt: skip
            self.targets.setdefault(key, []).append(row)
        vp = r.vehicle_pos_ned_m
        if vp is not None and _due(self._last, f"vehicle/{r.sysid}", t):
            yaw = None if yaw_rad is None else _r(math.degrees(yaw_rad))
            self.vehicles.setdefault(r.sysid, []).append([_r(t), _r(vp[0]), _r(vp[1]), yaw])

    def to_dict(self) -> dict[str, Any]:
        times = [row[0] for rows in self.targets.values() for row in (rows[0], rows[-1])]
        return {
            "clock": "t_boot",
            "t0": min(times, default=0.0),
            "t1": max(times, default=0.0),
            "targets": {k: {"series": rows} for k, rows in self.targets.items()},
            "vehicles": {
                str(s): {"track": rows, "origin": self.origins.get(s)}
                for s, rows in self.vehicles.items()
            },
        }


@dataclass
class FusedReportData:
    """What the report of a fusion shows: each vehicle's ray positions and each fused target's
    estimates, one per :data:`EVERY_S`, north and east (m) of the first ray's position, time
    (s) from the first ray."""

    targets: dict[str, list[list[Any]]] = field(default_factory=dict)
    vehicles: dict[int, list[list[Any]]] = field(default_factory=dict)
    origin: tuple[float, float, float] | None = None
    t0: float | None = None
    _last: dict[str, float] = field(default_factory=dict)

    def _ne(self, lat: float, lon: float, alt: float) -> tuple[float, float]:
        import pymap3d

        if self.origin is None:
            self.origin = (lat, lon, alt)
        n, e, _ = pymap3d.geodetic2ned(lat, lon, alt, *self.origin)
        return float(n), float(e)

    def add_ray(self, ray: Any) -> None:
        """A vehicle's ray (:class:`~mav_observer.fleet.rays.Ray`): where the vehicle was."""
        if self.t0 is None:
            self.t0 = ray.t_unix_s
        if _due(self._last, f"vehicle/{ray.sysid}", ray.t_unix_s):
            n, e = self._ne(ray.lat_deg, ray.lon_deg, ray.alt_m)
            self.vehicles.setdefault(ray.sysid, []).append([_r(ray.t_unix_s - self.t0),
                                                           _r(n), _r(e), None])  # fmt: skip

    def add_fused(self, est: Any) -> None:
        """A fused estimate (:class:`~mav_observer.fleet.fusion.FusedEstimate`)."""
        if est.geodetic is None or self.t0 is None:
            return
        if not _due(self._last, f"fused/{est.name}", est.t_unix_s):
            return
        n, e = self._ne(*est.geodetic)
        sd = est.std_ned_m
        sn, se = (None, None) if sd is None else (_r(sd[0]), _r(sd[1]))
        rng = math.nan if est.range_m is None else est.range_m
        self.targets.setdefault(est.name, []).append(
            [_r(est.t_unix_s - self.t0), _r(n), _r(e), sn, se, est.status, _r(rng)]
        )

    def to_dict(self) -> dict[str, Any]:
        times = [row[0] for rows in self.targets.values() for row in (rows[0], rows[-1])]
        o = self.origin
        origin = None if o is None else {"lat_deg": o[0], "lon_deg": o[1], "alt_m": o[2],
                                         "source": "the first ray", "frame": "wgs84"}  # fmt: skip
        return {
            "clock": "t from the first ray",
            "t0": min(times, default=0.0),
            "t1": max(times, default=0.0),
            "targets": {f"fused/{k}": {"series": rows} for k, rows in self.targets.items()},
            "vehicles": {
                str(s): {"track": rows, "origin": origin} for s, rows in self.vehicles.items()
            },
        }


def _due(last: dict[str, float], key: str, t: float) -> bool:
    """Whether ``key`` gains a point at ``t``: EVERY_S after its last one (or its clock went
    back), noting the time in ``last``."""
    if 0.0 <= t - last.get(key, -math.inf) < EVERY_S:
        return False
    last[key] = t
    return True


def _r(v: float) -> float | None:
    """A number for the page: 3 decimals (mm, ms), ``None`` if not finite."""
    return round(float(v), 3) if math.isfinite(v) else None


def write_html(
    path: Path,
    data: ReportData | FusedReportData,
    title: str,
    summary_text: str,
    plot_png: bytes | None,
) -> None:
    """The report: the page with everything inlined (``</`` escaped inside the scripts)."""
    payload = json.dumps(data.to_dict(), separators=(",", ":")).replace("</", "<\\/")

    def script(name: str) -> str:
        return static_file(name).decode().replace("</script", "<\\/script")

    plot = ""
    if plot_png is not None:
        b64 = base64.b64encode(plot_png).decode()
        plot = f'<img alt="report plot" style="max-width:100%" src="data:image/png;base64,{b64}">'
    page = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}: mav-observer report</title>
<style>{static_file("leaflet.css").decode()}</style>
<style>
body {{ margin: 0; font: 13px/1.35 system-ui, sans-serif; }}
#top {{ display: flex; height: 70vh; }} #map {{ flex: 1; background: #f4f4f0; }}
#side {{ width: 420px; overflow: auto; padding: 8px 12px; border-left: 1px solid #ccc; }}
table {{ border-collapse: collapse; width: 100%; }}
td, th {{ border-bottom: 1px solid #e4e4e4; padding: 3px 4px; text-align: left; }}
.converged {{ color: #1a7f37; font-weight: 600; }} .converging {{ color: #9a6700; }}
.stale, .not_observable {{ color: #cf222e; }} .muted {{ color: #777; }}
.grid-label {{ font-size: 10px; color: #888; background: none; border: none; box-shadow: none; }}
#bottom {{ padding: 8px 12px; }} pre {{ white-space: pre-wrap; }}
</style></head><body>
<div id="top"><div id="map"></div><div id="side">
<h1 style="font-size:15px">{html.escape(title)}</h1>
<div id="origin" class="muted">origin: unknown (local frame, metres)</div>
<p><input id="slider" type="range" style="width:100%"> <span id="t"></span></p>
<table id="targets"><thead><tr><th>target</th><th>status</th><th>range</th>
<th>north, east (m)</th><th>1 sigma (m)</th><th>time</th></tr></thead><tbody></tbody></table>
<p class="muted">Ellipses: 1 and 2 sigma of the target's position. Thin line: how the estimate
moved up to the slider's time. Leaflet (BSD 2-clause), inlined.</p>
<span id="latency" hidden></span><span id="count" hidden></span>
</div></div>
<div id="bottom"><pre>{html.escape(summary_text)}</pre>{plot}</div>
<script>window.REPORT = {payload};</script>
<script>{script("leaflet.js")}</script>
<script>{script("map.js")}</script>
</body></html>
"""
    path.write_text(page, encoding="utf-8")
