"""The tlog reader (mav_observer/mavlink/tlog.py): same messages as pymavlink, damage counted."""

from collections import Counter
from pathlib import Path

import pytest
from mavmsg import T0_UNIX, TLOGS, frame, tlog

from mav_observer.mavlink.dialect import MSG_ID, connect
from mav_observer.mavlink.tlog import TlogReader

REAL = sorted(TLOGS.glob("*.tlog"))
assert len(REAL) == 6, f"expected the six shared logs in {TLOGS}, found {REAL}"


def pymavlink_counts(path: Path) -> Counter[str]:
    conn = connect(str(path))
    c: Counter[str] = Counter()
    while (m := conn.recv_match()) is not None:
        if m.get_type() != "BAD_DATA":
            c[m.get_type()] += 1
    return c


@pytest.mark.slow
@pytest.mark.parametrize("path", REAL, ids=[p.name for p in REAL])
def test_real_logs_give_the_same_messages_as_pymavlink(path: Path) -> None:
    r = TlogReader(path)  # decode everything
    ours = Counter(m.get_type() for _, m in r)
    assert ours == pymavlink_counts(path)
    assert r.stats.records == sum(r.stats.by_id.values())
    assert (
        r.stats.first_t_unix_s is not None and r.stats.last_t_unix_s >= r.stats.first_t_unix_s - 600
    )


@pytest.mark.slow
def test_real_damage_is_counted() -> None:
    s = TlogReader(TLOGS / "bad_zeroholes_tsback_132613.tlog", set())
    assert list(s) == []
    assert s.stats.resyncs == 2 and s.stats.skipped_bytes == 4731 and s.stats.time_backwards == 2
    t = TlogReader(TLOGS / "bad_truncated_lastrec_124019.tlog", set())
    list(t)
    assert t.stats.truncated_tail and t.stats.skipped_bytes == 14
    # its 4 bad CRCs are camera messages; a CRC is checked for what is decoded
    ids = {MSG_ID[n] for n in ("MOUNT_STATUS", "CAMERA_INFORMATION", "LOCAL_POSITION_NED")}
    b = TlogReader(TLOGS / "gimbal_ardusub_bluerov_small.tlog", ids)
    got = Counter(m.get_type() for _, m in b)
    assert got["MOUNT_STATUS"] == 792 and b.stats.decode_errors == {"bad_crc": 1}
    everything = TlogReader(TLOGS / "gimbal_ardusub_bluerov_small.tlog")
    list(everything)
    assert everything.stats.decode_errors == {"bad_crc": 4}


def _records(n: int) -> list[tuple[float, bytes]]:
    return [
        (T0_UNIX + 0.1 * i, frame("ATTITUDE", 1000 + 100 * i, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0))
        for i in range(n)
    ]


def test_only_wanted_ids_are_decoded_but_all_are_counted(tmp_path: Path) -> None:
    recs = [*_records(5), (T0_UNIX + 1.0, frame("SYSTEM_TIME", 0, 5000))]
    r = TlogReader(tlog(tmp_path / "a.tlog", recs), {MSG_ID["SYSTEM_TIME"]})
    out = list(r)
    assert [m.get_type() for _, m in out] == ["SYSTEM_TIME"]
    assert r.stats.by_name() == {"ATTITUDE": 5, "SYSTEM_TIME": 1}
    assert out[0][0] == pytest.approx(T0_UNIX + 1.0)


def test_mavlink1_short_frames_after_mavlink2_keep_alignment(tmp_path: Path) -> None:
    """pymavlink's tlog reading loses alignment here (ENGINEERING_NOTES); ours does not."""
    recs = []
    for i in range(5):
        recs.append((T0_UNIX + i, frame("ATTITUDE", 1000 * i, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)))
        recs.append((T0_UNIX + i + 0.5, frame("COMMAND_ACK", 400, 0, v1=True)))
    r = TlogReader(tlog(tmp_path / "mixed.tlog", recs))
    assert Counter(m.get_type() for _, m in r) == {"ATTITUDE": 5, "COMMAND_ACK": 5}
    assert r.stats.damage() == {}


def test_junk_zero_holes_bit_flips_and_cut_tails(tmp_path: Path) -> None:
    good = b"".join(__import__("struct").pack(">Q", round(t * 1e6)) + f for t, f in _records(40))
    rec_len = len(good) // 40
    junk = good[: 10 * rec_len] + bytes(500) + good[10 * rec_len : 20 * rec_len] + b"\x17" * 333
    flipped = bytearray(good[20 * rec_len : 30 * rec_len])
    flipped[rec_len + 20] ^= 0x40  # a payload bit of record 21: bad CRC
    data = junk + bytes(flipped) + good[30 * rec_len :] + good[:7]  # cut tail
    p = tmp_path / "damaged.tlog"
    p.write_bytes(data)
    r = TlogReader(p, {MSG_ID["ATTITUDE"]})
    times = [m.time_boot_ms for _, m in r]
    assert len(times) == 39  # 40 records, one with a bad CRC
    assert r.stats.decode_errors == {"bad_crc": 1}
    assert r.stats.resyncs == 2 and r.stats.skipped_bytes == 500 + 333 + 7
    assert r.stats.truncated_tail


def test_empty_and_not_a_tlog(tmp_path: Path) -> None:
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    r = TlogReader(empty)
    assert list(r) == [] and r.stats.records == 0
    text = tmp_path / "notes.tlog"
    text.write_text("this is not a telemetry log\n" * 200)
    r = TlogReader(text)
    assert list(r) == [] and r.stats.records == 0 and r.stats.skipped_bytes == text.stat().st_size


def _read_all(r: TlogReader, drop_after: int | None = None) -> list[object]:
    """Every message (its time, type and fields as text) and then the statistics."""
    out: list[object] = []
    for k, (t, m) in enumerate(r):
        fields = tuple(m) if isinstance(m, tuple) else sorted(m.to_dict().items())
        out.append((t, m.get_type(), repr(fields)))
        if k == drop_after:
            r.drop({MSG_ID["ATTITUDE"], MSG_ID["GLOBAL_POSITION_INT"]})
    s = r.stats
    out.append((s.records, s.resyncs, s.skipped_bytes, s.truncated_tail, s.time_backwards))
    out.append((s.first_t_unix_s, s.last_t_unix_s, list(s.by_id.items()), s.decode_errors))
    return out


def _damaged(tmp_path: Path, seed: int) -> Path:
    """The start of a real log with damage of every kind the reader tells apart."""
    import random
    import struct

    from mav_observer.mavlink.tlog import _frame_at

    rng = random.Random(seed)
    data = bytearray((TLOGS / "real_copter_bruno_mission_132614.tlog").read_bytes()[:60_000])
    starts, i = [], 0
    while (h := _frame_at(data, i, len(data))) is not None and i + 8 + h[2] <= len(data):
        starts.append(i)
        i += 8 + h[2]
    for k in sorted(rng.sample(range(len(starts)), 4), reverse=True):  # timestamps
        ts = struct.unpack_from(">Q", data, starts[k])[0]
        bad = rng.choice([0, 10**15, ts - 100_000_000, ts + 30 * 86400 * 10**6, 2**64 - 1])
        struct.pack_into(">Q", data, starts[k], bad)
    for _ in range(5):
        i = rng.randrange(len(data))
        kind = rng.randrange(4)
        if kind == 0:
            data[i] ^= 1 << rng.randrange(8)  # a bit flip: a bad CRC or a broken header
        elif kind == 1:
            data[i:i] = bytes(rng.randrange(1, 400))  # a zero hole
        elif kind == 2:
            data[i:i] = b"\xfd" * rng.randrange(1, 20)  # magic bytes out of place
        else:
            del data[i : i + rng.randrange(1, 30)]
    p = tmp_path / f"damaged{seed}.tlog"
    p.write_bytes(bytes(data[: len(data) - rng.randrange(0, 20)]))
    return p


@pytest.mark.slow
@pytest.mark.parametrize("window", [1 << 22, 1000])
def test_the_fast_path_reads_what_record_by_record_reading_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, window: int
) -> None:
    """Runs of sound records are split, counted and filtered by numpy (``tlog._Scan``); the
    rest, record by record. Both give the same messages, counts and damage, whatever the
    damage and wherever the scan's windows end."""
    from mav_observer.mavlink import tlog as mod

    paths = [*REAL, *(_damaged(tmp_path, seed) for seed in range(12))]
    wanted = {MSG_ID[n] for n in ("ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT")}
    monkeypatch.setattr(mod, "SCAN_WINDOW", window)
    fast = [_read_all(TlogReader(p, w), d) for p in paths for w, d in ((None, None), (wanted, 30))]
    monkeypatch.setattr(mod._Scan, "clean_from", lambda self, i, last_ts: None)
    slow = [_read_all(TlogReader(p, w), d) for p in paths for w, d in ((None, None), (wanted, 30))]
    assert fast == slow
