"""What the operator hears: once per victim and class reached upwards, never for
flapping, at a rate the link carries; health changes once each."""

from __future__ import annotations

import dataclasses
from collections import Counter

from companion.reporting.announcements import Announcement, Announcements, Conditions
from companion.reporting.policy import FLAG_URGENCY_CHANGED, ReportPolicy
from fusion.params import TrackerParams
from fusion.registry import EventKind, TrackEvent, Victim
from fusion.tracker import VictimTracker
from fusion.types import Observation, TrackState, Urgency

T0 = 1_700_000_000.0


def _victim(**kw: object) -> Victim:
    base: dict[str, object] = dict(
        victim_id=1,
        state=TrackState.CONFIRMED,
        urgency=Urgency.MEDIUM,
        visibility_pct=30.0,
        north_m=5.0,
        east_m=2.0,
        cov_ne_m2=((0.04, 0.0), (0.0, 0.04)),
        observations=5,
        first_seen_unix_s=100.0,
        last_seen_unix_s=101.0,
        log_odds=3.0,
        merged_into=None,
    )
    base.update(kw)
    return Victim(**base)  # type: ignore[arg-type]


def _policy() -> ReportPolicy:
    return ReportPolicy(move_threshold_sigma=1.0, move_min_m=0.3, update_min_interval_s=5.0)


def test_urgency_flapping_is_announced_once_per_class_reached_upwards() -> None:
    p = _policy()
    v = _victim(urgency=Urgency.LIGHT)
    (new,) = p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    assert new.announce and new.spoken
    heard = []
    classes = [Urgency.MEDIUM, Urgency.LIGHT, Urgency.MEDIUM, Urgency.CRITICAL, Urgency.MEDIUM]
    classes += [Urgency.CRITICAL, Urgency.LIGHT, Urgency.CRITICAL, Urgency.MEDIUM]
    for t, urgency in enumerate(classes, start=101):
        u = dataclasses.replace(v, urgency=urgency)
        (d,) = p.decide([TrackEvent(EventKind.URGENCY_CHANGED, u)], [u], float(t))
        assert d.flags == FLAG_URGENCY_CHANGED  # the HQ hears every change
        if d.announce:
            heard.append((urgency, d.spoken))
    # MEDIUM quietly (an escalation, not an emergency), CRITICAL spoken; then silence.
    assert heard == [(Urgency.MEDIUM, False), (Urgency.CRITICAL, True)]


def test_what_was_announced_survives_a_restart() -> None:
    p = _policy()
    v = _victim(urgency=Urgency.CRITICAL)
    p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    q = _policy()
    q.restore(p.snapshot())
    med = dataclasses.replace(v, urgency=Urgency.MEDIUM)
    q.decide([TrackEvent(EventKind.URGENCY_CHANGED, med)], [med], 101.0)
    (d,) = q.decide([TrackEvent(EventKind.URGENCY_CHANGED, v)], [v], 102.0)
    assert not d.announce
    # A state saved before this change (five fields) counts its urgency as told.
    old = {"1": ["CONFIRMED", "MEDIUM", 5.0, 2.0, 100.0]}
    r = _policy()
    r.restore(old)
    (d,) = r.decide([TrackEvent(EventKind.URGENCY_CHANGED, v)], [v], 103.0)
    assert d.announce and d.spoken


def test_flapping_scenario_with_the_real_tracker() -> None:
    """Two victims whose visibility swings across the class boundaries (as a
    partly hidden body does while the rover drives past) for two minutes at 10 Hz:
    the tracker's urgency changes many times, people hear one line per class."""
    tracker = VictimTracker(TrackerParams())
    policy = _policy()
    swings = {  # (north, east): visibility phases, 8 s each
        (2.0, 1.0): [30.0, 4.0, 60.0, 4.0, 30.0, 2.0, 55.0, 30.0, 4.0, 60.0, 30.0, 4.0, 60.0],
        (6.0, -3.0): [70.0, 25.0, 70.0, 5.0, 70.0, 25.0, 3.0, 70.0, 25.0, 70.0, 5.0, 70.0, 25.0],
    }
    changes: Counter[int] = Counter()
    heard: list[tuple[int, Urgency, bool]] = []
    for k in range(8 * 10 * 13):
        t = T0 + 0.1 * k
        observations = [
            Observation(t, n, e, ((0.04, 0.0), (0.0, 0.04)), phases[k // 80], 1.0, 3.0)
            for (n, e), phases in swings.items()
        ]
        events = tracker.update(observations, t, lambda _n, _e: True)
        changes.update(e.victim.victim_id for e in events if e.kind is EventKind.URGENCY_CHANGED)
        for d in policy.decide(events, tracker.victims(), t):
            if d.announce:
                heard.append((d.victim.victim_id, d.victim.urgency, d.spoken))
    assert len(changes) == 2 and min(changes.values()) >= 4, changes  # it did flap
    per_class = Counter((vid, urgency) for vid, urgency, _ in heard)
    assert set(per_class.values()) == {1}, heard  # once per victim and class
    for vid in changes:
        told = [u for v, u, _ in heard if v == vid]
        assert told == sorted(told), heard  # only upwards
        assert told[-1] is Urgency.CRITICAL
    assert all(spoken for _, u, spoken in heard if u is Urgency.CRITICAL)


def test_rate_limit_bursts_then_paces_and_never_drops_spoken_first() -> None:
    a = Announcements(burst=3, interval_s=2.0, max_waiting=5)
    for i in range(8):
        a.put(Announcement(f"line {i}", 6 if i in (1, 2, 4) else 2, spoken=i not in (1, 2, 4)))
    # 8 offered, 5 may wait: the three quiet ones went first.
    assert a.dropped == 3
    assert [x.text for x in a.take(0.0)] == ["line 0", "line 3", "line 5"]
    assert a.take(1.0) == []
    assert a.seconds_until_due(1.0) == 1.0
    assert [x.text for x in a.take(2.0)] == ["line 6"]
    assert [x.text for x in a.take(4.0)] == ["line 7"]
    assert a.seconds_until_due(4.0) is None


def test_conditions_once_per_change_and_flapping_held() -> None:
    c = Conditions(hold_s=10.0)
    assert c.update("camera", True, 0.0) == []  # fine from the start: nothing to say
    assert c.update("camera", False, 1.0) == [("camera", False)]
    assert c.update("camera", False, 2.0) == []  # still lost: not repeated
    assert c.update("camera", True, 3.0) == []  # back, but within the hold
    assert c.update("camera", False, 4.0) == []  # and lost again
    assert c.due(11.5) == []  # settled where it was announced: nothing new
    assert c.update("camera", True, 12.0) == [("camera", True)]
    assert c.update("disk", False, 12.5) == [("disk", False)]  # conditions are independent
    assert c.update("camera", False, 13.0) == []
    assert c.due(22.0) == [("camera", False)]  # the hold is over: the settled state


def test_a_victim_only_the_thermal_camera_saw_is_announced_warm_only() -> None:
    """What the operator hears of a person under debris or in the dark: the thermal
    camera alone found them, so nothing may show when the team gets there."""
    import threading

    from companion.reporting.announcements import Announcer
    from companion.reporting.policy import Decision
    from fusion.types import Cue

    wake = threading.Event()
    ann = Announcer(enabled=True, announce_severity=5, robot_sysid=lambda: 1, wake=wake)
    v = _victim(victim_id=3, urgency=Urgency.CRITICAL, cues=Cue.WARM)
    ann.victim(Decision(v, 2, announce=True, spoken=True), v.to_report(1, 0.0, None))
    seen = dataclasses.replace(v, victim_id=4, cues=Cue.WARM | Cue.COLOUR_BODY)
    ann.victim(Decision(seen, 2, announce=True, spoken=True), seen.to_report(1, 0.0, None))
    (warm, both) = ann.take(0.0)
    assert warm.text == "R1 CRITICAL victim 3, warm only, 5.0 m N 2.0 m E" and warm.spoken
    assert len(warm.text) <= 50 and wake.is_set()
    assert both.text == "R1 CRITICAL victim 4, 5.0 m N 2.0 m E of start"
