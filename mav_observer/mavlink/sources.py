"""What a source string names: a tlog file to replay, or a MAVLink connection.

Apart from :mod:`~mav_observer.mavlink.connection` (which re-exports these names) so that
telling them apart, as replay and the settings do, imports none of the links' modules.
"""

from __future__ import annotations

import os

#: The connection strings' prefixes (``mavutil.mavlink_connection``'s).
URL_PREFIXES = ("udp:", "udpin:", "udpout:", "udpbcast:", "tcp:", "tcpin:", "serial:", "mcast:")


def is_file_source(source: str) -> bool:
    """True if ``source`` names a file to replay rather than a connection string."""
    if source.startswith(URL_PREFIXES):
        return False
    return os.path.isfile(source) and not source.startswith("/dev/")
