"""Exception types of mav-observer.

Every error the package raises on bad input derives from :class:`MavObserverError`, so a
caller can catch the project's own failures without catching programming errors. The
messages name the offending parameter and its value.
"""

from __future__ import annotations


class MavObserverError(Exception):
    """Base class of every error raised by mav-observer on bad input or state."""


class InvalidSampleError(MavObserverError, ValueError):
    """A velocity or bearing sample was rejected (non-finite, wrong size, not a direction,
    time going backwards). A rejected sample leaves the observer untouched."""


class ConfigError(MavObserverError, ValueError):
    """A configuration value is out of range; the message names the key."""


class StateError(MavObserverError, ValueError):
    """A saved observer state could not be restored; the message names the bad field."""
