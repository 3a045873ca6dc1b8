"""The state file: atomic writes, validated reads."""

from __future__ import annotations

from pathlib import Path

import pytest

from mav_observer.app import statefile
from mav_observer.errors import StateError


def test_round_trip_and_no_temporary_left(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    obs = [{"sysid": 1, "target": "gimbal", "x": [1.0, 2.0]}]
    statefile.save(path, obs, saved_unix_s=12.5)
    statefile.save(path, obs * 2, saved_unix_s=13.5)  # replaces it
    assert statefile.load(path) == (13.5, obs * 2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


def test_a_failed_write_leaves_the_old_file(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    statefile.save(path, [], saved_unix_s=1.0)
    with pytest.raises(TypeError):
        statefile.save(path, [object()], saved_unix_s=2.0)  # type: ignore[list-item]
    assert statefile.load(path) == (1.0, [])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]


def test_an_unwritable_place_raises_oserror(tmp_path: Path) -> None:
    with pytest.raises(OSError, match="No such file"):
        statefile.save(tmp_path / "nowhere" / "s.json", [], saved_unix_s=1.0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("not json", "not JSON"),
        ("[1, 2]", "not a mav-observer state file"),
        ('{"kind": "mav-observer state", "schema": 9}', "schema 9"),
        ('{"kind": "mav-observer state", "schema": 2, "saved_unix_s": null}', "saved_unix_s"),
        (
            '{"kind": "mav-observer state", "schema": 2, "saved_unix_s": 1, "observers": {}}',
            "observers must be a list",
        ),
    ],
)
def test_bad_files_are_errors_naming_the_key(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "s.json"
    path.write_text(text)
    with pytest.raises(StateError, match=match):
        statefile.load(path)


def test_binary_garbage_is_not_a_state_file(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    path.write_bytes(bytes(range(256)))
    with pytest.raises(StateError, match="not UTF-8"):
        statefile.load(path)
