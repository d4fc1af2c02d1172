"""One victim track's state, and the two forms it leaves the tracker in: the
``Victim`` snapshot the rest of the program reads and the ``TrackRecord`` the
registry stores (``fusion.registry`` encodes and validates it).

Where a victim lies, as reported, is the geometric median of the fixes its filter
took (``Track.fixes``, the newest ``TrackerParams.position_fixes``; from
``MIN_FIXES`` of them), not the filter's mean. The filter weighs each fix by its
covariance and, through its random walk, the newest most; but a body's fixes stray
more than their covariance says (the floor point of a body seen cut by the frame
or from 1 m, end-on or half hidden, is 0.5 m off in the median, its covariance says
0.13 m), and one stray fix after a minute out of view moved a victim 0.7 m. The
filter's mean and covariance still decide which detections are the victim's
(gating, merging). Measured on the scenario suite and a recorded 10-minute mission
(docs/VISION.md, "Where a victim lies: the median of its fixes")."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from filterpy.kalman import KalmanFilter

from fusion.camera import FloatArray
from fusion.median import geometric_median
from fusion.registry import TrackRecord, Victim
from fusion.types import NO_CUES, Cov2, Cue, TrackState, Urgency


@dataclass(eq=False)
class Track:
    track_id: int
    kf: KalmanFilter
    state: TrackState
    log_odds: float
    observations: int
    first_seen_unix_s: float
    last_seen_unix_s: float
    t_filter_unix_s: float  # the time the filter's x, P refer to
    history: deque[tuple[float, float, float]]  # (t_unix_s, visibility_pct, quality)
    urgency: Urgency
    visibility_pct: float
    victim_id: int = 0  # 0 until confirmed
    merged_into: int | None = None
    matched: bool = field(default=False, repr=False)  # in the current update
    # Confirmed tracks detected in the same frame as this tentative one (so not the
    # same body).
    seen_with: set[int] = field(default_factory=set, repr=False)
    # Detections of it as a body, and as a lone part (a hand, a face) only.
    body_hits: int = field(default=0, repr=False)
    part_hits: int = field(default=0, repr=False)
    # Detections by the thermal camera (also counted above, as a body or a part).
    warm_hits: int = field(default=0, repr=False)
    # Clear colour looks (lit, in range) at it that found nothing, while only the
    # thermal camera had found it.
    colour_looks: int = field(default=0, repr=False)
    cues: Cue = field(default=NO_CUES, repr=False)  # which sensing has seen it
    # The fixes the filter took, (t_unix_s, north_m, east_m), newest last and at most
    # TrackerParams.position_fixes of them: the victim's position is their median.
    fixes: deque[tuple[float, float, float]] = field(default_factory=deque, repr=False)
    _position: FloatArray | None = field(default=None, init=False, repr=False)  # cached median

    @property
    def x(self) -> FloatArray:
        """The filter's mean: what detections are gated against."""
        return self.kf.x.reshape(2)

    def add_fix(self, t_unix_s: float, north_m: float, east_m: float) -> None:
        self.fixes.append((t_unix_s, north_m, east_m))
        self._position = None

    def take_fixes(self, other: Track) -> None:
        """Add ``other``'s fixes (a merge), keeping the newest."""
        merged = sorted([*self.fixes, *other.fixes])
        self.fixes = deque(merged, maxlen=self.fixes.maxlen)
        self._position = None

    @property
    def position(self) -> FloatArray:
        """Where the victim lies: the geometric median of its fixes, or the filter's
        mean while it has fewer than MIN_FIXES (a restored track from before the
        fixes were stored has none)."""
        if len(self.fixes) < MIN_FIXES:
            return self.x
        if self._position is None:
            self._position = geometric_median(np.array([f[1:] for f in self.fixes]))
        return self._position


# Fewer fixes than this: the filter's mean is the position (the median of two fixes
# is anywhere between them).
MIN_FIXES = 3


def new_filter(x: FloatArray, p: FloatArray) -> KalmanFilter:
    """A filter holding one victim's state x and covariance P. Its model (a static
    target, F = I; the position observed, H = I; Q = q dt I) is applied to all
    tracks at once by ``VictimTracker._predict`` and ``kalman_update`` (the filter's
    own predict/update are never called; a test checks the batch equals them)."""
    kf = KalmanFilter(dim_x=2, dim_z=2)
    kf.x = np.array(x, dtype=float).reshape(2, 1)
    kf.P = np.array(p, dtype=float)
    return kf


def _cov2(p: FloatArray) -> Cov2:
    s = 0.5 * (p + p.T)
    return ((float(s[0, 0]), float(s[0, 1])), (float(s[0, 1]), float(s[1, 1])))


def victim_of(t: Track) -> Victim:
    """The frozen snapshot of a track."""
    x = t.position
    return Victim(
        victim_id=t.victim_id,
        state=t.state,
        urgency=t.urgency,
        visibility_pct=t.visibility_pct,
        north_m=float(x[0]),
        east_m=float(x[1]),
        cov_ne_m2=_cov2(t.kf.P),
        observations=t.observations,
        first_seen_unix_s=t.first_seen_unix_s,
        last_seen_unix_s=t.last_seen_unix_s,
        log_odds=t.log_odds,
        merged_into=t.merged_into,
        track_id=t.track_id,
        cues=t.cues,
    )


def record_of(t: Track) -> TrackRecord:
    """The track as stored: everything needed to continue it exactly."""
    return TrackRecord(
        track_id=t.track_id,
        victim_id=t.victim_id,
        state=t.state,
        x=(float(t.x[0]), float(t.x[1])),
        p=((float(t.kf.P[0, 0]), float(t.kf.P[0, 1])), (float(t.kf.P[1, 0]), float(t.kf.P[1, 1]))),
        t_filter_unix_s=t.t_filter_unix_s,
        log_odds=t.log_odds,
        observations=t.observations,
        first_seen_unix_s=t.first_seen_unix_s,
        last_seen_unix_s=t.last_seen_unix_s,
        history=tuple(t.history),
        urgency=t.urgency,
        visibility_pct=t.visibility_pct,
        merged_into=t.merged_into,
        body_hits=t.body_hits,
        part_hits=t.part_hits,
        seen_with=tuple(sorted(t.seen_with)),
        fixes=tuple(t.fixes),
        warm_hits=t.warm_hits,
        colour_looks=t.colour_looks,
        cues=t.cues,
    )


def track_of(rec: TrackRecord, urgency_window: int, position_fixes: int) -> Track:
    """The track a stored record continues (the record is already validated)."""
    return Track(
        track_id=rec.track_id,
        kf=new_filter(np.array(rec.x), np.array(rec.p)),
        state=rec.state,
        log_odds=rec.log_odds,
        observations=rec.observations,
        first_seen_unix_s=rec.first_seen_unix_s,
        last_seen_unix_s=rec.last_seen_unix_s,
        t_filter_unix_s=rec.t_filter_unix_s,
        history=deque(rec.history, maxlen=urgency_window),
        urgency=rec.urgency,
        visibility_pct=rec.visibility_pct,
        victim_id=rec.victim_id,
        merged_into=rec.merged_into,
        seen_with=set(rec.seen_with),
        body_hits=rec.body_hits,
        part_hits=rec.part_hits,
        fixes=deque(rec.fixes, maxlen=position_fixes),
        warm_hits=rec.warm_hits,
        colour_looks=rec.colour_looks,
        cues=rec.cues,
    )
