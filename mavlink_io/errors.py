"""Exceptions of mavlink_io.

MavlinkIOError (a fusion.errors.RescueError)
├── DialectError        the dialect XML does not generate or import
├── LinkError           a link cannot be opened or used
│   └── LinkSpecError   a link URL is malformed
├── SigningError        a signing key is missing, unreadable or too open
├── TlogError           a telemetry log cannot be written or read
├── ClockNotSynced      the autopilot clock offset is not known yet
└── LinkTimeout         a wait on the vehicle link timed out
"""

from __future__ import annotations

from fusion.errors import RescueError


class MavlinkIOError(RescueError):
    """Base of every error raised by mavlink_io."""


class DialectError(MavlinkIOError):
    """The dialect XML does not generate or import."""


class LinkError(MavlinkIOError):
    """A link cannot be opened or used."""


class LinkSpecError(LinkError, ValueError):
    """A link URL is malformed."""


class SigningError(MavlinkIOError):
    """A signing key is missing, unreadable or readable by others."""


class TlogError(MavlinkIOError):
    """A telemetry log cannot be written or read."""


class ClockNotSynced(MavlinkIOError):
    """The autopilot clock offset is not known yet (no timestamped message received)."""


class LinkTimeout(MavlinkIOError):
    """A wait on the vehicle link (heartbeat, acknowledgement) timed out."""
