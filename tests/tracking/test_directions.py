"""Frame chains of every bearing source, against hand-computed cases (docs/frames.md)."""

import math

import numpy as np
import pytest

from mav_observer.geo.frames import euler_to_dcm, quat_from_euler
from mav_observer.tracking import directions as A
from mav_observer.tracking.directions import Skip

D = math.radians
LEVEL_FORWARD = (1.0, 0.0, 0.0, 0.0)
STRAIGHT_DOWN = quat_from_euler(0.0, D(-90), 0.0)
VEHICLE_FRAME = A.GIMBAL_ROLL_LOCK | A.GIMBAL_PITCH_LOCK | A.GIMBAL_YAW_IN_VEHICLE_FRAME  # 0x2c
EARTH_FRAME = (
    A.GIMBAL_ROLL_LOCK | A.GIMBAL_PITCH_LOCK | A.GIMBAL_YAW_LOCK | A.GIMBAL_YAW_IN_EARTH_FRAME
)


def boresight(q, flags, yaw, **kw):
    fast = A.gimbal_boresight(q, flags, 0, vehicle_yaw=yaw, **kw)
    full = A.boresight(A.gimbal_camera_attitude(q, flags, 0, vehicle_yaw=yaw, **kw))
    assert np.allclose(fast, full, atol=1e-12)
    return np.array(fast)


# -- gimbal ------------------------------------------------------------------------------


def test_gimbal_level_and_forward_looks_where_the_vehicle_heads() -> None:
    assert np.allclose(boresight(LEVEL_FORWARD, VEHICLE_FRAME, 0.0), [1, 0, 0])
    assert np.allclose(boresight(LEVEL_FORWARD, VEHICLE_FRAME, D(90)), [0, 1, 0])  # heading east


def test_gimbal_pointing_straight_down() -> None:
    for yaw in (0.0, 1.0, -2.5):
        assert np.allclose(boresight(STRAIGHT_DOWN, VEHICLE_FRAME, yaw), [0, 0, 1], atol=1e-12)
        assert np.allclose(boresight(STRAIGHT_DOWN, EARTH_FRAME, yaw), [0, 0, 1], atol=1e-12)


def test_gimbal_yawed_90_in_each_yaw_mode() -> None:
    q = quat_from_euler(0.0, 0.0, D(90))  # gimbal yaw +90 deg
    # vehicle frame: relative to a vehicle heading east, +90 is south
    assert np.allclose(boresight(q, VEHICLE_FRAME, D(90)), [-1, 0, 0], atol=1e-12)
    # earth frame: +90 from north is east, whatever the vehicle
    assert np.allclose(boresight(q, EARTH_FRAME, D(90)), [0, 1, 0], atol=1e-12)
    # legacy flags (neither IN_*_FRAME): YAW_LOCK decides
    assert np.allclose(boresight(q, A.GIMBAL_YAW_LOCK, D(90)), [0, 1, 0], atol=1e-12)
    assert np.allclose(boresight(q, 0, D(90)), [-1, 0, 0], atol=1e-12)


def test_gimbal_pitched_down_45_in_the_vehicle_frame() -> None:
    q = quat_from_euler(0.0, D(-45), D(30))
    expected = [
        math.cos(D(45)) * math.cos(D(120)),
        math.cos(D(45)) * math.sin(D(120)),
        math.sin(D(45)),
    ]
    assert np.allclose(boresight(q, VEHICLE_FRAME, D(90)), expected, atol=1e-12)


def test_delta_yaw_is_used_only_with_the_new_flags() -> None:
    # the message's own delta_yaw wins over the vehicle yaw when the IN_* flags are set
    assert np.allclose(boresight(LEVEL_FORWARD, VEHICLE_FRAME, 0.0, delta_yaw=D(90)), [0, 1, 0])
    # without them (older senders, missing extension fields decode as 0) it is ignored
    assert np.allclose(boresight(LEVEL_FORWARD, 0, D(90), delta_yaw=0.0), [0, 1, 0])


def test_body_relative_gimbal_on_a_banked_vehicle() -> None:
    """A servo mount reports angles relative to the body: a camera pointing down on a vehicle
    rolled 30 deg right looks down and to the left."""
    body = euler_to_dcm(D(30), 0.0, 0.0)
    r = A.gimbal_camera_attitude(
        STRAIGHT_DOWN, VEHICLE_FRAME, 0, vehicle_yaw=0.0, vehicle_dcm=body, angles="body"
    )
    assert np.allclose(A.boresight(r), [0, -0.5, math.sqrt(3) / 2], atol=1e-12)


@pytest.mark.parametrize(
    ("q", "flags", "failure", "reason"),
    [
        (LEVEL_FORWARD, VEHICLE_FRAME, 8, "gimbal_failure"),  # encoder error
        (LEVEL_FORWARD, VEHICLE_FRAME | A.GIMBAL_RETRACT, 0, "gimbal_not_tracking"),
        (LEVEL_FORWARD, VEHICLE_FRAME | A.GIMBAL_NEUTRAL, 0, "gimbal_not_tracking"),
        ((0.0, 0.0, 0.0, 0.0), VEHICLE_FRAME, 0, "zero_quaternion"),
        ((2.0, 0.0, 0.0, 0.0), VEHICLE_FRAME, 0, "quaternion_not_unit"),
        ((math.nan, 0.0, 0.0, 1.0), VEHICLE_FRAME, 0, "non_finite"),
    ],
)
def test_unusable_gimbal_messages_are_skipped_with_a_reason(q, flags, failure, reason) -> None:
    with pytest.raises(Skip) as err:
        A.gimbal_boresight(q, flags, failure, vehicle_yaw=0.0)
    assert err.value.reason == reason


def test_limits_do_not_make_a_gimbal_unusable() -> None:
    assert np.allclose(
        A.gimbal_boresight(LEVEL_FORWARD, VEHICLE_FRAME, 1 | 2 | 4 | 512, vehicle_yaw=0.0),
        [1, 0, 0],
    )


def test_vehicle_frame_yaw_needs_the_vehicle() -> None:
    with pytest.raises(Skip, match="no_attitude"):
        A.gimbal_boresight(LEVEL_FORWARD, VEHICLE_FRAME, 0, vehicle_yaw=None)


# -- camera tracking ---------------------------------------------------------------------


def test_tracked_point_rays() -> None:
    h, v = D(90), D(60)
    assert A.tracking_ray(0.5, 0.5, h, v) == pytest.approx((1.0, 0.0, 0.0))
    assert A.tracking_ray(1.0, 0.5, h, v) == pytest.approx(
        (1.0, 1.0, 0.0)
    )  # right edge: 45 deg right
    assert A.tracking_ray(0.5, 0.0, h, v) == pytest.approx((1.0, 0.0, -math.tan(D(30))))  # top: up
    with pytest.raises(Skip, match="out_of_range"):
        A.tracking_ray(1.5, 0.5, h, v)
    with pytest.raises(Skip, match="no_fov"):
        A.tracking_ray(0.5, 0.5, 0.0, v)


def test_tracking_status_and_fov_from_camera_information() -> None:
    A.tracking_status_usable(1)
    for bad in (0, 2, 3):
        with pytest.raises(Skip, match="tracking_inactive"):
            A.tracking_status_usable(bad)
    h, v = A.fov_from_camera_information(4.0, 6.4, 4.8)
    assert math.degrees(h) == pytest.approx(2 * math.degrees(math.atan(0.8)))
    assert math.degrees(v) == pytest.approx(2 * math.degrees(math.atan(0.6)))
    assert A.fov_from_camera_information(math.nan, 6.4, 4.8) is None


# -- mounts ------------------------------------------------------------------------------


def test_mount_orientation() -> None:
    # pitch -90 (global): straight down
    assert A.mount_orientation_direction(-90.0, 0.0, math.nan, 0.0) == pytest.approx(
        (0.0, 0.0, 1.0), abs=1e-12
    )
    # yaw relative to a vehicle heading east: +90 is south
    assert A.mount_orientation_direction(0.0, 90.0, math.nan, D(90)) == pytest.approx(
        (-1.0, 0.0, 0.0), abs=1e-12
    )
    # yaw_absolute, when valid, wins
    assert A.mount_orientation_direction(0.0, 90.0, 90.0, D(90)) == pytest.approx(
        (0.0, 1.0, 0.0), abs=1e-12
    )
    with pytest.raises(Skip, match="attitude_out_of_range"):
        A.mount_orientation_direction(120.0, 0.0, math.nan, 0.0)


def test_mount_status_centidegrees() -> None:
    d = A.mount_status_direction(-4500, 9000, D(90), yaw_frame="vehicle")
    assert d == pytest.approx((-math.sqrt(0.5), 0.0, math.sqrt(0.5)), abs=1e-12)  # south, 45 down
    d = A.mount_status_direction(-4500, 9000, D(90), yaw_frame="earth")
    assert d == pytest.approx((0.0, math.sqrt(0.5), math.sqrt(0.5)), abs=1e-12)  # east, 45 down


# -- landing target ------------------------------------------------------------------


def lt(frame, ax, ay, att=(0.0, 0.0, 0.0), **kw):
    args = dict(
        frame=frame,
        angle_x=ax,
        angle_y=ay,
        position_valid=0,
        x=0.0,
        y=0.0,
        z=0.0,
        vehicle_dcm=euler_to_dcm(*att),
        vehicle_yaw=att[2],
    )
    args.update(kw)
    v = np.array(A.landing_target_direction(**args))
    return v / np.linalg.norm(v)


def test_landing_target_body_frd_ardupilot_convention() -> None:
    assert np.allclose(lt(12, 0.0, 0.0), [0, 0, 1])  # centred: straight below
    # angle_x > 0: to the right of the image = to the body's right (east at yaw 0)
    assert np.allclose(lt(12, D(45), 0.0), [0, math.sqrt(0.5), math.sqrt(0.5)])
    # angle_y > 0: lower in the image = toward the tail (south at yaw 0)
    assert np.allclose(lt(12, 0.0, D(45)), [-math.sqrt(0.5), 0, math.sqrt(0.5)])
    # heading east: the body's right is south
    assert np.allclose(
        lt(12, D(45), 0.0, att=(0.0, 0.0, D(90))), [-math.sqrt(0.5), 0, math.sqrt(0.5)], atol=1e-12
    )


def test_landing_target_banked_vehicle_body_fixed_camera() -> None:
    """Rolled 30 deg right, a centred target under a body-fixed downward camera lies down
    and to the left; LOCAL_FRD angles are levelled (yaw only) so the same angles mean straight
    down."""
    assert np.allclose(
        lt(12, 0.0, 0.0, att=(D(30), 0.0, 0.0)), [0, -0.5, math.sqrt(3) / 2], atol=1e-12
    )
    assert np.allclose(lt(20, 0.0, 0.0, att=(D(30), 0.0, 0.0)), [0, 0, 1], atol=1e-12)
    # LOCAL_FRD heading east: +angle_x (right) is south
    assert np.allclose(
        lt(20, D(45), 0.0, att=(D(30), 0.0, D(90))),
        [-math.sqrt(0.5), 0, math.sqrt(0.5)],
        atol=1e-12,
    )


def test_landing_target_positions() -> None:
    v = lt(1, 0.0, 0.0, position_valid=1, x=10.0, y=0.0, z=5.0, vehicle_pos_ned=(0.0, 0.0, 0.0))
    assert np.allclose(v, np.array([10, 0, 5]) / math.hypot(10, 5))  # PX4: absolute LOCAL_NED
    v = lt(12, 0.0, 0.0, position_valid=1, x=3.0, y=4.0, z=0.0)  # body-frame position
    assert np.allclose(v, [0.6, 0.8, 0.0])
    with pytest.raises(Skip, match="unsupported_frame"):
        lt(8, 0.0, 0.0)
    with pytest.raises(Skip, match="out_of_range"):
        lt(12, D(95), 0.0)
    with pytest.raises(Skip, match="invalid_frame"):
        lt(12, 0.0, 0.0, position_valid=7)


def test_landing_target_forward_camera_and_time_kind() -> None:
    fwd = A.landing_target_sensor("forward")
    assert np.allclose(lt(12, 0.0, 0.0, sensor=fwd), [1, 0, 0], atol=1e-12)
    assert A.landing_target_sensor("down") is None
    with pytest.raises(ValueError, match="orientation"):
        A.landing_target_sensor("sideways")
    assert A.time_usec_kind(1_767_225_600_000_000) == "unix"
    assert A.time_usec_kind(125_000_000) == "boot"


def test_attitude_checks() -> None:
    A.check_attitude(0.1, -0.2, 3.0)
    with pytest.raises(Skip, match="attitude_out_of_range"):
        A.check_attitude(0.0, 2.0, 0.0)
    with pytest.raises(Skip, match="non_finite"):
        A.check_attitude(math.inf, 0.0, 0.0)


def test_landing_target_offset_ned_is_the_line_of_sight_itself() -> None:
    """MAV_FRAME_LOCAL_OFFSET_NED with a position: relative to the vehicle, NED (ArduPilot's
    PL measurement): no attitude, no sensor rotation; a zero vector is refused."""
    sensor = A.landing_target_sensor("forward")
    v = lt(7, 0.0, 0.0, att=(D(30), D(10), D(90)), position_valid=1, x=3.0, y=-4.0, z=12.0,
           sensor=sensor)  # fmt: skip
    assert np.allclose(v, np.array([3.0, -4.0, 12.0]) / 13.0)
    with pytest.raises(A.Skip):
        lt(7, 0.0, 0.0, position_valid=1, x=0.0, y=0.0, z=0.0)
