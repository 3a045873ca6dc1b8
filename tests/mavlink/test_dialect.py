"""The dialect's table (mav_observer/mavlink/_dialect_table.py) is the installed dialect's, and
replaying a tlog imports neither the dialect's module nor the links' (start-up)."""

import subprocess
import sys
from pathlib import Path

from mavmsg import TLOGS

from mav_observer.mavlink import dialect
from mav_observer.mavlink.dialect import mavlink

ROOT = Path(__file__).resolve().parents[2]


def test_the_table_is_the_installed_dialects() -> None:
    """If this fails after an upgrade of pymavlink: ``python -m mav_observer.mavlink.dialect``
    writes the table again (until then the names come from the dialect, at start-up's cost)."""
    table = Path(dialect.__file__).with_name("_dialect_table.py")
    assert table.read_text(encoding="utf-8") == dialect.table_source()
    assert dialect._TABLE is not None
    assert list(dialect.MSG_NAME.items()) == [
        (i, c.msgname) for i, c in mavlink.mavlink_map.items()
    ]
    assert {c.msgname: i for i, c in mavlink.mavlink_map.items()} == dialect.MSG_ID
    for name in dialect.TABLE_MESSAGES:
        msgid = dialect.MSG_ID[name]
        assert dialect.wire(msgid) == dialect.wire_of(mavlink.mavlink_map[msgid])


def test_a_tlog_replay_imports_neither_the_dialect_nor_the_links() -> None:
    log = TLOGS / "real_copter_bruno_mission_132614.tlog"
    code = (
        "import sys\n"
        "from mav_observer.app.replay import ReplayError, replay\n"
        "try:\n"
        f"    replay({str(log)!r})\n"
        "except ReplayError:\n"
        "    pass\n"  # (no bearing stream: read to its end all the same)
        "heavy = ('pymavlink.dialects.v20.ardupilotmega', 'pymavlink.mavutil', 'socket',\n"
        "         'mav_observer.mavlink.connection')\n"
        "print(sorted(m for m in heavy if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout + done.stderr
