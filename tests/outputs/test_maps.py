"""Replay's exports for maps (mav_observer/outputs/maps.py, replay --geojson / --kml)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import geojson
import numpy as np
import pytest

from mav_observer.core.samples import Estimate, Status
from mav_observer.geo.geodesy import Origin, to_geodetic
from mav_observer.outputs import maps as mapexport
from mav_observer.outputs.records import EstimateRecord
from sim import scenarios
from sim.emitter import Emitter, EmitterConfig, run
from sim.inject import split_records

ORIGIN = Origin(-35.363261, 149.16523, 584.0, "GLOBAL_POSITION_INT")
KML = "{http://www.opengis.net/kml/2.2}"


def _records(n: int = 120, origin: Origin | None = ORIGIN) -> list[EstimateRecord]:
    """A vehicle circling a target at (40, 30, 0) at 10 Hz for ``n / 10`` s, the estimate's
    1-sigma shrinking from 2 m."""
    out = []
    for k in range(n):
        t = 100.0 + 0.1 * k
        veh = (40.0 + 15.0 * math.cos(0.1 * t), 30.0 + 15.0 * math.sin(0.1 * t), -10.0)
        x = np.array([40.0 - veh[0], 30.0 - veh[1], 10.0])
        sd = np.array([2.0, 1.0, 1.5]) / (1.0 + 0.1 * k)
        est = Estimate(t, x, np.zeros(3), float(np.linalg.norm(x)), 0.3, 2.0,
                       Status.CONVERGED, True, 0.0, 0.0, 0.0, x_std_m=sd)  # fmt: skip
        out.append(EstimateRecord(1.7e9 + t, t, 1, "gimbal", "G", est, veh, origin))
    return out


def _tracks(records: list[EstimateRecord]) -> mapexport.MapTracks:
    m = mapexport.MapTracks()
    for r in records:
        m.add(r)
    return m


def test_the_geojson_is_valid_and_holds_track_estimates_ellipses_and_the_final_estimate() -> None:
    doc = mapexport.geojson(_tracks(_records()))
    g = geojson.loads(json.dumps(doc))
    assert g.is_valid, g.errors()
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    assert kinds.count("vehicle_track") == 1 and kinds.count("target_estimates") == 1
    assert kinds.count("uncertainty_2sigma") == 2  # 12 s: one per 10 s
    assert kinds.count("final_estimate") == 1 and kinds.count("final_uncertainty_2sigma") == 1
    fin = next(f for f in doc["features"] if f["properties"]["kind"] == "final_estimate")
    lat, lon, alt = to_geodetic(ORIGIN, (40.0, 30.0, 0.0))
    assert fin["geometry"]["coordinates"] == pytest.approx([lon, lat, alt])
    assert fin["properties"]["h_std_m"] == pytest.approx(math.hypot(2.0, 1.0) / 12.9)
    track = next(f for f in doc["features"] if f["properties"]["kind"] == "vehicle_track")
    assert len(track["geometry"]["coordinates"]) == 12  # one point per second
    ring = next(
        f for f in doc["features"] if f["properties"]["kind"] == "final_uncertainty_2sigma"
    )["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and len(ring) == mapexport.ELLIPSE_POINTS + 1
    # counter-clockwise (RFC 7946), and twice the 1-sigma north and east from the centre
    xy = np.array([[(p[0] - lon) * math.cos(math.radians(lat)), p[1] - lat] for p in ring])
    area = 0.5 * np.sum(xy[:-1, 0] * xy[1:, 1] - xy[1:, 0] * xy[:-1, 1])
    assert area > 0.0
    north_m = (max(p[1] for p in ring) - lat) * math.pi / 180 * 6.357e6
    assert north_m == pytest.approx(2.0 * 2.0 / 12.9, rel=0.01)


def test_the_kml_parses_with_the_target_placemark() -> None:
    root = ET.fromstring(mapexport.kml(_tracks(_records()), name="flight.tlog"))
    names = [p.findtext(f"{KML}name") for p in root.iter(f"{KML}Placemark")]
    assert names == ["vehicle track", "target estimates", "target gimbal",
                     "target gimbal: 2-sigma uncertainty"]  # fmt: skip
    pm = next(
        p for p in root.iter(f"{KML}Placemark") if p.findtext(f"{KML}name") == "target gimbal"
    )
    lon, lat, alt = (float(v) for v in pm.find(f"{KML}Point/{KML}coordinates").text.split(","))
    lat_t, lon_t, alt_t = to_geodetic(ORIGIN, (40.0, 30.0, 0.0))
    assert (lat, lon) == pytest.approx((lat_t, lon_t), abs=1e-7)  # 8 decimals written
    assert alt == pytest.approx(alt_t, abs=1e-3)
    assert "status converged" in pm.findtext(f"{KML}description")


def test_records_without_an_origin_leave_the_map_empty() -> None:
    m = _tracks(_records(origin=None))
    assert not m
    assert mapexport.geojson(m) == {"type": "FeatureCollection", "features": []}


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mav_observer", *args],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip


@pytest.mark.slow
def test_replay_writes_both_maps_or_says_why_not(tmp_path: Path) -> None:
    tl = tmp_path / "orbit.tlog"
    run(Emitter(scenarios.orbit(duration_s=60.0), EmitterConfig(duration_s=60.0, seed=2)), tlog=tl)
    gj, km = tmp_path / "m.geojson", tmp_path / "m.kml"
    proc = _cli("replay", str(tl), "-q", "--geojson", str(gj), "--kml", str(km))
    assert proc.returncode == 0, proc.stderr
    assert geojson.loads(gj.read_text()).is_valid
    assert any(p.findtext(f"{KML}name") == "target gimbal"
               for p in ET.parse(km).getroot().iter(f"{KML}Placemark"))  # fmt: skip
    # the same flight without GLOBAL_POSITION_INT (no origin): nothing written, exit 3
    bare = tmp_path / "bare.tlog"
    run(Emitter(scenarios.orbit(duration_s=20.0), EmitterConfig(duration_s=20.0, seed=2)),
        tlog=bare)  # fmt: skip
    recs = split_records(bare.read_bytes())
    keep = [r.data for r in recs if r.msgid != 33]  # GLOBAL_POSITION_INT dropped
    assert len(keep) < len(recs)
    bare.write_bytes(b"".join(keep))
    gj.unlink()
    proc = _cli("replay", str(bare), "-q", "--geojson", str(gj))
    assert proc.returncode == 3 and "no map written" in proc.stderr
    assert not gj.exists()
