"""What the tracker tells the rest of the program: victim snapshots and events.

``Victim`` is a frozen snapshot of one track; ``TrackEvent`` pairs it with what
happened. Events the tracker emits:

    CONFIRMED          a tentative track gathered enough support: a new victim
    URGENCY_CHANGED    a confirmed victim's urgency class changed
    MERGED             a younger confirmed track was merged into an older one; the
                       event's victim is the younger, with ``merged_into`` set
    NOT_SEEN_RECENTLY  a confirmed victim has not been seen for a while
    SEEN_AGAIN         ...and now it has
    OPERATOR           the operator marked a victim (rescued, false alarm, reopened)

MOVED is part of the vocabulary but the tracker never emits it: only the reporter
knows which position it last sent. It calls ``moved_beyond(victim, sent_north_m,
sent_east_m, n_sigma)`` on the victims it has reported and emits MOVED itself.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum
from typing import Any, cast

from fusion.errors import FusionError
from fusion.geodesy import ned_to_geodetic
from fusion.types import (
    MAX_LOCAL_M,
    NO_CUES,
    Cov2,
    Cue,
    GlobalOrigin,
    TrackState,
    Urgency,
    VictimReport,
)


class EventKind(Enum):
    CONFIRMED = "confirmed"
    URGENCY_CHANGED = "urgency_changed"
    MOVED = "moved"
    MERGED = "merged"
    NOT_SEEN_RECENTLY = "not_seen_recently"
    SEEN_AGAIN = "seen_again"
    OPERATOR = "operator"


@dataclass(frozen=True)
class Victim:
    """A snapshot of one victim track."""

    victim_id: int
    state: TrackState
    urgency: Urgency
    visibility_pct: float  # robust estimate over recent observations
    north_m: float
    east_m: float
    cov_ne_m2: Cov2
    observations: int
    first_seen_unix_s: float
    last_seen_unix_s: float
    log_odds: float
    merged_into: int | None
    track_id: int = 0  # internal, unique, never reused; a tentative track's only identity
    cues: Cue = NO_CUES  # which sensing has seen it (colour body, colour part, warm)

    @property
    def sigma_m(self) -> float:
        """One-sigma horizontal uncertainty along the covariance's major axis."""
        return _major_sigma(self.cov_ne_m2)

    def to_report(
        self, robot_sysid: int, down_m: float, origin: GlobalOrigin | None
    ) -> VictimReport:
        """The HQ report of this victim; latitude, longitude and altitude when the
        EKF origin is known."""
        lat = lon = alt = None
        if origin is not None:
            lat, lon, alt = ned_to_geodetic(origin, self.north_m, self.east_m, down_m)
        return VictimReport(
            victim_id=self.victim_id,
            robot_sysid=robot_sysid,
            state=self.state,
            urgency=self.urgency,
            visibility_pct=self.visibility_pct,
            north_m=self.north_m,
            east_m=self.east_m,
            down_m=down_m,
            cov_ne_m2=self.cov_ne_m2,
            observations=self.observations,
            first_seen_unix_s=self.first_seen_unix_s,
            last_seen_unix_s=self.last_seen_unix_s,
            lat_deg=lat,
            lon_deg=lon,
            alt_m=alt,
            cues=self.cues,
        )


@dataclass(frozen=True)
class TrackEvent:
    """Something the reporter should tell the HQ about."""

    kind: EventKind
    victim: Victim


def _major_sigma(cov: Cov2) -> float:
    (a, b), (_, d) = cov
    half_trace = 0.5 * (a + d)
    return math.sqrt(half_trace + math.sqrt((0.5 * (a - d)) ** 2 + b * b))


def moved_beyond(victim: Victim, north_m: float, east_m: float, n_sigma: float) -> bool:
    """Whether the victim now lies more than ``n_sigma`` times its one-sigma
    uncertainty (major axis) away from the position (north_m, east_m), typically
    the one last reported."""
    distance_m = math.hypot(victim.north_m - north_m, victim.east_m - east_m)
    return distance_m > n_sigma * victim.sigma_m


# -- persistence ---------------------------------------------------------------------
#
# Snapshot format (JSON-serialisable; floats are written with repr, so a JSON round
# trip restores them bit for bit):
#
#   {"format": "rescue-companion/victim-tracker", "version": 1,
#    "next_victim_id": int, "next_track_id": int,
#    "tracks": [{"track_id", "victim_id" (0 while tentative), "state" (TrackState name),
#                "x": [north_m, east_m], "P": [[m^2, m^2], [m^2, m^2]],
#                "t_filter_unix_s", "log_odds", "observations",
#                "first_seen_unix_s", "last_seen_unix_s",
#                "history": [[t_unix_s, visibility_pct, quality], ...],
#                "urgency" (Urgency name), "visibility_pct", "merged_into": int | null,
#                "body_hits": int, "part_hits": int, "seen_with": [track_id, ...],
#                "fixes": [[t_unix_s, north_m, east_m], ...],
#                "warm_hits": int, "cues": int (a fusion.types.Cue bitmask),
#                "colour_looks": int}]}
#
# "seen_with" was added to version 1 on 2026-11-27 (a snapshot written before reads as
# []), and "body_seen": bool with it, which "body_hits" and "part_hits" (detections as
# a body, and as a lone hand or face) replaced the same day: a snapshot with
# "body_seen" reads as 1 and 0 hits when it is true, else as 0 and 0. "fixes" (the
# fixes whose median is the victim's position) was added on 2026-11-28; a snapshot
# without it reads as none, and the track reports its filter's mean until it has
# new ones. A position ("x", a fix) more than MAX_LOCAL_M from the origin is refused,
# as on the vehicle link: a stored fix at 1e154 m overflowed the median.
# "warm_hits" (detections by the thermal camera) and "cues" (which sensing saw the
# track) were added on 2026-11-29; a snapshot without them reads as 0 warm hits and
# the colour cues its body and part hits imply. "colour_looks" (clear colour looks that
# found nothing at a track only the thermal camera found) was added on 2026-11-29 too;
# without it, 0.

_ALL_CUES = Cue.COLOUR_BODY | Cue.COLOUR_PART | Cue.WARM
SNAPSHOT_FORMAT = "rescue-companion/victim-tracker"
SNAPSHOT_VERSION = 1

Matrix2 = tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class TrackRecord:
    """One track as stored: everything needed to continue it exactly."""

    track_id: int
    victim_id: int
    state: TrackState
    x: tuple[float, float]
    p: Matrix2
    t_filter_unix_s: float
    log_odds: float
    observations: int
    first_seen_unix_s: float
    last_seen_unix_s: float
    history: tuple[tuple[float, float, float], ...]
    urgency: Urgency
    visibility_pct: float
    merged_into: int | None
    body_hits: int = 0  # detections as a body
    part_hits: int = 0  # detections as a lone hand or face only
    seen_with: tuple[int, ...] = ()  # confirmed tracks detected in a frame with it
    fixes: tuple[tuple[float, float, float], ...] = ()  # (t_unix_s, north_m, east_m)
    warm_hits: int = 0  # detections by the thermal camera
    cues: Cue = NO_CUES  # which sensing has seen it
    colour_looks: int = 0  # clear colour looks that found nothing (a warm-only track)


def encode(next_victim_id: int, next_track_id: int, records: list[TrackRecord]) -> dict[str, Any]:
    return {
        "format": SNAPSHOT_FORMAT,
        "version": SNAPSHOT_VERSION,
        "next_victim_id": next_victim_id,
        "next_track_id": next_track_id,
        "tracks": [
            {
                "track_id": r.track_id,
                "victim_id": r.victim_id,
                "state": r.state.name,
                "x": list(r.x),
                "P": [list(r.p[0]), list(r.p[1])],
                "t_filter_unix_s": r.t_filter_unix_s,
                "log_odds": r.log_odds,
                "observations": r.observations,
                "first_seen_unix_s": r.first_seen_unix_s,
                "last_seen_unix_s": r.last_seen_unix_s,
                "history": [list(h) for h in r.history],
                "urgency": r.urgency.name,
                "visibility_pct": r.visibility_pct,
                "merged_into": r.merged_into,
                "body_hits": r.body_hits,
                "part_hits": r.part_hits,
                "seen_with": list(r.seen_with),
                "fixes": [list(f) for f in r.fixes],
                "warm_hits": r.warm_hits,
                "cues": int(r.cues),
                "colour_looks": r.colour_looks,
            }
            for r in records
        ],
    }


def _get(obj: Any, key: str, where: str) -> Any:
    if not isinstance(obj, dict):
        raise FusionError(f"snapshot{where}: expected an object, got {type(obj).__name__}")
    if key not in obj:
        raise FusionError(f"snapshot{where}: missing key {key!r}")
    return obj[key]


def _int(obj: Any, key: str, where: str, minimum: int) -> int:
    value = _get(obj, key, where)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise FusionError(f"snapshot{where}.{key}: expected an integer >= {minimum}, got {value!r}")
    return value


def _float(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise FusionError(f"snapshot{where}: expected a finite number, got {value!r}")
    return float(value)


def _percent(value: Any, where: str) -> float:
    pct = _float(value, where)
    if not 0.0 <= pct <= 100.0:
        raise FusionError(f"snapshot{where}: expected a percentage 0-100, got {value!r}")
    return pct


def _local(north_m: float, east_m: float, where: str) -> None:
    if max(abs(north_m), abs(east_m)) > MAX_LOCAL_M:
        raise FusionError(
            f"snapshot{where}: ({north_m!r}, {east_m!r}) lies more than {MAX_LOCAL_M:.0f} m "
            "from the origin"
        )


def _floats(value: Any, n: int, where: str) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise FusionError(f"snapshot{where}: expected a list of {n} numbers, got {value!r}")
    return tuple(_float(v, f"{where}[{i}]") for i, v in enumerate(value))


def _enum(value: Any, kind: type[TrackState] | type[Urgency], where: str) -> Any:
    if not isinstance(value, str) or value not in kind.__members__:
        names = ", ".join(kind.__members__)
        raise FusionError(f"snapshot{where}: expected one of {names}, got {value!r}")
    return kind[value]


def _matrix(value: Any, where: str) -> Matrix2:
    if not isinstance(value, list) or len(value) != 2:
        raise FusionError(f"snapshot{where}: expected a 2x2 matrix, got {value!r}")
    (a, b), (c, d) = (_floats(row, 2, f"{where}[{i}]") for i, row in enumerate(value))
    if abs(b - c) > 1e-9 * max(1.0, abs(a), abs(d)) or a <= 0.0 or d <= 0.0 or a * d - b * c <= 0:
        raise FusionError(f"snapshot{where}: not a symmetric positive-definite covariance")
    return ((a, b), (c, d))


def _record(obj: Any, where: str) -> TrackRecord:
    history_raw = _get(obj, "history", where)
    if not isinstance(history_raw, list) or not history_raw:
        raise FusionError(f"snapshot{where}.history: expected a non-empty list")
    history = tuple(
        cast(tuple[float, float, float], _floats(h, 3, f"{where}.history[{i}]"))
        for i, h in enumerate(history_raw)
    )
    for i, (_t, visibility, quality) in enumerate(history):
        if not (0.0 <= visibility <= 100.0 and 0.0 <= quality <= 1.0):
            raise FusionError(
                f"snapshot{where}.history[{i}]: expected [t_unix_s, visibility_pct 0-100, "
                f"quality 0-1], got {list(history[i])!r}"
            )
    merged_into = _get(obj, "merged_into", where)
    if merged_into is not None and (
        isinstance(merged_into, bool) or not isinstance(merged_into, int)
    ):
        raise FusionError(f"snapshot{where}.merged_into: expected an integer or null")
    state = _enum(_get(obj, "state", where), TrackState, f"{where}.state")
    victim_id = _int(obj, "victim_id", where, 0)
    if (victim_id == 0) != (state == TrackState.TENTATIVE):
        raise FusionError(f"snapshot{where}: victim_id {victim_id} does not fit state {state.name}")
    if (merged_into is not None) != (state == TrackState.MERGED):
        raise FusionError(f"snapshot{where}: merged_into must be set exactly for MERGED tracks")
    x = _floats(_get(obj, "x", where), 2, f"{where}.x")
    _local(x[0], x[1], f"{where}.x")
    body_seen = obj.get("body_seen", False)  # before body_hits (see the format above)
    if not isinstance(body_seen, bool):
        raise FusionError(f"snapshot{where}.body_seen: expected true or false, got {body_seen!r}")
    body_hits = _int(obj, "body_hits", where, 0) if "body_hits" in obj else int(body_seen)
    part_hits = _int(obj, "part_hits", where, 0) if "part_hits" in obj else 0
    seen_with = obj.get("seen_with", [])
    if not isinstance(seen_with, list) or not all(
        isinstance(i, int) and not isinstance(i, bool) and i >= 1 for i in seen_with
    ):
        raise FusionError(f"snapshot{where}.seen_with: expected a list of track ids")
    fixes_raw = obj.get("fixes", [])
    if not isinstance(fixes_raw, list):
        raise FusionError(f"snapshot{where}.fixes: expected a list")
    fixes = tuple(
        cast(tuple[float, float, float], _floats(f, 3, f"{where}.fixes[{i}]"))
        for i, f in enumerate(fixes_raw)
    )
    for i, (_t, north_m, east_m) in enumerate(fixes):
        _local(north_m, east_m, f"{where}.fixes[{i}]")
    warm_hits = _int(obj, "warm_hits", where, 0) if "warm_hits" in obj else 0
    colour_looks = _int(obj, "colour_looks", where, 0) if "colour_looks" in obj else 0
    if "cues" in obj:
        cues_raw = _int(obj, "cues", where, 0)
        if cues_raw & ~int(_ALL_CUES):
            raise FusionError(f"snapshot{where}.cues: {cues_raw} has bits no cue uses")
        cues = Cue(cues_raw)
    else:  # written before the thermal camera: the colour hits say which
        cues = (Cue.COLOUR_BODY if body_hits else NO_CUES) | (
            Cue.COLOUR_PART if part_hits else NO_CUES
        )
    return TrackRecord(
        track_id=_int(obj, "track_id", where, 1),
        victim_id=victim_id,
        state=state,
        x=(x[0], x[1]),
        p=_matrix(_get(obj, "P", where), f"{where}.P"),
        t_filter_unix_s=_float(_get(obj, "t_filter_unix_s", where), f"{where}.t_filter_unix_s"),
        log_odds=_float(_get(obj, "log_odds", where), f"{where}.log_odds"),
        observations=_int(obj, "observations", where, 1),
        first_seen_unix_s=_float(
            _get(obj, "first_seen_unix_s", where), f"{where}.first_seen_unix_s"
        ),
        last_seen_unix_s=_float(_get(obj, "last_seen_unix_s", where), f"{where}.last_seen_unix_s"),
        history=history,
        urgency=_enum(_get(obj, "urgency", where), Urgency, f"{where}.urgency"),
        visibility_pct=_percent(_get(obj, "visibility_pct", where), f"{where}.visibility_pct"),
        merged_into=merged_into,
        body_hits=body_hits,
        part_hits=part_hits,
        seen_with=tuple(sorted(set(seen_with))),
        fixes=fixes,
        warm_hits=warm_hits,
        cues=cues,
        colour_looks=colour_looks,
    )


def decode(snapshot: Any) -> tuple[int, int, list[TrackRecord]]:
    """(next_victim_id, next_track_id, records) of a snapshot; FusionError naming
    the first thing that is wrong."""
    if _get(snapshot, "format", "") != SNAPSHOT_FORMAT:
        raise FusionError(f"snapshot.format: expected {SNAPSHOT_FORMAT!r}")
    version = _get(snapshot, "version", "")
    if version != SNAPSHOT_VERSION:
        raise FusionError(f"snapshot.version: {version!r} is not supported ({SNAPSHOT_VERSION})")
    next_victim_id = _int(snapshot, "next_victim_id", "", 1)
    next_track_id = _int(snapshot, "next_track_id", "", 1)
    tracks = _get(snapshot, "tracks", "")
    if not isinstance(tracks, list):
        raise FusionError("snapshot.tracks: expected a list")
    records = [_record(obj, f".tracks[{i}]") for i, obj in enumerate(tracks)]
    track_ids = [r.track_id for r in records]
    victim_ids = [r.victim_id for r in records if r.victim_id]
    if len(set(track_ids)) != len(track_ids) or len(set(victim_ids)) != len(victim_ids):
        raise FusionError("snapshot.tracks: duplicate track_id or victim_id")
    if track_ids and max(track_ids) >= next_track_id:
        raise FusionError(f"snapshot.next_track_id: {next_track_id} would reuse a track id")
    if victim_ids and max(victim_ids) >= next_victim_id:
        raise FusionError(f"snapshot.next_victim_id: {next_victim_id} would reuse a victim id")
    return next_victim_id, next_track_id, records


def check_links(victim_ids: Iterable[int], merged_into: Iterable[int | None]) -> None:
    """Every merged_into must name a known victim."""
    known = set(victim_ids)
    for target in merged_into:
        if target is not None and target not in known:
            raise FusionError(f"snapshot.tracks: merged_into {target} names no victim")
