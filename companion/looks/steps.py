"""What one step of a closer look takes and gives (companion/looks/machine.py): the
rover as the companion knows it, the commands for the autopilot, the lines to say,
and the count of looks and what they settled. Plain values, no I/O."""

from __future__ import annotations

from dataclasses import dataclass, field

from companion.looks.choose import PointNE


@dataclass(frozen=True)
class SetMode:
    mode: int


@dataclass(frozen=True)
class GoTo:
    north_m: float
    east_m: float


@dataclass(frozen=True)
class Face:
    yaw_rad: float


@dataclass(frozen=True)
class SetCurrent:
    seq: int


@dataclass(frozen=True)
class RequestMissionCurrent:
    pass


Command = SetMode | GoTo | Face | SetCurrent | RequestMissionCurrent


@dataclass(frozen=True)
class Say:
    text: str
    severity: int


@dataclass(frozen=True)
class Rover:
    """What the companion knows of the rover now."""

    connected: bool
    north_m: float | None = None
    east_m: float | None = None
    yaw_rad: float | None = None

    @property
    def ne(self) -> PointNE | None:
        if self.north_m is None or self.east_m is None:
            return None
        return (self.north_m, self.east_m)


@dataclass
class LookCounts:
    started: int = 0
    settled: dict[str, int] = field(default_factory=dict)  # outcome word: count
    aborted: dict[str, int] = field(default_factory=dict)  # reason: count
    spent_s: float = 0.0

    def summary(self) -> str:
        parts = [f"{self.started} look{'' if self.started == 1 else 's'}"]
        parts += [f"{n} {what}" for what, n in sorted(self.settled.items())]
        parts += [f"{n} aborted ({why})" for why, n in sorted(self.aborted.items())]
        return ", ".join(parts)
