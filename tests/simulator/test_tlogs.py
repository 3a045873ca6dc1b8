"""sim.tlogs: the shared logs are found from any checkout, or their absence is loud."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim import tlogs


def test_the_environment_variable_wins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / tlogs.MARKER).write_bytes(b"")
    monkeypatch.setenv("MAV_OBSERVER_TLOGS", str(tmp_path))
    assert tlogs.find_tlogs() == tmp_path


def test_missing_logs_are_an_error_naming_where_it_looked(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MAV_OBSERVER_TLOGS", str(tmp_path))  # no logs there
    monkeypatch.setattr(tlogs, "ROOT", tmp_path / "checkout")
    monkeypatch.setattr(tlogs, "Path", _NoWorkplace)
    with pytest.raises(FileNotFoundError, match="set MAV_OBSERVER_TLOGS"):
        tlogs.find_tlogs()


class _NoWorkplace(type(Path())):  # type: ignore[misc]
    """Path, with the workplace's copy of the logs hidden."""

    def is_file(self, **kwargs: object) -> bool:
        return not str(self).startswith("/work/shared") and super().is_file()
