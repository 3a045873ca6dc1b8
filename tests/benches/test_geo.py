"""The target on the map on the shared SITL log (bench/accuracy/geo.py)."""

from __future__ import annotations

import json

import pytest

from bench.accuracy.geo import LOG, score_log
from mav_observer.tracking.tracker import TrackerConfig
from sim.tlogs import find_tlogs


def test_the_sitl_logs_region_of_interest_is_found_on_the_map() -> None:
    """Its gimbal's angles read as body angles: the published latitude and longitude are
    within 1.5 m of the ROI (median over the last third), the origin from the log's
    GPS_GLOBAL_ORIGIN, and the horizontal 1-sigma honest (80 % or more within twice it)."""
    log = find_tlogs() / LOG
    if not log.is_file():
        pytest.fail(f"the shared log {log} is missing")
    meta = json.loads(log.with_suffix(".json").read_text())
    r = score_log(log, meta, TrackerConfig(gimbal_angles="body"))
    assert r["origin"] == "GPS_GLOBAL_ORIGIN"
    assert r["h_median_m"] < 1.5, r
    assert r["v_median_m"] < 0.5, r
    assert r["within_2sd"] > 0.8, r
    # its bearings' errors repeat every orbit and the estimate keeps moving: the product never
    # declares it converged (so never sends it to the autopilot), and nothing is "after
    # convergence"
    assert r["converged_n"] == 0, r
    assert r["after_convergence_n"] == 0 and r["within_2sd_after_convergence"] is None, r
