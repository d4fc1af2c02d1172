"""The base of every error the companion program raises on purpose.

CompanionError (a fusion.errors.RescueError)
├── config.ConfigError          a configuration file or value is unusable
├── vision.base.VisionError     a detector cannot be built or run
│   └── DetectorUnavailable     its model files are missing or altered
├── sources.base.CameraError    a camera source cannot be opened or read
│   ├── CameraTimeout
│   └── EndOfStream
├── detectcmd.ImageError        an image file cannot be read
└── store.StoreError            the state database cannot be used
    └── StoreCorrupt            ... because it is damaged (moved aside at start)
"""

from __future__ import annotations

from fusion.errors import RescueError


class CompanionError(RescueError):
    """Base of every error raised by ``companion``."""
