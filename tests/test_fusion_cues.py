"""Two cameras, one tracker: colour and thermal observations of one person are one
victim with one ID, a person seen only warm can be confirmed although the colour
camera has them in view and sees nothing, and every victim says which cues saw it."""

from __future__ import annotations

import copy

import pytest

from fusion.errors import FusionError
from fusion.params import TrackerParams
from fusion.registry import EventKind
from fusion.tracker import VictimTracker
from fusion.types import Cue, Observation, Sensor, Urgency

T0 = 1_700_000_000.0
PARAMS = TrackerParams()


def obs(
    north_m: float,
    east_m: float,
    t: float,
    sensor: Sensor = Sensor.COLOUR,
    part_only: bool = False,
    visibility_pct: float = 80.0,
) -> Observation:
    return Observation(
        T0 + t,
        north_m,
        east_m,
        ((0.04, 0.0), (0.0, 0.04)),
        visibility_pct,
        1.0,
        3.0,
        part_only=part_only,
        sensor=sensor,
    )


def always(_n: float, _e: float) -> bool:
    return True


def test_one_person_seen_by_both_cameras_is_one_victim_with_both_cues() -> None:
    tracker = VictimTracker(PARAMS)
    for k in range(6):
        tracker.update([obs(2.0, 3.0, k)], T0 + k, always, Sensor.COLOUR)
        tracker.update(
            [obs(2.05, 3.02, k + 0.05, Sensor.THERMAL)], T0 + k + 0.05, always, Sensor.THERMAL
        )
    victims = tracker.victims()
    assert len(victims) == 1
    assert victims[0].cues == Cue.COLOUR_BODY | Cue.WARM
    assert victims[0].cues.names() == ["colour_body", "warm"]
    assert victims[0].to_report(1, 0.0, None).cues == Cue.COLOUR_BODY | Cue.WARM


def test_a_person_seen_only_warm_is_confirmed_while_the_colour_camera_sees_nothing() -> None:
    tracker = VictimTracker(PARAMS)
    confirmed = []
    for k in range(8):
        # The colour camera has the place in view every frame (twice as often as the
        # thermal camera) and sees nothing there: under thin cover, or in the dark.
        tracker.update([], T0 + k, always, Sensor.COLOUR)
        tracker.update([], T0 + k + 0.3, always, Sensor.COLOUR)
        events = tracker.update(
            [obs(4.0, 1.0, k + 0.5, Sensor.THERMAL, part_only=True, visibility_pct=3.0)],
            T0 + k + 0.5,
            always,
            Sensor.THERMAL,
        )
        confirmed += [e.victim for e in events if e.kind == EventKind.CONFIRMED]
    assert len(confirmed) == 1
    assert confirmed[0].cues == Cue.WARM
    assert tracker.victims()[0].urgency == Urgency.CRITICAL


def test_a_colour_phantom_the_thermal_camera_sees_cold_is_not_confirmed() -> None:
    # A plank taken for a body by the colour camera in one frame of three: alone it
    # gathers support; with the thermal camera seeing no warmth there it does not.
    def run(thermal: bool) -> list[int]:
        tracker = VictimTracker(PARAMS)
        for k in range(12):
            tracker.update([obs(5.0, 5.0, k)] if k % 3 == 0 else [], T0 + k, always)
            if thermal:
                tracker.update([], T0 + k + 0.5, always, Sensor.THERMAL)
        return [v.victim_id for v in tracker.victims()]

    assert run(thermal=False) == [1]
    assert run(thermal=True) == []


def test_cues_survive_a_snapshot_and_old_snapshots_read_their_colour_cues() -> None:
    tracker = VictimTracker(PARAMS)
    for k in range(5):
        tracker.update([obs(1.0, 1.0, k, Sensor.THERMAL)], T0 + k, always, Sensor.THERMAL)
    snap = tracker.snapshot()
    restored = VictimTracker.restore(PARAMS, copy.deepcopy(snap))
    assert restored.victims()[0].cues == Cue.WARM
    assert restored.snapshot() == snap

    old = copy.deepcopy(snap)
    for rec in old["tracks"]:
        del rec["warm_hits"], rec["cues"]
    assert VictimTracker.restore(PARAMS, old).victims()[0].cues == Cue.COLOUR_BODY

    bad = copy.deepcopy(snap)
    bad["tracks"][0]["cues"] = 64
    with pytest.raises(FusionError, match=r"tracks\[0\]\.cues"):
        VictimTracker.restore(PARAMS, bad)


def test_merging_two_victims_keeps_every_cue() -> None:
    # Two confirmed victims 0.1 m apart, one seen warm and one in colour, are one
    # person: the survivor has both cues.
    tracker = VictimTracker(PARAMS)
    for k in range(4):
        tracker.update([obs(0.0, 0.0, k, Sensor.THERMAL)], T0 + k, always, Sensor.THERMAL)
    snap = tracker.snapshot()
    twin = copy.deepcopy(snap["tracks"][0])
    twin.update(track_id=2, victim_id=2, x=[0.0, 0.1], cues=int(Cue.COLOUR_BODY), warm_hits=0)
    snap["tracks"].append(twin)
    snap.update(next_track_id=3, next_victim_id=3)
    restored = VictimTracker.restore(PARAMS, snap)
    events = restored.update([], T0 + 5, always)
    assert [e.kind for e in events] == [EventKind.MERGED]
    (survivor,) = [v for v in restored.victims() if v.merged_into is None]
    assert survivor.cues == Cue.COLOUR_BODY | Cue.WARM


def never(_n: float, _e: float) -> bool:
    return False


def test_a_warm_body_the_colour_camera_looked_at_clearly_and_never_saw_is_critical() -> None:
    # The thermal camera sees a person's warmth through a blanket as 40 % of a body;
    # the colour camera, looking at the place in good light, sees only the blanket.
    params = TrackerParams(covered_after_looks=5)
    lit, dark = VictimTracker(params), VictimTracker(params)
    for tracker, looked_at in ((lit, always), (dark, never)):
        for k in range(6):
            warm = [obs(2.0, 3.0, k, Sensor.THERMAL, visibility_pct=40.0)]
            tracker.update(warm, T0 + k, always, Sensor.THERMAL)
            tracker.update([], T0 + k + 0.05, always, Sensor.COLOUR, looked_at)
    (covered,) = lit.victims()
    assert covered.urgency == Urgency.CRITICAL
    assert covered.visibility_pct == params.covered_visibility_pct
    # In the dark the colour camera saw nothing, which says nothing.
    (unlit,) = dark.victims()
    assert unlit.urgency == Urgency.MEDIUM
    # The count survives a restart.
    restored = VictimTracker.restore(params, copy.deepcopy(lit.snapshot()))
    assert restored.snapshot() == lit.snapshot()


def test_colour_looks_do_not_cap_a_body_the_colour_camera_has_seen() -> None:
    tracker = VictimTracker(PARAMS)
    for k in range(8):
        seen = [obs(2.0, 3.0, k, Sensor.THERMAL, visibility_pct=60.0)]
        tracker.update(seen, T0 + k, always, Sensor.THERMAL)
        colour = [obs(2.02, 3.0, k + 0.05, visibility_pct=60.0)] if k == 0 else []
        tracker.update(colour, T0 + k + 0.05, always, Sensor.COLOUR, always)
    (victim,) = tracker.victims()
    assert victim.cues == Cue.COLOUR_BODY | Cue.WARM
    assert victim.urgency == Urgency.LIGHT
