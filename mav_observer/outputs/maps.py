"""Replay's exports for maps: GeoJSON (RFC 7946) and KML, from the estimate records
(``replay --geojson FILE``, ``--kml FILE``; ``docs/geolocation.md``).

For every target (``sysid/target``) whose records carry a place on the map (the local frame's
origin known, :mod:`mav_observer.geo.geodesy`):

* the vehicle's track (a line, one point per :data:`EVERY_S`);
* the target's estimates over time (a line through them, and every :data:`ELLIPSE_EVERY_S`
  the horizontal uncertainty ellipse, 2 sigma, with its time);
* the final estimate (a point with its latitude, longitude, altitude AMSL, 1-sigma
  uncertainties, status and time) and its 2-sigma ellipse.

The ellipse is axis-aligned north-east with half-axes twice the records' per-axis standard
deviations (the records carry no north-east correlation), :data:`ELLIPSE_POINTS` vertices,
each placed with :func:`mav_observer.geo.geodesy.to_geodetic`. Pure: builds a dictionary and a
string; the caller writes them.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Any

from mav_observer.geo.geodesy import Origin, to_geodetic
from mav_observer.outputs.records import EstimateRecord

#: One point of each track per this many seconds (s, autopilot clock).
EVERY_S = 1.0
#: One uncertainty ellipse of the estimates over time per this many seconds (s).
ELLIPSE_EVERY_S = 10.0
#: Vertices of an ellipse (the ring closes on the first).
ELLIPSE_POINTS = 36
#: The ellipses' size in standard deviations.
ELLIPSE_SIGMA = 2.0


@dataclass
class _Track:
    sysid: int
    target: str
    source: str
    vehicle: list[tuple[float, float, float]] = field(default_factory=list)
    estimates: list[tuple[float, float, float, float]] = field(default_factory=list)  # t,...
    ellipses: list[tuple[float, list[tuple[float, float]]]] = field(default_factory=list)
    last: EstimateRecord | None = None
    t_point: float = -math.inf
    t_ellipse: float = -math.inf


def ellipse(
    origin: Origin, center_ned_m: tuple[float, float, float], std_n_m: float, std_e_m: float
) -> list[tuple[float, float]]:
    """The closed ring (longitude, latitude deg) of the axis-aligned ellipse of half-axes
    :data:`ELLIPSE_SIGMA` times ``std_n_m`` and ``std_e_m`` around ``center_ned_m``,
    counter-clockwise (RFC 7946's right-hand rule for an exterior ring)."""
    n0, e0, d0 = center_ned_m
    ring = []
    for k in range(ELLIPSE_POINTS):
        th = 2.0 * math.pi * k / ELLIPSE_POINTS  # north, then west: counter-clockwise
        n = n0 + ELLIPSE_SIGMA * std_n_m * math.cos(th)
        e = e0 - ELLIPSE_SIGMA * std_e_m * math.sin(th)
        lat, lon, _ = to_geodetic(origin, (n, e, d0))
        ring.append((lon, lat))
    ring.append(ring[0])
    return ring


class MapTracks:
    """Collects what the map needs from the estimate records, thinned in time."""

    def __init__(self) -> None:
        self.tracks: dict[str, _Track] = {}

    def add(self, r: EstimateRecord) -> None:
        """One estimate record (those without a place on the map are ignored)."""
        if r.origin is None or r.vehicle_pos_ned_m is None:
            return
        key = f"{r.sysid}/{r.target}"
        tr = self.tracks.get(key)
        if tr is None:
            tr = self.tracks[key] = _Track(r.sysid, r.target, r.source)
        tr.last = r
        t = r.t_boot_s
        if t < tr.t_point + EVERY_S and t >= tr.t_point:
            return
        geo = r.target_geodetic()
        if geo is None or not all(math.isfinite(v) for v in geo[:3]):
            return
        tr.t_point = t
        lat_v, lon_v, alt_v = to_geodetic(r.origin, r.vehicle_pos_ned_m)
        tr.vehicle.append((lon_v, lat_v, alt_v))
        tr.estimates.append((t, geo[1], geo[0], geo[2]))
        sd = r.estimate.x_std_m
        tp = r.target_pos_ned_m
        if (
            sd is not None
            and tp is not None
            and not tr.t_ellipse <= t < tr.t_ellipse + ELLIPSE_EVERY_S
        ):
            tr.t_ellipse = t
            tr.ellipses.append((t, ellipse(r.origin, tp, float(sd[0]), float(sd[1]))))

    def __bool__(self) -> bool:
        return any(tr.estimates for tr in self.tracks.values())


def final_estimate(tr: _Track) -> tuple[dict[str, Any], list[tuple[float, float]] | None] | None:
    """A target's final estimate: its properties and its 2-sigma ellipse ring (``None``
    without one), or ``None``."""
    r = tr.last
    if r is None or r.origin is None:
        return None
    geo = r.target_geodetic()
    if geo is None or not all(math.isfinite(v) for v in geo[:3]):
        return None
    lat, lon, alt, h_sd, v_sd = geo
    props = {
        "kind": "final_estimate",
        "sysid": tr.sysid,
        "target": tr.target,
        "source": tr.source,
        "t_boot_s": r.t_boot_s,
        "t_unix_s": r.t_unix_s,
        "lat_deg": lat,
        "lon_deg": lon,
        "alt_m": alt,
        "h_std_m": h_sd,
        "v_std_m": v_sd,
        "status": str(r.estimate.status),
        "origin_source": r.origin.source,
    }
    sd, tp = r.estimate.x_std_m, r.target_pos_ned_m
    ring = None
    if sd is not None and tp is not None:
        ring = ellipse(r.origin, tp, float(sd[0]), float(sd[1]))
    return props, ring


def geojson(tracks: MapTracks) -> dict[str, Any]:
    """A GeoJSON FeatureCollection (RFC 7946: [longitude, latitude, altitude] in degrees and
    metres AMSL) of every target's vehicle track, estimates, ellipses and final estimate."""
    features: list[dict[str, Any]] = []

    def feature(geometry: dict[str, Any], **props: Any) -> None:
        features.append({"type": "Feature", "geometry": geometry, "properties": props})

    for tr in tracks.tracks.values():
        if not tr.estimates:
            continue
        base = {"sysid": tr.sysid, "target": tr.target}
        if len(tr.vehicle) >= 2:
            feature({"type": "LineString", "coordinates": [list(p) for p in tr.vehicle]},
                    kind="vehicle_track", **base)  # fmt: skip
        pts = [[lon, lat, alt] for _, lon, lat, alt in tr.estimates]
        times = [t for t, *_ in tr.estimates]
        if len(pts) >= 2:
            feature({"type": "LineString", "coordinates": pts}, kind="target_estimates",
                    t_boot_s=times, **base)  # fmt: skip
        for t, ring in tr.ellipses:
            feature({"type": "Polygon", "coordinates": [[list(p) for p in ring]]},
                    kind="uncertainty_2sigma", t_boot_s=t, **base)  # fmt: skip
        fin = final_estimate(tr)
        if fin is not None:
            props, ring = fin
            feature({"type": "Point", "coordinates": [props["lon_deg"], props["lat_deg"],
                                                      props["alt_m"]]}, **props)  # fmt: skip
            if ring is not None:
                feature({"type": "Polygon", "coordinates": [[list(p) for p in ring]]},
                        kind="final_uncertainty_2sigma", **base)  # fmt: skip
    return {"type": "FeatureCollection", "features": features}


def kml(tracks: MapTracks, name: str = "mav-observer") -> str:
    """A KML 2.2 document (Google Earth, QGIS) of the same: a folder per target with the
    vehicle's track, the estimates' track, the final estimate's placemark and its ellipse."""
    ns = "http://www.opengis.net/kml/2.2"
    root = ET.Element("kml", xmlns=ns)
    doc = ET.SubElement(root, "Document")
    ET.SubElement(doc, "name").text = name

    def coords(points: list[tuple[float, ...]]) -> str:
        return " ".join(",".join(f"{v:.8f}" if i < 2 else f"{v:.3f}" for i, v in enumerate(p))
                        for p in points)  # fmt: skip

    def line(parent: ET.Element, title: str, points: list[tuple[float, ...]]) -> None:
        pm = ET.SubElement(parent, "Placemark")
        ET.SubElement(pm, "name").text = title
        ls = ET.SubElement(pm, "LineString")
        ET.SubElement(ls, "altitudeMode").text = "absolute"
        ET.SubElement(ls, "coordinates").text = coords(points)

    for tr in tracks.tracks.values():
        if not tr.estimates:
            continue
        folder = ET.SubElement(doc, "Folder")
        ET.SubElement(folder, "name").text = f"vehicle {tr.sysid} {tr.target}"
        if len(tr.vehicle) >= 2:
            line(folder, "vehicle track", tr.vehicle)
        if len(tr.estimates) >= 2:
            line(folder, "target estimates", [(lon, lat, alt) for _, lon, lat, alt in tr.estimates])
        fin = final_estimate(tr)
        if fin is None:
            continue
        props, ring = fin
        pm = ET.SubElement(folder, "Placemark")
        ET.SubElement(pm, "name").text = f"target {tr.target}"
        sd = "" if props["h_std_m"] is None else f" +-{props['h_std_m']:.2f} m (1 sigma)"
        ET.SubElement(pm, "description").text = (
            f"{props['lat_deg']:.7f} {props['lon_deg']:.7f} {props['alt_m']:.1f} m AMSL{sd}, "
            f"status {props['status']}, t_boot {props['t_boot_s']:.2f} s, origin from "
            f"{props['origin_source']}"
        )
        pt = ET.SubElement(pm, "Point")
        ET.SubElement(pt, "altitudeMode").text = "absolute"
        ET.SubElement(pt, "coordinates").text = coords(
            [(props["lon_deg"], props["lat_deg"], props["alt_m"])]
        )
        if ring is not None:
            pm = ET.SubElement(folder, "Placemark")
            ET.SubElement(pm, "name").text = f"target {tr.target}: 2-sigma uncertainty"
            poly = ET.SubElement(pm, "Polygon")
            ET.SubElement(poly, "altitudeMode").text = "clampToGround"
            outer = ET.SubElement(ET.SubElement(poly, "outerBoundaryIs"), "LinearRing")
            ET.SubElement(outer, "coordinates").text = coords([(lon, lat) for lon, lat in ring])
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode")
