"""The fast decoder equals pymavlink's, message for message (mav_observer/mavlink/fastdecode.py)."""

import math
from pathlib import Path

import pytest
from mavmsg import TLOGS, frame, landing_target_fields

from mav_observer.mavlink.dialect import MSG_ID, codec
from mav_observer.mavlink.fastdecode import DecodeError, FastDecoder

USED = [
    "LOCAL_POSITION_NED", "ATTITUDE", "ATTITUDE_QUATERNION", "GIMBAL_DEVICE_ATTITUDE_STATUS",
    "MOUNT_STATUS", "MOUNT_ORIENTATION", "LANDING_TARGET", "CAMERA_TRACKING_IMAGE_STATUS",
    "CAMERA_FOV_STATUS", "CAMERA_INFORMATION", "SYSTEM_TIME", "HOME_POSITION", "HEARTBEAT",
]  # fmt: skip


def same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def _check(frames: list[bytes]) -> int:
    fast, ref = FastDecoder({MSG_ID[n] for n in USED}), codec()
    for fr in frames:
        a, b = fast.decode(fr), ref.decode(bytearray(fr))
        assert a.get_type() == b.get_type()
        assert (a.get_srcSystem(), a.get_srcComponent()) == (
            b.get_srcSystem(),
            b.get_srcComponent(),
        )
        for name in b.get_fieldnames():
            assert same(getattr(a, name), getattr(b, name)), (b.get_type(), name)
    return len(frames)


def _raw_frames(path: Path) -> list[bytes]:
    import mmap

    from mav_observer.mavlink.tlog import _frame_at

    out = []
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        n, i = len(buf), 0
        wanted = {MSG_ID[x] for x in USED}
        ref = codec()
        while i < n:
            h = _frame_at(buf, i, n)
            if h is None or i + 8 + h[2] > n:
                i += 1
                continue
            fr = bytes(buf[i + 8 : i + 8 + h[2]])
            if h[1] in wanted:
                try:
                    ref.decode(bytearray(fr))
                    out.append(fr)
                except Exception:
                    pass
            i += 8 + h[2]
    return out


@pytest.mark.parametrize(
    "name",
    [
        "ardupilot_sitl_servo_mount_roi.tlog",
        "gimbal_ardusub_bluerov_small.tlog",
        "real_copter_phoenix_m2.tlog",
    ],
)
def test_real_log_messages_decode_identically(name: str) -> None:
    assert _check(_raw_frames(TLOGS / name)) > 1000


def test_arrays_extensions_truncation_and_mavlink1() -> None:
    nan = float("nan")
    frames = [
        frame(
            "GIMBAL_DEVICE_ATTITUDE_STATUS",
            0,
            0,
            5,
            0x2C,
            [1.0, 0.0, 0.0, 0.0],
            nan,
            nan,
            nan,
            0,
            nan,
            nan,
            1,
        ),
        frame("LANDING_TARGET", *landing_target_fields(123, 2, 12, 0.1, -0.2)),
        frame("LOCAL_POSITION_NED", 10, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),  # trailing zeros trimmed
        frame("ATTITUDE", 10, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0, v1=True),
        frame(
            "CAMERA_INFORMATION",
            1,
            [*b"vendor", *[0] * 26],
            [*b"model", *[0] * 27],
            0,
            4.0,
            6.4,
            4.8,
            640,
            480,
            0,
            0,
            0,
            b"",
            0,
            0,
        ),
    ]
    assert _check(frames) == 5


def test_bad_crc_and_bad_length_are_refused() -> None:
    fd = FastDecoder({MSG_ID["ATTITUDE"]})
    fr = bytearray(frame("ATTITUDE", 10, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
    fr[12] ^= 1
    with pytest.raises(DecodeError) as err:
        fd.decode(bytes(fr))
    assert err.value.reason == "bad_crc"
    with pytest.raises(DecodeError) as err:
        fd.decode(bytes(fr[:-3]))
    assert err.value.reason == "invalid_frame"


def test_decode_at_reads_a_frame_in_place_as_decode_does() -> None:
    """A tlog's frames are decoded where they lie in the file (``decode_at``): the same
    messages as ``decode``, trimmed payloads, MAVLink 1 and pymavlink's messages included,
    and the same refusals."""
    frames = _raw_frames(TLOGS / "ardupilot_sitl_servo_mount_roi.tlog")[:3000]
    info = [1, [0] * 32, [0] * 32, 0, 4.0, 6.4, 4.8, 640, 480, 0, 0, 0, b"", 0, 0]
    frames += [
        frame("LOCAL_POSITION_NED", 10, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),  # trailing zeros trimmed
        frame("ATTITUDE", 10, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0, v1=True),
        frame("GIMBAL_DEVICE_ATTITUDE_STATUS", 0, 0, 5, 0x2C, [1.0, 0, 0, 0], 0, 0, 0, 0, 0, 0, 1),
        frame("CAMERA_INFORMATION", *info),  # a string: pymavlink's decoder
    ]
    fd = FastDecoder({MSG_ID[n] for n in USED})
    buf = b"\x00" * 7 + b"".join(frames)
    i = 7
    for fr in frames:
        msgid = fr[7] | (fr[8] << 8) | (fr[9] << 16) if fr[0] == 0xFD else fr[5]
        a, b = fd.decode_at(buf, i, i + len(fr), msgid), fd.decode(fr)
        assert type(a) is type(b) and a.get_type() == b.get_type()
        assert repr(a.to_dict() if hasattr(a, "to_dict") else tuple(a)) == repr(
            b.to_dict() if hasattr(b, "to_dict") else tuple(b)
        )
        i += len(fr)
    bad = bytearray(frame("ATTITUDE", 10, 0.1, 0.2, 0.3, 0.01, 0.02, 0.03))
    bad[12] ^= 1
    with pytest.raises(DecodeError) as err:
        fd.decode_at(bytes(bad), 0, len(bad), MSG_ID["ATTITUDE"])
    assert err.value.reason == "bad_crc"
