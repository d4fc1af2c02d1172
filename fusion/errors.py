"""Exceptions of the fusion core.

    FusionError                  any failure of the fusion math or its saved state
    ├── PoseUnavailable          no trustworthy pose at the requested time (.reason)
    └── GeolocationRejected      a pixel does not give a usable floor point (.reason)

A malformed tracker snapshot raises FusionError itself, naming the bad field.
"""

from __future__ import annotations


class FusionError(Exception):
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
