"""An operator's note stays with the person when the robot merges that victim into another.

Real registry and notes on one SQLite file, read back the way the console shows them
(hq.view, hq.web.state.snapshot).
"""

from __future__ import annotations

from pathlib import Path

from fusion.types import TrackState, Urgency, VictimReport
from hq.records import IncomingReport
from hq.registry import Registry
from hq.view import hq_victims
from hq.web.notes import Notes
from hq.web.state import snapshot

T_UNIX_S = 1_700_000_000.0


def _report(victim: int, north_m: float, state: TrackState = TrackState.CONFIRMED) -> VictimReport:
    return VictimReport(
        victim_id=victim,
        robot_sysid=3,
        state=state,
        urgency=Urgency.MEDIUM,
        visibility_pct=30.0,
        north_m=north_m,
        east_m=0.0,
        down_m=0.0,
        cov_ne_m2=((0.25, 0.0), (0.0, 0.25)),
        observations=3,
        first_seen_unix_s=T_UNIX_S - 1.0,
        last_seen_unix_s=T_UNIX_S,
    )


def _shown_notes(reg: Registry, notes: Notes) -> dict[tuple[tuple[int, int], ...], list[str]]:
    """What the console shows: each HQ victim (by its robots' victims) and its notes."""
    victims = hq_victims(reg)
    state = snapshot(victims, reg.robots(), reg.actions(), notes.all(), {}, {}, T_UNIX_S, 5.0)
    return {
        tuple(tuple(s.values()) for s in v["sources"]): [n["text"] for n in v["notes"]]
        for v in state["victims"]
    }


def test_a_note_follows_the_victim_the_robot_merged_it_into(tmp_path: Path) -> None:
    path = tmp_path / "hq.sqlite"
    with Registry(path) as reg:
        reg.store_reports(
            [
                IncomingReport(_report(1, 0.0), 1, 1, 0, 191, T_UNIX_S),
                IncomingReport(_report(2, 6.0), 2, 2, 0, 191, T_UNIX_S),
            ]
        )
        second = next(v.hq_id for v in hq_victims(reg) if v.sources == ((3, 2),))
        notes = Notes(path)
        try:
            notes.add(second, "two voices heard, team B digging")
            assert _shown_notes(reg, notes)[((3, 2),)] == ["two voices heard, team B digging"]
            # The robot's tracker finds its victim 2 is its victim 1 and says so.
            merged = IncomingReport(_report(2, 0.5, TrackState.MERGED), 3, 3, 1, 191, T_UNIX_S)
            reg.store_reports([merged])
            assert _shown_notes(reg, notes) == {((3, 1),): ["two voices heard, team B digging"]}
        finally:
            notes.close()
    # and it stays there after a restart of the HQ
    with Registry(path) as reg:
        notes = Notes(path)
        try:
            assert _shown_notes(reg, notes) == {((3, 1),): ["two voices heard, team B digging"]}
        finally:
            notes.close()


def test_a_note_stays_on_a_victim_another_robot_still_sees(tmp_path: Path) -> None:
    """Robot 3's victim 2 and robot 4's victim 7 are one HQ victim; robot 3 merging its
    victim 2 away leaves robot 4's view of that person, and the note with it."""
    path = tmp_path / "hq.sqlite"
    other = VictimReport(**{**_report(7, 6.0).__dict__, "robot_sysid": 4})
    with Registry(path) as reg:
        reg.store_reports(
            [
                IncomingReport(_report(1, 0.0), 1, 1, 0, 191, T_UNIX_S),
                IncomingReport(_report(2, 6.0), 2, 2, 0, 191, T_UNIX_S),
                IncomingReport(other, 1, 1, 0, 191, T_UNIX_S),
            ]
        )
        shared = next(v.hq_id for v in hq_victims(reg) if v.sources == ((3, 2), (4, 7)))
        notes = Notes(path)
        try:
            notes.add(shared, "team B on it")
            merged = IncomingReport(_report(2, 0.5, TrackState.MERGED), 3, 3, 1, 191, T_UNIX_S)
            reg.store_reports([merged])
            assert _shown_notes(reg, notes) == {((3, 1),): [], ((4, 7),): ["team B on it"]}
        finally:
            notes.close()
