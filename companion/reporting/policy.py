"""When to tell the HQ about a victim: the reporting policy. Pure logic, no I/O.

A victim is reported
- when it is confirmed (NEW; announced to people, spoken: STATUSTEXT with a
  severity QGC speaks);
- again when its urgency class changes. People hear of it only when the victim
  reaches a class higher than any announced before (spoken when that class is
  CRITICAL, quiet text otherwise): a class flapping between MEDIUM and CRITICAL is
  announced once per class, and a de-escalation is never announced (the HQ still
  gets every change in the full report);
- when it has moved by more than ``move_threshold_sigma`` of its uncertainty and by
  at least ``move_min_m`` since the last report, and that report is at least
  ``update_min_interval_s`` old (quiet: the full report and the map marker, no
  STATUSTEXT; a sharpening fix moves a little at every frame, which is no news);
- when its state changes (merged, not seen recently, seen again, operator marks);
- on request from the HQ (RESEND);
never once per frame. What was last reported per victim is part of the saved state,
so a restart re-announces nothing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from fusion.registry import EventKind, TrackEvent, Victim, moved_beyond
from fusion.types import TrackState, Urgency

# RESCUE_REPORT_FLAGS of the dialect (mavlink_io/dialects/rescue.xml).
FLAG_NEW = 2
FLAG_URGENCY_CHANGED = 4
FLAG_MOVED = 8
FLAG_REQUESTED = 16


@dataclass(frozen=True)
class Reported:
    """What the HQ was last told about one victim."""

    state: TrackState
    urgency: Urgency
    north_m: float
    east_m: float
    t_unix_s: float  # when it was reported
    announced: Urgency  # the highest urgency people were told of


@dataclass(frozen=True)
class Decision:
    """Report ``victim`` with these flags; ``announce``: also tell people (STATUSTEXT);
    ``spoken``: with a severity QGC speaks (else quiet text)."""

    victim: Victim
    flags: int
    announce: bool
    spoken: bool = False


class ReportPolicy:
    """Decides reports from tracker events and the current victims."""

    def __init__(
        self,
        move_threshold_sigma: float,
        move_min_m: float = 0.0,
        update_min_interval_s: float = 0.0,
    ) -> None:
        self.move_threshold_sigma = move_threshold_sigma
        self.move_min_m = move_min_m
        self.update_min_interval_s = update_min_interval_s
        self.reported: dict[int, Reported] = {}

    def decide(
        self, events: Sequence[TrackEvent], victims: Iterable[Victim], now_unix_s: float
    ) -> list[Decision]:
        """The reports owed after one tracker update; records them as reported."""
        decisions: dict[int, Decision] = {}
        for event in events:
            decision = self._for_event(event)
            if decision is not None:
                decisions[decision.victim.victim_id] = _merge(
                    decisions.get(decision.victim.victim_id), decision
                )
        for victim in victims:
            last = self.reported.get(victim.victim_id)
            if victim.victim_id in decisions or last is None:
                continue
            if self._moved(victim, last, now_unix_s):
                decisions[victim.victim_id] = Decision(victim, FLAG_MOVED, announce=False)
        for d in decisions.values():
            tells_urgency = d.announce and d.flags & (FLAG_NEW | FLAG_URGENCY_CHANGED)
            self._record(d.victim, now_unix_s, announced=bool(tells_urgency))
        return list(decisions.values())

    def _moved(self, victim: Victim, last: Reported, now_unix_s: float) -> bool:
        if victim.state not in (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY):
            return False
        if now_unix_s - last.t_unix_s < self.update_min_interval_s:
            return False
        distance_m = math.hypot(victim.north_m - last.north_m, victim.east_m - last.east_m)
        return distance_m >= self.move_min_m and moved_beyond(
            victim, last.north_m, last.east_m, self.move_threshold_sigma
        )

    def requested(
        self, victims: Iterable[Victim], now_unix_s: float, flags: int = FLAG_REQUESTED
    ) -> list[Decision]:
        """Reports of every victim already reported: on request from the HQ (RESEND),
        or with ``flags=0`` when there is more to say (the origin became known)."""
        out = [Decision(v, flags, announce=False) for v in victims if v.victim_id in self.reported]
        for d in out:
            self._record(d.victim, now_unix_s)
        return out

    def _for_event(self, event: TrackEvent) -> Decision | None:
        v = event.victim
        last = self.reported.get(v.victim_id)
        if event.kind is EventKind.CONFIRMED:
            if last is None:
                return Decision(v, FLAG_NEW, announce=True, spoken=True)
            return None  # already reported (e.g. before a restart)
        if last is None and event.kind is not EventKind.MERGED:
            # Not yet reported: nothing to update. A merge of a never-reported track
            # is also silent (below).
            return None
        if event.kind is EventKind.URGENCY_CHANGED:
            if last is not None and last.urgency == v.urgency:
                return None
            if last is not None and v.urgency <= last.announced:
                return Decision(v, FLAG_URGENCY_CHANGED, announce=False)  # flapping, or better
            return Decision(
                v, FLAG_URGENCY_CHANGED, announce=True, spoken=v.urgency is Urgency.CRITICAL
            )
        if event.kind is EventKind.MERGED:
            return Decision(v, 0, announce=True) if last is not None else None
        if event.kind is EventKind.OPERATOR:
            return Decision(v, 0, announce=True)
        # NOT_SEEN_RECENTLY, SEEN_AGAIN: the state changed; the HQ should know.
        return Decision(v, 0, announce=False)

    def _record(self, v: Victim, now_unix_s: float, *, announced: bool = False) -> None:
        last = self.reported.get(v.victim_id)
        told = v.urgency if last is None else last.announced
        if announced:
            told = max(told, v.urgency)
        self.reported[v.victim_id] = Reported(
            v.state, v.urgency, v.north_m, v.east_m, now_unix_s, told
        )

    # -- persistence ---------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        return {
            str(vid): [
                r.state.name,
                r.urgency.name,
                r.north_m,
                r.east_m,
                r.t_unix_s,
                r.announced.name,
            ]
            for vid, r in self.reported.items()
        }

    def restore(self, snapshot: Any) -> None:
        """Load what was reported; ValueError naming the bad entry. An entry saved
        before announcements were tracked (five fields) counts its urgency as told."""
        if not isinstance(snapshot, dict):
            raise ValueError("reported-state snapshot must be a JSON object")
        reported: dict[int, Reported] = {}
        for key, value in snapshot.items():
            try:
                state, urgency, north_m, east_m, t_unix_s, *rest = value
                if len(rest) > 1:
                    raise ValueError("too many fields")
                n, e, t = float(north_m), float(east_m), float(t_unix_s)
                if not math.isfinite(n + e + t) or int(key) < 1:
                    raise ValueError("not a victim ID and finite numbers")
                reported[int(key)] = Reported(
                    TrackState[state],
                    Urgency[urgency],
                    n,
                    e,
                    t,
                    Urgency[rest[0] if rest else urgency],
                )
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"reported-state entry {key!r} = {value!r} is malformed") from None
        self.reported = reported


def _merge(a: Decision | None, b: Decision) -> Decision:
    if a is None:
        return b
    return Decision(b.victim, a.flags | b.flags, a.announce or b.announce, a.spoken or b.spoken)
