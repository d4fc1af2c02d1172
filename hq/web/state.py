"""What the console shows, as JSON: HQ victims, robots (link, position, path), notes.

``LiveRobots`` is filled by the HQ's main thread (every message heard from a
system, LOCAL_POSITION_NED from a robot's autopilot) and read by the console's
thread; it is the only state the two share, behind one lock. ``Page`` holds the
page's whole state as JSON entries per victim and robot and replaces only those
that changed (hq.web.feed says which); ``snapshot`` builds it all at once. Both
are pure.

The list order is the operator's: open victims before resolved ones (RESCUED,
FALSE_ALARM), then the most urgent first, then the one waiting longest (earliest
first seen). A robot's entry carries its closer looks (on or off, how many made and
what they settled, from its RESCUE_STATUS) and the operator's newest "no more looks"
or "looks on" for it with the robot's answer. Positions are in the robots' local frame (metres north/east of the
EKF origin, where the robots started); the uncertainty ellipse is the 95 % region
of the fused position's covariance.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from fusion.types import Sensor, TrackState
from hq.records import (
    ACK_RESULT_REJECTED,
    Action,
    OperatorAction,
    Robot,
    RobotStatus,
    cue_words,
)
from hq.view import HqVictim
from mavlink_io.statustext import RETIRED_LABEL, URGENCY_LABEL, callsign

CHI2_2DOF_95 = 5.991  # scipy.stats.chi2.ppf(0.95, df=2): the ellipse's scale
_RESOLVED = (TrackState.RESCUED, TrackState.FALSE_ALARM)
_ACTION_NAMES = {
    1: "rescued",
    2: "false_alarm",
    4: "confirmed",
    5: "look_closer",
    6: "looks_off",
    7: "looks_on",
}


@dataclass
class _Track:
    last_heard_unix_s: float = 0.0
    north_m: float | None = None
    east_m: float | None = None
    position_unix_s: float | None = None
    path: list[tuple[float, float]] = field(default_factory=list)
    path_version: int = 0  # bumped when the path changes


@dataclass(frozen=True)
class RobotTrack:
    sysid: int
    last_heard_unix_s: float
    north_m: float | None
    east_m: float | None
    position_unix_s: float | None
    path: tuple[tuple[float, float], ...] | None  # None: unchanged since the version asked for
    path_version: int = 0


class LiveRobots:
    """Thread-safe: when each system was last heard, and each robot's position and path.

    A path point is kept when the robot moved at least ``path_step_m`` from the
    last one; beyond ``max_path_points`` every other point of the older half is
    dropped, so a long mission keeps its whole shape in bounded memory.
    """

    def __init__(self, path_step_m: float = 0.5, max_path_points: int = 2000) -> None:
        self._lock = threading.Lock()
        self._tracks: dict[int, _Track] = {}
        self._step_m = path_step_m
        self._max_points = max_path_points
        self.version = 0  # bumped on every change a page shows (a new position)

    def heard(self, sysid: int, now_unix_s: float) -> None:
        with self._lock:
            self._tracks.setdefault(sysid, _Track()).last_heard_unix_s = now_unix_s

    def position(self, sysid: int, north_m: float, east_m: float, now_unix_s: float) -> None:
        if not (math.isfinite(north_m) and math.isfinite(east_m)):
            return
        with self._lock:
            t = self._tracks.setdefault(sysid, _Track())
            t.last_heard_unix_s = max(t.last_heard_unix_s, now_unix_s)
            t.north_m, t.east_m, t.position_unix_s = north_m, east_m, now_unix_s
            last = t.path[-1] if t.path else None
            if last is None or math.hypot(north_m - last[0], east_m - last[1]) >= self._step_m:
                t.path.append((north_m, east_m))
                t.path_version += 1
                if len(t.path) > self._max_points:
                    half = len(t.path) // 2
                    t.path[:half] = t.path[:half:2]
            self.version += 1

    def last_heard(self) -> dict[int, float]:
        """System ID -> when it was last heard (Unix s); cheap, no paths."""
        with self._lock:
            return {s: t.last_heard_unix_s for s, t in self._tracks.items()}

    def positioned(self) -> frozenset[int]:
        with self._lock:
            return frozenset(s for s, t in self._tracks.items() if t.north_m is not None)

    def tracks(self, paths_held: Mapping[int, int] | None = None) -> dict[int, RobotTrack]:
        """Every robot's track; a path is copied only when its version is not the one
        ``paths_held`` says the caller has (otherwise ``path`` is None)."""
        held = paths_held or {}
        with self._lock:
            return {
                s: RobotTrack(
                    s,
                    t.last_heard_unix_s,
                    t.north_m,
                    t.east_m,
                    t.position_unix_s,
                    None if held.get(s) == t.path_version else tuple(t.path),
                    t.path_version,
                )
                for s, t in self._tracks.items()
            }


@dataclass(frozen=True)
class Note:
    note_id: int
    hq_id: int
    text: str
    created_unix_s: float


def ellipse_95(cov: Sequence[Sequence[float]]) -> dict[str, float]:
    """Semi-axes (m) and the major axis' bearing (deg from north toward east)."""
    (nn, ne), (_, ee) = cov
    mean = 0.5 * (nn + ee)
    diff = math.hypot(0.5 * (nn - ee), ne)
    major, minor = max(mean + diff, 0.0), max(mean - diff, 0.0)
    bearing = 0.5 * math.degrees(math.atan2(2.0 * ne, nn - ee))
    k = math.sqrt(CHI2_2DOF_95)
    return {
        "major_m": round(k * math.sqrt(major), 3),
        "minor_m": round(k * math.sqrt(minor), 3),
        "bearing_deg": round(bearing, 2),
    }


def _sort_key(v: HqVictim) -> tuple[bool, int, float, int]:
    return (v.state in _RESOLVED, -int(v.urgency), v.first_seen_unix_s, v.hq_id)


def _action(a: Action) -> dict[str, Any]:
    """One operator action as the card shows it: sending, applied by the robot, or
    refused by it (then the victim's state is what the robots report, and the card
    says so)."""
    answered = a.acked_unix_s is not None
    return {
        "seq": a.action_seq,
        "action": _ACTION_NAMES.get(a.action.value, a.action.name.lower()),
        "robot": a.robot_sysid,
        "created_unix_s": a.created_unix_s,
        "acked": answered and not a.rejected,
        "rejected": answered and a.rejected,
        "why": _why_refused(a) if answered and a.rejected else None,
    }


def _why_refused(a: Action) -> str:
    if a.ack_result == ACK_RESULT_REJECTED:
        answer = "REJECTED"
    else:
        answer = f"answered with unknown result {a.ack_result}"
    if a.action == OperatorAction.LOOK_CLOSER:
        return (
            f"{answer}: no closer look (the robot's closer looks are off, or it no longer "
            "tracks that victim; its message says which)"
        )
    if a.action.whole_robot:
        return f"{answer}: the robot's closer looks are as they were"
    return (
        f"{answer}: the robot does not know that victim, cannot do it, or already applied "
        "a newer decision for it; "
        "not applied, the victim stays as the robots report it"
    )


def _picture_url(hq_id: int, kind: Sensor, version: str | None) -> str | None:
    if version is None:
        return None
    if kind is Sensor.COLOUR:
        return f"/victims/{hq_id}/picture?v={version}"
    return f"/victims/{hq_id}/picture?kind={kind}&v={version}"


def _victim(
    v: HqVictim, actions: list[Action], notes: list[Note], pictures: Mapping[Sensor, str]
) -> dict[str, Any]:
    return {
        "id": v.hq_id,
        # The HQ's name for the person: QGC's map label, and what the robots say once
        # they know the HQ's number (mavlink_io.statustext.victim_name).
        "label": callsign(RETIRED_LABEL.get(v.state, URGENCY_LABEL[v.urgency]), v.hq_id),
        "urgency": v.urgency.name,
        "urgency_rank": int(v.urgency),
        "state": v.state.name,
        "resolved": v.state in _RESOLVED,
        "sources": [{"robot": r, "victim_id": i} for r, i in v.sources],
        "robots": list(v.robots),
        "north_m": round(v.north_m, 3),
        "east_m": round(v.east_m, 3),
        "sigma_m": round(v.sigma_m, 3),
        "ellipse": ellipse_95(v.cov_ne_m2),
        "lat_deg": v.lat_deg,
        "lon_deg": v.lon_deg,
        "visibility_pct": round(v.visibility_pct, 1),
        "first_seen_unix_s": v.first_seen_unix_s,
        "last_seen_unix_s": v.last_seen_unix_s,
        "sightings": v.observations,
        "cues": v.cues.names(),  # colour_body, colour_part, warm; [] not known
        "seen": cue_words(v.cues),  # "colour body · warm"
        "actions_pending": v.actions_pending,
        "actions": [_action(a) for a in actions],
        "notes": [{"text": n.text, "created_unix_s": n.created_unix_s} for n in notes],
        "picture": _picture_url(v.hq_id, Sensor.COLOUR, pictures.get(Sensor.COLOUR)),
        "thermal_picture": _picture_url(v.hq_id, Sensor.THERMAL, pictures.get(Sensor.THERMAL)),
    }


def _robot(
    sysid: int,
    robot: Robot | None,
    status: dict[str, Any] | None,
    track: RobotTrack | None,
    now: float,
    timeout_s: float,
    looks: Action | None = None,
) -> dict[str, Any]:
    """A robot's entry without its path (Page adds the path, kept as JSON); ``looks``
    the operator's newest closer looks off/on for it."""
    heard = max(
        robot.last_heard_unix_s if robot else 0.0, track.last_heard_unix_s if track else 0.0
    )
    return {
        "sysid": sysid,
        "last_heard_unix_s": heard,
        "link_lost": now - heard > timeout_s,
        "status": status,
        "looks_action": None if looks is None else _action(looks),
        "position": (
            None
            if track is None or track.north_m is None
            else {"north_m": round(track.north_m, 2), "east_m": round(track.east_m or 0.0, 2)}
        ),
    }


def robots_lost(
    robots: Iterable[Robot], live: LiveRobots, now: float, timeout_s: float
) -> frozenset[int]:
    """The robots (reported or positioned) not heard for longer than ``timeout_s``."""
    known = {r.sysid: r.last_heard_unix_s for r in robots}
    positioned = live.positioned()
    for sysid, heard in live.last_heard().items():
        if sysid in known or sysid in positioned:
            known[sysid] = max(known.get(sysid, 0.0), heard)
    return frozenset(s for s, heard in known.items() if now - heard > timeout_s)


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


class Page:
    """The page's whole state, kept between builds as one JSON entry per victim and
    per robot: a build replaces only the entries whose victim changed (the caller
    says which) and a robot's path only when it grew, then joins them. Pure."""

    def __init__(self) -> None:
        self._victims: dict[int, tuple[tuple[bool, int, float, int], str]] = {}
        self._order: list[str] | None = None  # the victims' entries in the operator's order
        self._paths: dict[int, tuple[int, str]] = {}  # sysid -> (path version, path JSON)
        self._robots: list[str] = []
        self._statuses: dict[int, tuple[RobotStatus, dict[str, Any]]] = {}
        self.builds = 0  # how many times it was brought up to date (the builder counts)

    def victim_ids(self) -> set[int]:
        return set(self._victims)

    def set_victim(
        self,
        v: HqVictim,
        actions: list[Action],
        notes: list[Note],
        pictures: Mapping[Sensor, str],
    ) -> None:
        """(Re)place one victim's entry; ``actions`` in action_seq order; ``pictures``
        the version of its evidence picture of each kind it has."""
        self._victims[v.hq_id] = (_sort_key(v), _dumps(_victim(v, actions, notes, pictures)))
        self._order = None

    def drop_victim(self, hq_id: int) -> None:
        if self._victims.pop(hq_id, None) is not None:
            self._order = None

    def paths_held(self) -> dict[int, int]:
        """sysid -> the version of the path held (for LiveRobots.tracks)."""
        return {s: version for s, (version, _) in self._paths.items()}

    def set_robots(
        self,
        robots: list[Robot],
        tracks: dict[int, RobotTrack],
        now: float,
        timeout_s: float,
        looks: Mapping[int, Action] | None = None,
    ) -> None:
        """Every robot that reported, and every one with a position; ``looks``: each
        robot's newest closer looks off/on (``robot_actions``)."""
        looks = looks or {}
        registered = {r.sysid: r for r in robots}
        shown = sorted(set(registered) | {s for s, t in tracks.items() if t.north_m is not None})
        entries = []
        for sysid in shown:
            track = tracks.get(sysid)
            if track is not None and track.path is not None:
                path = _dumps([[round(n, 2), round(e, 2)] for n, e in track.path])
                self._paths[sysid] = (track.path_version, path)
            path_json = self._paths.get(sysid, (0, "[]"))[1] if track is not None else "[]"
            robot = registered.get(sysid)
            status = self._status(robot)
            head = _dumps(_robot(sysid, robot, status, track, now, timeout_s, looks.get(sysid)))
            entries.append(f'{head[:-1]},"path":{path_json}}}')  # the path spliced in
        self._robots = entries

    def _status(self, robot: Robot | None) -> dict[str, Any] | None:
        """A robot's last RESCUE_STATUS as JSON values, made again only when it changed."""
        if robot is None or robot.status is None:
            return None
        held = self._statuses.get(robot.sysid)
        if held is None or held[0] != robot.status:
            entry = asdict(robot.status)
            entry["looks_on"] = robot.status.looks_on
            entry["looks"] = robot.status.look_words()  # "looks on: 3 made, 1 confirmed"
            held = (robot.status, entry)
            self._statuses[robot.sysid] = held
        return held[1]

    def json(self, now_unix_s: float, link_timeout_s: float) -> str:
        """The state as the page gets it (``builds``: how many builds it is the result of)."""
        if self._order is None:
            ranked = sorted(self._victims.values(), key=lambda entry: entry[0])
            self._order = [entry for _, entry in ranked]
        head = _dumps(
            {"now_unix_s": now_unix_s, "link_timeout_s": link_timeout_s, "builds": self.builds}
        )
        victims, robots = ",".join(self._order), ",".join(self._robots)
        return f'{head[:-1]},"victims":[{victims}],"robots":[{robots}]}}'


def actions_by_source(actions: Iterable[Action]) -> dict[tuple[int, int], list[Action]]:
    """(robot, robot's victim) -> its actions, in action_seq order."""
    out: dict[tuple[int, int], list[Action]] = {}
    for a in sorted(actions, key=lambda a: a.action_seq):
        out.setdefault((a.robot_sysid, a.victim_id), []).append(a)
    return out


def robot_actions(actions: Iterable[Action]) -> dict[int, Action]:
    """Each robot's newest action about the whole robot (closer looks off or on)."""
    out: dict[int, Action] = {}
    for a in sorted(actions, key=lambda a: a.action_seq):
        if a.action.whole_robot:
            out[a.robot_sysid] = a
    return out


def victim_actions(v: HqVictim, by_source: Mapping[tuple[int, int], list[Action]]) -> list[Action]:
    """The actions on any of an HQ victim's sources, in action_seq order."""
    acts = [a for key in v.sources for a in by_source.get(key, [])]
    return sorted(acts, key=lambda a: a.action_seq)


def snapshot(
    victims: list[HqVictim],
    robots: list[Robot],
    actions: list[Action],
    notes: list[Note],
    tracks: dict[int, RobotTrack],
    pictures: Mapping[int, Mapping[Sensor, str]],
    now_unix_s: float,
    link_timeout_s: float,
) -> dict[str, Any]:
    """The page's whole state built at once (what a Page holds after it was given all)."""
    by_source = actions_by_source(actions)
    by_victim: dict[int, list[Note]] = {}
    for n in notes:
        by_victim.setdefault(n.hq_id, []).append(n)
    page = Page()
    for v in victims:
        page.set_victim(
            v, victim_actions(v, by_source), by_victim.get(v.hq_id, []), pictures.get(v.hq_id, {})
        )
    page.set_robots(robots, tracks, now_unix_s, link_timeout_s, robot_actions(actions))
    return dict(json.loads(page.json(now_unix_s, link_timeout_s)))
