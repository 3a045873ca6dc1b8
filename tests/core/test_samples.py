"""Validation of the sample records at the boundary."""

import json
import math

import numpy as np
import pytest

from mav_observer.core.samples import BearingSample, Estimate, Status, VelocitySample
from mav_observer.errors import InvalidSampleError, MavObserverError


def test_velocity_sample_is_frozen_copy() -> None:
    src = np.array([1.0, 2.0, 3.0])
    s = VelocitySample(1.5, src)
    src[0] = 99.0
    assert s.v_mps.tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(ValueError, match="read-only"):
        s.v_mps[0] = 5.0


@pytest.mark.parametrize(
    ("value", "match"),
    [
        ([1.0, math.nan, 0.0], "non-finite"),
        ([1.0, math.inf, 0.0], "non-finite"),
        ([1.0], "dimension >= 2"),
        ([[1.0, 2.0], [3.0, 4.0]], "dimension >= 2"),
        ("abc", "not a numeric vector"),
    ],
)
def test_velocity_sample_rejects_bad_vectors(value: object, match: str) -> None:
    with pytest.raises(InvalidSampleError, match=match):
        VelocitySample(0.0, value)  # type: ignore[arg-type]


@pytest.mark.parametrize("t", [math.nan, math.inf, "1.0", True, None])
def test_sample_time_must_be_a_finite_number(t: object) -> None:
    with pytest.raises(InvalidSampleError, match="t_s"):
        VelocitySample(t, [0.0, 0.0, 0.0])  # type: ignore[arg-type]
    with pytest.raises(InvalidSampleError, match="t_s"):
        BearingSample(t, [0.0, 0.0, 1.0])  # type: ignore[arg-type]


def test_bearing_zero_length_is_rejected_naming_value() -> None:
    with pytest.raises(InvalidSampleError, match=r"y=\[0.0, 0.0, 0.0\].*zero length"):
        BearingSample(2.0, [0.0, 0.0, 0.0])


def test_bearing_far_from_unit_is_rejected() -> None:
    with pytest.raises(InvalidSampleError, match=r"far from unit length \(\|y\|=2"):
        BearingSample(2.0, [0.0, 2.0, 0.0])


def test_slightly_off_unit_bearing_is_normalised() -> None:
    s = BearingSample(0.0, [0.0, 0.0, 1.005])
    assert s.y.tolist() == [0.0, 0.0, 1.0]
    s2 = BearingSample(0.0, [0.6, 0.8 * 0.999, 0.0])
    assert abs(np.linalg.norm(s2.y) - 1.0) < 1e-15


def test_bearing_from_any_vector() -> None:
    s = BearingSample.from_vector(3.0, [0.0, -3.0, 4.0])
    assert np.allclose(s.y, [0.0, -0.6, 0.8])
    with pytest.raises(InvalidSampleError, match="no usable length"):
        BearingSample.from_vector(3.0, [0.0, 0.0, 0.0])


def test_errors_share_the_project_base_class() -> None:
    with pytest.raises(MavObserverError):
        BearingSample(0.0, [math.nan, 0.0, 1.0])


def _estimate(**fields: object) -> Estimate:
    """An estimate at 1 s of a target 3.7 m away, ``fields`` replacing the defaults."""
    base: dict[str, object] = dict(
        t_s=1.0,
        x_m=np.array([1.0, 2.0, 3.0]),
        a_mps=np.zeros(3),
        range_m=math.sqrt(14.0),
        excitation=0.2,
        cond_m=3.0,
        status=Status.NOT_OBSERVABLE,
        corrected=True,
        bearing_age_s=0.0,
        velocity_age_s=None,
        correction_rel=0.01,
    )
    return Estimate(**{**base, **fields})  # type: ignore[arg-type]


def test_estimate_to_dict_is_json() -> None:
    e = _estimate()
    d = json.loads(json.dumps(e.to_dict()))
    assert d["status"] == "not observable"
    assert d["x_m"] == [1.0, 2.0, 3.0]
    assert d["velocity_age_s"] is None


def test_estimate_with_a_replaces_only_the_bias() -> None:
    e = _estimate(status=Status.CONVERGED, velocity_age_s=0.1, x_std_m=np.ones(3), nis=1.5)
    f = e.with_a(np.array([0.5, -0.3, 0.0]))
    assert f.a_mps.tolist() == [0.5, -0.3, 0.0] and e.a_mps.tolist() == [0.0, 0.0, 0.0]
    d, g = e.to_dict(), f.to_dict()
    assert {k for k in d if d[k] != g[k]} == {"a_mps"}
