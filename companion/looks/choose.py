"""Closer looks: which candidate deserves one and where to look from. Pure, no I/O.

- ``candidates``: from the tracker's snapshots (``VictimTracker.victims(True)``), the
  ones the companion cannot settle from the route's views: a tentative track still
  unconfirmed ``tentative_min_s`` after it was first seen, a victim whose visibility
  is within ``urgency_margin_pct`` of an urgency bound (10 or 50 %), and a find only
  the thermal camera has seen.
- ``viewpoint``: a point ``view_min_m``..``view_max_m`` from the candidate, at most
  ``beside_path_m`` from the path already driven (known free), never within
  ``clearance_m`` of any victim or candidate, the nearest such point to the rover
  whose straight leg from the rover is known free (``known_free``: beside the path
  driven all along, clear of everyone); the heading faces the candidate.
- ``settlement``: what a look settled, comparing the candidate before with its track
  after (confirmed, rejected, urgency changed, seen in colour), or None.

The steps that take the rover there and back: companion/looks/machine.py.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from companion.config import LooksConfig
from fusion.registry import Victim
from fusion.types import Cue, TrackState, Urgency

PointNE = tuple[float, float]
_PATH_STEP_M = 0.25  # the driven path keeps a point every this far
_PATH_POINTS = 8000  # ~2 km of path
_COMPASS = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")


class Kind(Enum):
    TENTATIVE = "possible victim"
    URGENCY = "victim of uncertain urgency"
    WARM_ONLY = "warm find"
    ASKED = "victim the operator asked about"  # never found by ``candidates``


@dataclass(frozen=True)
class Candidate:
    track_id: int
    victim_id: int  # 0 while tentative
    kind: Kind
    north_m: float
    east_m: float
    state: TrackState
    urgency: Urgency
    cues: Cue

    @property
    def ne(self) -> PointNE:
        return (self.north_m, self.east_m)


LIVE_STATES = (TrackState.TENTATIVE, TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)


def candidates(
    victims: Iterable[Victim], now_unix_s: float, settings: LooksConfig
) -> list[Candidate]:
    """The candidates among the tracker's snapshots, most doubtful first."""
    out: list[Candidate] = []
    for v in victims:
        if v.state not in LIVE_STATES:
            continue
        kind = None
        if v.state == TrackState.TENTATIVE:
            if now_unix_s - v.first_seen_unix_s >= settings.tentative_min_s:
                kind = Kind.TENTATIVE
        elif not v.cues & (Cue.COLOUR_BODY | Cue.COLOUR_PART) and v.cues & Cue.WARM:
            kind = Kind.WARM_ONLY
        elif any(abs(v.visibility_pct - b) <= settings.urgency_margin_pct for b in (10.0, 50.0)):
            kind = Kind.URGENCY
        if kind is not None:
            out.append(
                Candidate(
                    v.track_id,
                    v.victim_id,
                    kind,
                    v.north_m,
                    v.east_m,
                    v.state,
                    v.urgency,
                    v.cues,
                )
            )
    order = {Kind.TENTATIVE: 0, Kind.WARM_ONLY: 1, Kind.URGENCY: 2}
    return sorted(out, key=lambda c: order[c.kind])


def settlement(before: Candidate, after: Victim | None) -> str | None:
    """What the look settled ("confirmed", "rejected", "urgency changed", "seen in
    colour"), or None when the candidate is as doubtful as before."""
    if after is None or after.state == TrackState.FALSE_ALARM:
        return "rejected"
    if after.state == TrackState.MERGED:
        return f"merged into victim {after.merged_into}"
    if before.state == TrackState.TENTATIVE and after.state != TrackState.TENTATIVE:
        return "confirmed"
    if after.urgency != before.urgency:
        return f"urgency changed to {after.urgency.name}"
    if before.kind == Kind.WARM_ONLY and after.cues & (Cue.COLOUR_BODY | Cue.COLOUR_PART):
        return "seen in colour"
    return None


class DrivenPath:
    """The rover's positions, a point every 0.25 m: where it has driven is free."""

    def __init__(self, max_points: int = _PATH_POINTS) -> None:
        self.points: deque[PointNE] = deque(maxlen=max_points)

    def add(self, north_m: float, east_m: float) -> None:
        if not self.points or math.dist(self.points[-1], (north_m, east_m)) >= _PATH_STEP_M:
            self.points.append((north_m, east_m))


@dataclass(frozen=True)
class Viewpoint:
    north_m: float
    east_m: float
    yaw_rad: float  # facing the candidate

    @property
    def ne(self) -> PointNE:
        return (self.north_m, self.east_m)


def viewpoint(
    target: PointNE,
    driven: Sequence[PointNE],
    avoid: Sequence[PointNE],
    rover: PointNE,
    settings: LooksConfig,
) -> Viewpoint | None:
    """See the module docstring; None when no driven point gives one whose straight
    leg from the rover is known free (``known_free``)."""
    lo, hi, beside = settings.view_min_m, settings.view_max_m, settings.beside_path_m
    options: list[tuple[float, PointNE]] = []
    for p in driven:
        d = math.dist(p, target)
        if d < 1e-6 or not lo - beside <= d <= hi + beside:
            continue
        # Slide along the line to the candidate into [lo, hi]: at most `beside` away.
        want = min(hi, max(lo, d))
        s = want / d
        q = (target[0] + (p[0] - target[0]) * s, target[1] + (p[1] - target[1]) * s)
        if any(math.dist(q, a) < settings.clearance_m for a in avoid):
            continue
        options.append((math.dist(q, rover), q))
    for _cost, q in sorted(options):
        if known_free(rover, q, driven, avoid, settings):
            return Viewpoint(q[0], q[1], math.atan2(target[1] - q[1], target[0] - q[0]))
    return None


def known_free(
    a: PointNE, b: PointNE, driven: Sequence[PointNE], avoid: Sequence[PointNE], s: LooksConfig
) -> bool:
    """Whether the straight leg a-b stays within ``beside_path_m`` of the path driven
    and ``clearance_m`` from every victim and candidate (every 0.1 m along it): the
    rover drives there and back on ground it has already driven, past no one."""
    if not driven:
        return False
    n = max(1, math.ceil(math.dist(a, b) / 0.1))
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    samples = np.asarray(a) + t * (np.asarray(b) - np.asarray(a))
    path = np.asarray(driven, dtype=float)
    lo, hi = samples.min(axis=0) - s.beside_path_m, samples.max(axis=0) + s.beside_path_m
    path = path[np.all((path >= lo) & (path <= hi), axis=1)]
    if not len(path):
        return False
    near = np.sqrt(((samples[:, None, :] - path[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
    if float(near.max()) > s.beside_path_m + 1e-9:
        return False
    if avoid:
        people = np.asarray(avoid, dtype=float)
        gap = np.sqrt(((samples[:, None, :] - people[None, :, :]) ** 2).sum(axis=2)).min()
        if float(gap) < s.clearance_m:
            return False
    return True


def compass(from_ne: PointNE, to_ne: PointNE) -> str:
    """ "2 m NE": the distance and the 8-point direction from one point to another."""
    dn, de = to_ne[0] - from_ne[0], to_ne[1] - from_ne[1]
    bearing = math.degrees(math.atan2(de, dn)) % 360.0
    return f"{math.hypot(dn, de):.0f} m {_COMPASS[round(bearing / 45.0) % 8]}"
