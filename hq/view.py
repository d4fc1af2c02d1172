"""What the operator sees: HQ victims (merged groups of robot victims), read from the registry.

An HQ victim keeps the highest urgency of its sources and the lowest visibility
(the most buried view of the person), the earliest first-seen and latest
last-seen times, the information-weighted position (hq.merge.fuse) and every cue
that saw it (hq.merge.union_cues). Sources a
robot itself merged into another of its victims (state MERGED) are folded into
that victim and not shown on their own.

State, in order of precedence: an operator decision (rescued, false alarm,
confirmed; acknowledged or still being sent; not one the robot REJECTED) or a robot's RESCUED / FALSE_ALARM, then CONFIRMED, NOT_SEEN_RECENTLY,
TENTATIVE.
"""

from __future__ import annotations

from dataclasses import dataclass

from fusion.types import NO_CUES, Cov2, Cue, TrackState, Urgency
from hq import merge
from hq.merge import Origins, placed
from hq.records import Action, OperatorAction, Source
from hq.registry import Registry

_STATE_RANK = {
    TrackState.RESCUED: 5,
    TrackState.FALSE_ALARM: 4,
    TrackState.CONFIRMED: 3,
    TrackState.NOT_SEEN_RECENTLY: 2,
    TrackState.TENTATIVE: 1,
    TrackState.MERGED: 0,
}
_ACTION_STATE = {
    OperatorAction.RESCUED: TrackState.RESCUED,
    OperatorAction.FALSE_ALARM: TrackState.FALSE_ALARM,
    OperatorAction.CONFIRMED: TrackState.CONFIRMED,
}


@dataclass(frozen=True)
class HqVictim:
    hq_id: int
    sources: tuple[tuple[int, int], ...]  # (robot sysid, robot's victim_id)
    urgency: Urgency
    visibility_pct: float
    state: TrackState
    north_m: float
    east_m: float
    down_m: float
    cov_ne_m2: Cov2
    sigma_m: float
    lat_deg: float | None
    lon_deg: float | None
    alt_m: float | None
    first_seen_unix_s: float
    last_seen_unix_s: float
    observations: int
    actions_pending: int  # operator actions sent but not yet acknowledged by the robot
    cues: Cue = NO_CUES  # which sensing saw it, on any robot (none: not known)

    @property
    def robots(self) -> tuple[int, ...]:
        return tuple(sorted({r for r, _ in self.sources}))

    @property
    def has_global(self) -> bool:
        return self.lat_deg is not None


def _sigma_m(cov: Cov2) -> float:
    (a, b), (_, d) = cov
    half_trace = 0.5 * (a + d)
    return float((half_trace + ((0.5 * (a - d)) ** 2 + b * b) ** 0.5) ** 0.5)


def _state(members: list[Source], actions: list[Action]) -> TrackState:
    # The robot refused the rejected ones; a closer look decides nothing about the state.
    applied = [a for a in actions if not a.rejected and a.action.decides_state]
    if applied:
        latest = max(applied, key=lambda a: a.action_seq)
        return _ACTION_STATE[latest.action]
    return max((m.report.state for m in members), key=_STATE_RANK.__getitem__)


def build(sources: list[Source], actions: list[Action], origins: Origins) -> list[HqVictim]:
    """The HQ victims, most urgent first, then by HQ ID."""
    groups: dict[int, list[Source]] = {}
    for src in sources:
        if src.report.state != TrackState.MERGED:
            groups.setdefault(src.hq_id, []).append(src)
    by_source: dict[tuple[int, int], list[Action]] = {}
    for action in actions:
        by_source.setdefault((action.robot_sysid, action.victim_id), []).append(action)
    out = []
    for hq_id, members in groups.items():
        keys = [(m.report.robot_sysid, m.report.victim_id) for m in members]
        acts = [a for k in keys for a in by_source.get(k, [])]
        fused = merge.fuse([placed(m.report, origins) for m in members])
        reports = [m.report for m in members]
        geo = fused.geo
        out.append(
            HqVictim(
                hq_id=hq_id,
                sources=tuple(sorted(keys)),
                urgency=max(r.urgency for r in reports),
                visibility_pct=min(r.visibility_pct for r in reports),
                state=_state(members, acts),
                north_m=fused.north_m,
                east_m=fused.east_m,
                down_m=sum(r.down_m for r in reports) / len(reports),
                cov_ne_m2=fused.cov_ne_m2,
                sigma_m=_sigma_m(fused.cov_ne_m2),
                lat_deg=None if geo is None else geo[0],
                lon_deg=None if geo is None else geo[1],
                alt_m=None if geo is None else geo[2],
                first_seen_unix_s=min(r.first_seen_unix_s for r in reports),
                last_seen_unix_s=max(r.last_seen_unix_s for r in reports),
                observations=sum(r.observations for r in reports),
                actions_pending=sum(1 for a in acts if a.acked_unix_s is None),
                cues=merge.union_cues(reports),
            )
        )
    out.sort(key=lambda v: (-int(v.urgency), v.hq_id))
    return out


def hq_victims(registry: Registry) -> list[HqVictim]:
    return build(registry.sources(), registry.actions(), registry.origins())
