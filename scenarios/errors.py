"""The base of every error the simulator raises on purpose.

SimError (a fusion.errors.RescueError)
├── world.WorldError        a world file or value is unusable
├── score.ScoreInputError   a truth or report file is unusable
└── demo.DemoError          the demo could not run
"""

from __future__ import annotations

from fusion.errors import RescueError


class SimError(RescueError):
    """Base of every error raised by ``scenarios``."""
