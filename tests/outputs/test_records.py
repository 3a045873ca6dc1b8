"""The estimate record (schema 1, docs/schema.md)."""

import json
import math

import numpy as np
import pytest

from mav_observer.core.samples import Estimate, Status
from mav_observer.geo.geodesy import Origin, to_geodetic
from mav_observer.outputs.records import CSV_COLUMNS, SCHEMA_VERSION, EstimateRecord

REQUIRED = {
    "schema", "t_unix_s", "sysid", "target", "rel_pos_ned_m", "range_m", "bias_ned_mps",
    "target_pos_ned_m", "pe", "cond_m", "status",
}  # fmt: skip


def _est(cond: float = 3.0) -> Estimate:
    return Estimate(
        12.5, np.array([3.0, 4.0, 12.0]), np.array([0.1, -0.2, 0.0]), 13.0, 0.25, cond,
        Status.NOT_OBSERVABLE, True, 0.0, 0.05, 0.01,
    )  # fmt: skip


def test_record_fields_and_meaning() -> None:
    r = EstimateRecord(
        1_767_225_600.5,
        12.5,
        7,
        "gimbal",
        "GIMBAL_DEVICE_ATTITUDE_STATUS",
        _est(),
        (10.0, 20.0, -15.0),
    )
    d = r.to_dict()
    assert d.keys() >= REQUIRED
    assert d["schema"] == SCHEMA_VERSION == 1
    assert d["rel_pos_ned_m"] == [3.0, 4.0, 12.0]
    assert d["target_pos_ned_m"] == [13.0, 24.0, -3.0]  # vehicle + (target - vehicle)
    assert d["status"] == "not observable"
    assert json.loads(r.to_json()) == d  # these values are exact at the JSON resolution


def test_no_position_and_non_finite_values_give_null() -> None:
    r = EstimateRecord(1.0, 2.0, 1, "camera", "CAMERA_TRACKING_IMAGE_STATUS", _est(math.inf), None)
    d = json.loads(r.to_json())
    assert d["target_pos_ned_m"] is None and d["vehicle_pos_ned_m"] is None
    assert d["cond_m"] is None
    assert d == {**r.to_dict(), "cond_m": None}


def test_csv_row_matches_the_columns() -> None:
    r = EstimateRecord(1.0, 2.0, 1, "mount", "MOUNT_ORIENTATION", _est(), (1.0, 1.0, 1.0))
    row = r.csv_row()
    assert len(row) == len(CSV_COLUMNS)
    named = dict(zip(CSV_COLUMNS, row, strict=True))
    assert (
        named["rel_pos_d_m"] == 12.0 and named["target_pos_e_m"] == 5.0 and named["corrected"] == 1
    )


def _close(a: object, b: object, tol: float) -> bool:
    if isinstance(a, list):
        return isinstance(b, list) and all(_close(p, q, tol) for p, q in zip(a, b, strict=True))
    if isinstance(a, float):
        return abs(a - b) <= tol  # type: ignore[operator]
    return a == b


def test_json_is_the_dict_rounded_to_the_documented_resolution() -> None:
    rng = np.random.default_rng(7)
    tol = {"t_unix_s": 5e-7, "t_boot_s": 5e-7, "bias_ned_mps": 5e-6}
    tol |= {"target_lat_deg": 5e-9, "target_lon_deg": 5e-9}
    for _ in range(200):
        x = rng.normal(0.0, 300.0, 3)
        est = Estimate(
            float(rng.uniform(0, 1e4)), x, rng.normal(0.0, 2.0, 3), float(np.linalg.norm(x)),
            float(rng.uniform(0, 1)) ** 6, float(rng.uniform(1, 1e4)), Status.CONVERGING,
            bool(rng.integers(2)), 0.0, 0.0, 0.0,
        )  # fmt: skip
        if rng.integers(2):
            est = est._replace(x_std_m=np.abs(rng.normal(0.0, 3.0, 3)))
        vpos = None if rng.integers(4) == 0 else tuple(rng.normal(0.0, 500.0, 3).tolist())
        origin = ORIGIN if rng.integers(2) else None
        r = EstimateRecord(
            1.7e9 + float(rng.uniform(0, 1e7)), est.t_s, 3, "gimbal", "G", est, vpos, origin
        )
        d, j = r.to_dict(), json.loads(r.to_json())
        assert j.keys() == d.keys()
        for key, value in d.items():
            if key in ("pe", "cond_m"):  # 6 significant digits
                assert math.isclose(j[key], value, rel_tol=6e-6), key
            else:
                assert _close(j[key], value, tol.get(key, 5e-5)), (key, j[key], value)


def test_non_finite_with_a_position_gives_null_only_where_it_is() -> None:
    est = Estimate(
        12.5, np.array([3.0, math.nan, 12.0]), np.array([0.1, -0.2, 0.0]), math.nan, 0.25, 3.0,
        Status.STALE, False, 0.0, 0.05, 0.01,
    )  # fmt: skip
    r = EstimateRecord(1.0, 2.0, 1, "gimbal", "G", est, (1.0, 2.0, 3.0))
    d = json.loads(r.to_json())
    assert d["rel_pos_ned_m"] == [3.0, None, 12.0] and d["range_m"] is None
    assert d["target_pos_ned_m"] == [4.0, None, 15.0]
    assert d["vehicle_pos_ned_m"] == [1.0, 2.0, 3.0] and d["corrected"] is False


ORIGIN = Origin(-35.3632621, 149.1652374, 584.09, "HOME_POSITION")


def test_the_target_on_the_map_once_the_origin_is_known() -> None:
    """With an origin: the target's latitude, longitude and altitude are the local target
    position's (vehicle + relative) on WGS84, the horizontal 1-sigma the root sum of the
    north and east ones, the vertical the down one; in JSON, the dict and CSV alike. Without
    an origin (or a vehicle position) they are null."""
    est = _est()._replace(x_std_m=np.array([0.3, 0.4, 1.2]))
    r = EstimateRecord(1.0, 2.0, 1, "gimbal", "G", est, (10.0, 20.0, -15.0), ORIGIN)
    lat, lon, alt = to_geodetic(ORIGIN, (13.0, 24.0, -3.0))
    d = r.to_dict()
    assert (d["target_lat_deg"], d["target_lon_deg"], d["target_alt_m"]) == (lat, lon, alt)
    assert alt == pytest.approx(584.09 + 3.0, abs=1e-3)  # 3 m above the origin
    assert d["target_h_std_m"] == pytest.approx(0.5) and d["target_v_std_m"] == 1.2
    j = json.loads(r.to_json())
    assert j["target_lat_deg"] == pytest.approx(lat, abs=5e-9)
    assert j["target_h_std_m"] == pytest.approx(0.5)
    named = dict(zip(CSV_COLUMNS, r.csv_row(), strict=True))
    assert named["target_lon_deg"] == lon and named["target_v_std_m"] == 1.2
    for no in (
        EstimateRecord(1.0, 2.0, 1, "gimbal", "G", est, (10.0, 20.0, -15.0)),
        EstimateRecord(1.0, 2.0, 1, "gimbal", "G", est, None, ORIGIN),
    ):
        j = json.loads(no.to_json())
        assert [j[k] for k in ("target_lat_deg", "target_lon_deg", "target_alt_m")] == [None] * 3
        assert no.to_dict()["target_h_std_m"] is None


def test_a_non_finite_standard_deviation_is_null_alone_and_the_map_fields_without_one() -> None:
    """The vectors and the map fields written in one format when every value is known fall
    back to value by value otherwise: a NaN sigma is null where it is, and without sigmas the
    target is still on the map with null sigmas."""
    est = _est()._replace(x_std_m=np.array([0.3, math.nan, 1.2]), a_std_mps=np.array([0.01] * 3))
    j = json.loads(
        EstimateRecord(1.0, 2.0, 1, "gimbal", "G", est, (1.0, 2.0, 3.0), ORIGIN).to_json()
    )
    assert j["rel_pos_std_ned_m"] == [0.3, None, 1.2] and j["bias_std_ned_mps"] == [0.01] * 3
    assert j["target_h_std_m"] is None and j["target_v_std_m"] == 1.2
    assert j["target_lat_deg"] is not None and j["target_alt_m"] is not None
    j = json.loads(
        EstimateRecord(1.0, 2.0, 1, "gimbal", "G", _est(), (1.0, 2.0, 3.0), ORIGIN).to_json()
    )
    assert j["rel_pos_std_ned_m"] is None
    assert j["target_h_std_m"] is None and j["target_v_std_m"] is None
    assert j["target_lon_deg"] == pytest.approx(to_geodetic(ORIGIN, (4.0, 6.0, 15.0))[1], abs=5e-9)
