"""The base of every error rescue-hq raises on purpose.

HqError (a fusion.errors.RescueError)
├── wire.BadMessage, records.BadRecord   a radio message or a stored row is refused
├── registry_file.RegistryError          the registry file cannot be used
│   ├── RegistryBusy, RegistryCorrupt, RegistryFull
├── epoch.EpochError                     the ID epoch file cannot be used
├── cli.UsageError                       bad usage or configuration (exit 2)
└── web: ConsoleError, AccessConfigError, notes.BadNote
"""

from __future__ import annotations

from fusion.errors import RescueError


class HqError(RescueError):
    """Base of every error raised by ``hq``."""
