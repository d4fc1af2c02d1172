"""The project's exception root, and the exceptions of the fusion core.

Every error the project raises on purpose derives from ``RescueError``; each package
has one base under it (``FusionError``, ``mavlink_io.errors.MavlinkIOError``,
``companion.errors.CompanionError``, ``hq.errors.HqError``,
``scenarios.errors.SimError``, ``npmfetch.FetchError``), so a caller can catch one
package's failures, or all of them, without catching the bugs (a ``TypeError`` is
never one of ours). Validation errors are also ``ValueError``s.

    RescueError
    └── FusionError                  any failure of the fusion math or its saved state
    ├── PoseUnavailable          no trustworthy pose at the requested time (.reason)
    └── GeolocationRejected      a pixel does not give a usable floor point (.reason)

A malformed tracker snapshot raises FusionError itself, naming the bad field.
"""

from __future__ import annotations


class RescueError(Exception):
    """Root of every error this project raises on purpose."""


class FusionError(RescueError):
    """Base class of every error raised by ``fusion``."""


class PoseUnavailable(FusionError):
    """No pose can be given for the requested time without guessing."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"pose unavailable: {reason}")
        self.reason = reason


class GeolocationRejected(FusionError):
    """A pixel's ray does not give a floor point that can be trusted."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"geolocation rejected: {reason}")
        self.reason = reason
