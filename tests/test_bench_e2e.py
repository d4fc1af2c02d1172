"""The end-to-end bench scores what the companion holds at the end of its mission:
each victim ID's latest report, not its first, and not an ID merged away."""

from __future__ import annotations

import dataclasses
from typing import Any

from bench.e2e import _found, _score
from fusion.types import TrackState, Urgency, VictimReport
from mavlink_io.convert import victim_report_to_msg
from scenarios.world import preset


def _msg(victim_id: int, seq: int, north_m: float, east_m: float, state: TrackState) -> Any:
    report = VictimReport(
        victim_id=victim_id,
        robot_sysid=1,
        state=state,
        urgency=Urgency.LIGHT,
        visibility_pct=80.0,
        north_m=north_m,
        east_m=east_m,
        down_m=0.0,
        cov_ne_m2=((0.04, 0.0), (0.0, 0.04)),
        observations=5,
        first_seen_unix_s=1700000000.0,
        last_seen_unix_s=1700000010.0,
    )
    merged = 1 if state is TrackState.MERGED else None
    return victim_report_to_msg(report, seq, 0, 1700000010.0, merged)


def test_the_latest_report_of_each_id_is_scored_and_merged_ids_are_not() -> None:
    world = preset("mixed")
    t1 = world.victims[0]
    messages = [
        # ID 1 was first reported 3 m off, then moved onto T1: it counts where it ended.
        (0.0, _msg(1, 1, t1.north_m + 3.0, t1.east_m, TrackState.CONFIRMED)),
        (1.0, _msg(1, 3, t1.north_m + 0.1, t1.east_m, TrackState.CONFIRMED)),
        # ID 2 was a second ID of T1, merged into ID 1: not a duplicate at the end.
        (0.5, _msg(2, 2, t1.north_m, t1.east_m + 0.2, TrackState.MERGED)),
        # ID 3 lies where no one lies: a false victim.
        (2.0, _msg(3, 4, 0.5, 0.5, TrackState.CONFIRMED)),
    ]
    scored, reported = _score(world, messages)
    assert sorted(r.victim_id for r in reported) == [1, 3]  # ID 2 was merged away
    assert [m.true_id for m in scored.matches] == [t1.victim_id]
    assert scored.matches[0].error_m < 0.15  # where ID 1 ended, not its first report
    assert scored.false_victims == 1
    # The bench names each person found, and the true urgency where it was wrong.
    assert t1.urgency is Urgency.LIGHT
    error = f"{scored.matches[0].error_m:.2f} m"
    assert _found(world, scored, reported) == f"T{t1.victim_id}: LIGHT, {error}"
    wrong = [dataclasses.replace(r, urgency=Urgency.MEDIUM) for r in reported]
    assert _found(world, scored, wrong) == f"T{t1.victim_id}: MEDIUM (is LIGHT), {error}"
    assert sum(scored.duplicates.values()) == 0
    assert scored.true_victims == len(world.victims)
