"""The closer looks' pure decisions (companion/looks/choose.py, machine.py): which candidate, from where,
what a look settled, and the safety rules of the steps, without any link."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.config import LooksConfig
from companion.config_load import config_from_dict, load_config
from companion.looks.choose import Kind, candidates, compass, known_free, settlement, viewpoint
from companion.looks.machine import LookMachine, Phase
from companion.looks.steps import Face, GoTo, RequestMissionCurrent, Rover, SetCurrent, SetMode
from fusion.registry import Victim
from fusion.types import Cue, TrackState, Urgency
from mavlink_io.guided import (
    MAV_AUTOPILOT_PX4,
    MAV_CMD_DO_SET_MODE,
    ROVER_AUTO,
    ROVER_GUIDED,
    ROVER_HOLD,
    ROVER_MANUAL,
    ROVER_RTL,
    ROVER_SMART_RTL,
    AutopilotView,
)

S = LooksConfig(enabled=True)


def _victim(
    track_id: int = 1,
    state: TrackState = TrackState.TENTATIVE,
    visibility_pct: float = 80.0,
    ne: tuple[float, float] = (5.0, 5.0),
    first_seen: float = 0.0,
    cues: Cue = Cue.COLOUR_BODY,
    victim_id: int = 0,
) -> Victim:
    return Victim(
        victim_id=victim_id,
        state=state,
        urgency=Urgency.from_visibility(visibility_pct),
        visibility_pct=visibility_pct,
        north_m=ne[0],
        east_m=ne[1],
        cov_ne_m2=((0.1, 0.0), (0.0, 0.1)),
        observations=1,
        first_seen_unix_s=first_seen,
        last_seen_unix_s=first_seen,
        log_odds=0.85,
        merged_into=None,
        track_id=track_id,
        cues=cues,
    )


# -- candidates and settlements ------------------------------------------------------------


def test_candidates_are_old_tentatives_uncertain_urgencies_and_warm_only_finds() -> None:
    victims = [
        _victim(1, first_seen=0.0),  # tentative for 10 s
        _victim(2, first_seen=8.0),  # tentative for 2 s: not yet
        _victim(3, TrackState.CONFIRMED, 48.0, victim_id=1),  # near the 50 % bound
        _victim(4, TrackState.CONFIRMED, 30.0, victim_id=2),  # clearly MEDIUM
        _victim(5, TrackState.CONFIRMED, 70.0, cues=Cue.WARM, victim_id=3),
        _victim(6, TrackState.FALSE_ALARM, 48.0, victim_id=4),  # the operator decided
        _victim(7, TrackState.RESCUED, 9.0, victim_id=5),
    ]
    found = candidates(victims, 10.0, S)
    assert [(c.track_id, c.kind) for c in found] == [
        (1, Kind.TENTATIVE),
        (5, Kind.WARM_ONLY),
        (3, Kind.URGENCY),
    ]


def test_settlement_says_what_the_look_changed() -> None:
    (tentative,) = candidates([_victim(1)], 10.0, S)
    assert settlement(tentative, None) == "rejected"
    assert settlement(tentative, _victim(1)) is None
    assert settlement(tentative, _victim(1, TrackState.CONFIRMED, victim_id=3)) == "confirmed"
    (urgent,) = candidates([_victim(2, TrackState.CONFIRMED, 52.0, victim_id=1)], 10.0, S)
    assert settlement(urgent, _victim(2, TrackState.CONFIRMED, 52.0)) is None
    changed = _victim(2, TrackState.CONFIRMED, 40.0, victim_id=1)
    assert settlement(urgent, changed) == "urgency changed to MEDIUM"
    (warm,) = candidates([_victim(3, TrackState.CONFIRMED, cues=Cue.WARM, victim_id=2)], 10, S)
    both = _victim(3, TrackState.CONFIRMED, cues=Cue.WARM | Cue.COLOUR_BODY, victim_id=2)
    assert settlement(warm, both) == "seen in colour"


def test_compass_words() -> None:
    assert compass((0.0, 0.0), (1.5, 1.5)) == "2 m NE"
    assert compass((0.0, 0.0), (-3.0, 0.0)) == "3 m S"
    assert compass((0.0, 0.0), (0.0, -1.0)) == "1 m W"


# -- viewpoints ------------------------------------------------------------------------------

coord = st.floats(-20.0, 20.0, allow_nan=False)
point = st.tuples(coord, coord)


@settings(max_examples=300, deadline=None)
@given(
    target=point,
    driven=st.lists(point, max_size=60),
    avoid=st.lists(point, max_size=8),
    rover=point,
)
def test_a_viewpoint_is_in_range_beside_the_driven_path_clear_and_facing(
    target: tuple[float, float],
    driven: list[tuple[float, float]],
    avoid: list[tuple[float, float]],
    rover: tuple[float, float],
) -> None:
    v = viewpoint(target, driven, [*avoid, target], rover, S)
    if v is None:
        return
    d = math.dist(v.ne, target)
    assert S.view_min_m - 1e-9 <= d <= S.view_max_m + 1e-9
    assert min(math.dist(v.ne, p) for p in driven) <= S.beside_path_m + 1e-9
    assert all(math.dist(v.ne, a) >= S.clearance_m for a in [*avoid, target])
    assert known_free(rover, v.ne, driven, [*avoid, target], S)
    for k in range(11):  # the leg there, checked independently every 0.1 of its length
        x = (rover[0] + (v.north_m - rover[0]) * k / 10, rover[1] + (v.east_m - rover[1]) * k / 10)
        assert min(math.dist(x, p) for p in driven) <= S.beside_path_m + 1e-9
        assert all(math.dist(x, a) >= S.clearance_m - 1e-9 for a in [*avoid, target])
    facing = math.atan2(target[1] - v.east_m, target[0] - v.north_m)
    assert abs(math.remainder(v.yaw_rad - facing, math.tau)) < 1e-9


def test_no_viewpoint_whose_way_there_leaves_the_driven_path_or_passes_someone() -> None:
    lane = [(0.0, e * 0.25) for e in range(41)]  # 10 m east along north = 0
    # The rover stands 3 m off the lane's far end: the leg would cross unknown ground.
    assert viewpoint((1.2, 5.0), lane, [(1.2, 5.0)], (3.0, 10.0), S) is None
    # On the lane, with a victim lying across it between the rover and the candidate.
    assert viewpoint((1.2, 5.0), lane, [(1.2, 5.0), (0.3, 8.0)], (0.0, 10.0), S) is None
    assert viewpoint((1.2, 5.0), lane, [(1.2, 5.0)], (0.0, 10.0), S) is not None


def test_no_viewpoint_without_driven_path_near_it_or_when_another_find_is_in_the_way() -> None:
    driven = [(0.0, float(e)) for e in range(10)]  # a lane east along north = 0
    assert viewpoint((5.0, 5.0), driven, [], (0.0, 9.0), S) is None  # 5 m off the lane
    v = viewpoint((1.2, 5.0), driven, [(1.2, 5.0)], (0.0, 9.0), S)
    assert v is not None and abs(v.north_m) <= S.beside_path_m
    # A victim lying on the lane beside the candidate: no viewpoint next to it.
    blocked = [(1.2, 5.0), *[(0.0, e / 2) for e in range(20)]]
    assert viewpoint((1.2, 5.0), driven, blocked, (0.0, 9.0), S) is None


# -- the steps --------------------------------------------------------------------------------


def _ap(now: float, mode: int, **kw: object) -> AutopilotView:
    base: dict[str, object] = {
        "mode": mode,
        "armed": True,
        "ardupilot_rover": True,
        "autopilot": 3,
        "heartbeat_s": now,
    }
    base.update(kw)
    return AutopilotView(**base)  # type: ignore[arg-type]


def _machine_with_path() -> tuple[LookMachine, dict[int, Victim]]:
    m = LookMachine(S)
    for e in range(12):
        m.path.add(0.0, e * 0.5)
    victim = _victim(1, ne=(1.2, 3.0))
    return m, {1: victim}


def _phase(m: LookMachine) -> Phase:
    return m.phase  # read afresh: mypy would narrow the attribute across steps


def _start(m: LookMachine, victims: dict[int, Victim], now: float = 100.0) -> list[object]:
    found = candidates(victims.values(), 10.0, S)
    cmds, says = m.step(now, Rover(True, 0.0, 5.5, 0.0), _ap(now, ROVER_AUTO), found, victims)
    return [*cmds, *says]


@pytest.mark.parametrize("mode", [ROVER_MANUAL, ROVER_HOLD, ROVER_RTL, ROVER_SMART_RTL])
def test_no_look_outside_auto(mode: int) -> None:
    m, victims = _machine_with_path()
    found = candidates(victims.values(), 10.0, S)
    cmds, says = m.step(100.0, Rover(True, 0.0, 5.5, 0.0), _ap(100.0, mode), found, victims)
    assert (cmds, says, m.phase) == ([], [], Phase.IDLE)


def test_no_look_disarmed_off_without_link_or_on_a_stale_heartbeat() -> None:
    m, victims = _machine_with_path()
    found = candidates(victims.values(), 10.0, S)
    here = Rover(True, 0.0, 5.5, 0.0)
    assert m.step(100.0, here, _ap(100.0, ROVER_AUTO, armed=False), found, victims) == ([], [])
    assert m.step(100.0, here, _ap(90.0, ROVER_AUTO), found, victims) == ([], [])
    assert m.step(100.0, Rover(False), _ap(100.0, ROVER_AUTO), found, victims) == ([], [])
    m.set_enabled(False)
    assert m.step(100.0, here, _ap(100.0, ROVER_AUTO), found, victims) == ([], [])


def test_px4_is_refused_once_and_clearly() -> None:
    m, victims = _machine_with_path()
    found = candidates(victims.values(), 10.0, S)
    px4 = _ap(100.0, ROVER_AUTO, ardupilot_rover=False, autopilot=MAV_AUTOPILOT_PX4)
    cmds, says = m.step(100.0, Rover(True, 0.0, 5.5, 0.0), px4, found, victims)
    assert cmds == [] and "need ArduPilot Rover" in says[0].text
    assert m.step(101.0, Rover(True, 0.0, 5.5, 0.0), px4, found, victims) == ([], [])


def test_a_whole_look_goes_guided_drives_faces_looks_and_resumes_at_its_item() -> None:
    m, victims = _machine_with_path()
    out = _start(m, victims)
    assert out[0] == SetMode(ROVER_GUIDED)
    assert m.phase == Phase.GUIDED
    acks = {MAV_CMD_DO_SET_MODE: (0, 100.5)}
    ap = _ap(100.6, ROVER_GUIDED, acks=acks)
    rover = Rover(True, 0.0, 5.5, 0.0)
    assert m.step(100.7, rover, ap, [], victims)[0] == [RequestMissionCurrent()]
    ap = _ap(100.8, ROVER_GUIDED, acks=acks, mission_seq=7, mission_s=100.8)
    (goto,), _ = m.step(100.9, rover, ap, [], victims)
    assert isinstance(goto, GoTo)
    assert _phase(m) == Phase.DRIVING
    assert m.look is not None
    view = m.look.view
    there = Rover(True, view.north_m, view.east_m, 0.0)
    (face,), _ = m.step(105.0, there, _ap(105.0, ROVER_GUIDED, acks=acks), [], victims)
    assert face == Face(view.yaw_rad) and _phase(m) == Phase.LOOKING
    faced = Rover(True, view.north_m, view.east_m, view.yaw_rad)
    m.step(106.0, faced, _ap(106.0, ROVER_GUIDED, acks=acks), [], victims)
    cmds, says = m.step(106.0 + S.look_s, faced, _ap(110.0, ROVER_GUIDED), [], victims)
    assert cmds == [GoTo(0.0, 5.5)]  # back to where it left the route, the way it came
    assert "still unsettled" in says[0].text
    assert _phase(m) == Phase.RETURNING
    back = Rover(True, 0.0, 5.45, 0.0)
    cmds, _ = m.step(110.5, back, _ap(110.5, ROVER_GUIDED), [], victims)
    assert cmds == [SetCurrent(7), SetMode(ROVER_AUTO)]
    done = _ap(111.0, ROVER_AUTO, acks={MAV_CMD_DO_SET_MODE: (0, 111.0)})
    assert m.step(111.2, faced, done, [], victims) == ([], [])
    assert _phase(m) == Phase.IDLE and m.counts.started == 1
    # Never a second look at the same candidate.
    assert _start(m, victims, 120.0) == []


def test_a_refused_guided_aborts_without_touching_the_mission() -> None:
    m, victims = _machine_with_path()
    _start(m, victims)
    refused = _ap(100.5, ROVER_AUTO, acks={MAV_CMD_DO_SET_MODE: (4, 100.5)})
    cmds, says = m.step(100.6, Rover(True, 0.0, 5.5, 0.0), refused, [], victims)
    assert cmds == [] and "refused GUIDED" in says[0].text
    assert m.phase == Phase.IDLE and not m.switched_off


def test_the_time_budget_aborts_and_resumes_and_the_mission_budget_stops_new_looks() -> None:
    m, victims = _machine_with_path()
    _start(m, victims)
    acks = {MAV_CMD_DO_SET_MODE: (0, 100.5)}
    rover = Rover(True, 0.0, 5.5, 0.0)
    m.step(100.7, rover, _ap(100.6, ROVER_GUIDED, acks=acks), [], victims)
    ap = _ap(100.8, ROVER_GUIDED, acks=acks, mission_seq=3, mission_s=100.8)
    m.step(100.9, rover, ap, [], victims)
    late = 100.0 + S.look_budget_s + 1.0
    cmds, says = m.step(late, rover, _ap(late, ROVER_GUIDED, acks=acks), [], victims)
    assert cmds == [GoTo(0.0, 5.5)]
    assert "time budget spent" in says[0].text
    # Back, or not: past the budget and the stuck time, AUTO from wherever it is.
    later = late + S.stuck_s + 0.1
    cmds, _ = m.step(later, Rover(True, 1.0, 3.0, 0.0), _ap(later, ROVER_GUIDED), [], victims)
    assert cmds == [SetCurrent(3), SetMode(ROVER_AUTO)]
    m2, victims2 = _machine_with_path()
    m2.counts.spent_s = S.mission_budget_s - 1.0
    assert _start(m2, victims2) == []


def test_a_look_of_its_own_waits_until_the_looks_so_far_are_within_the_route_share() -> None:
    m, victims = _machine_with_path()
    m.counts.spent_s = 10.0  # one earlier look took 10 s: at 10 %, 100 s of route pay it
    here = Rover(True, 0.0, 5.5, 0.0)
    found = candidates(victims.values(), 10.0, S)
    t = 0.0
    while m.phase == Phase.IDLE:
        t += 0.2
        assert t < 200.0, "no look started"
        m.step(t, here, _ap(t, ROVER_AUTO), found, victims)
    assert 99.0 < m.route_s < 101.0 and t == pytest.approx(m.route_s, abs=0.3)
    # Time in HOLD, disarmed or between distant steps is not route time.
    m2, _ = _machine_with_path()
    m2.step(0.0, here, _ap(0.0, ROVER_AUTO), [], victims)
    m2.step(30.0, here, _ap(30.0, ROVER_AUTO), [], victims)  # a 30-s gap: 1 s at most
    m2.step(30.5, here, _ap(30.5, ROVER_HOLD), [], victims)
    m2.step(31.0, here, _ap(31.0, ROVER_AUTO, armed=False), [], victims)
    assert m2.route_s == pytest.approx(1.0)
    # The operator's own request is not held back by the share (it is theirs to spend).
    m3, victims3 = _machine_with_path()
    m3.counts.spent_s = 10.0
    victims3[1] = _victim(1, TrackState.CONFIRMED, ne=(1.2, 3.0), victim_id=4)
    m3.ask(1, 4, 100.0)
    cmds, _ = m3.step(100.0, here, _ap(100.0, ROVER_AUTO), [], victims3)
    assert cmds == [SetMode(ROVER_GUIDED)]


def test_a_dropped_request_is_said_whatever_holds_the_companions_own_looks_back() -> None:
    # The operator asked about victim 4; it is resolved meanwhile. The rover is in
    # HOLD, so no look of the companion's own (a tentative candidate) starts either:
    # the operator still hears why their look was dropped.
    m, victims = _machine_with_path()
    victims[9] = _victim(9, TrackState.FALSE_ALARM, ne=(1.2, 3.5), victim_id=4)
    m.ask(9, 4, 100.0)
    found = candidates(victims.values(), 10.0, S)
    assert found
    here = Rover(True, 0.0, 5.5, 0.0)
    cmds, says = m.step(100.0, here, _ap(100.0, ROVER_HOLD), found, victims)
    assert (
        cmds == [] and len(says) == 1 and "victim 4 the operator asked for dropped" in says[0].text
    )


def test_an_operator_mode_mid_look_ends_it_at_once_and_looks_stay_off() -> None:
    m, victims = _machine_with_path()
    _start(m, victims)
    acks = {MAV_CMD_DO_SET_MODE: (0, 100.5)}
    rover = Rover(True, 0.0, 5.5, 0.0)
    m.step(100.7, rover, _ap(100.6, ROVER_GUIDED, acks=acks), [], victims)
    ap = _ap(100.8, ROVER_GUIDED, acks=acks, mission_seq=3, mission_s=100.8)
    m.step(100.9, rover, ap, [], victims)
    cmds, says = m.step(101.5, rover, _ap(101.4, ROVER_HOLD, acks=acks), [], victims)
    assert cmds == [] and "operator switched to HOLD" in says[0].text
    assert m.switched_off and m.phase == Phase.IDLE
    m.route_s = 1000.0  # a long route since: the time share is not what holds looks back
    victims[2] = _victim(2, ne=(-1.2, 2.0))
    assert m.step(102.0, rover, _ap(102.0, ROVER_AUTO), [], victims) == ([], [])
    found = candidates(victims.values(), 10.0, S)
    assert m.step(102.0, rover, _ap(102.0, ROVER_AUTO), found, victims) == ([], [])
    m.set_enabled(True)  # the operator sets RC_LOOK_ON again
    assert m.step(103.0, rover, _ap(103.0, ROVER_AUTO), found, victims)[0] == [
        SetMode(ROVER_GUIDED)
    ]


# -- the safety rules, over any sequence of what the autopilot says -------------------------

_OTHER_MODES = [ROVER_MANUAL, ROVER_HOLD, ROVER_RTL, ROVER_SMART_RTL, ROVER_AUTO, ROVER_GUIDED]
_event = st.tuples(
    st.floats(0.05, 3.0),  # time to the next step
    st.sampled_from(["obeys"] * 6 + ["silent", "operator", "disarm", "link down", "refuse"]),
    st.sampled_from(_OTHER_MODES),  # the operator's mode
    st.booleans(),  # the rover has reached the viewpoint
)


@settings(max_examples=400, deadline=None)
@given(st.lists(_event, min_size=1, max_size=60))
def test_the_operator_always_wins(events: list[tuple[float, str, int, bool]]) -> None:
    """An autopilot that mostly obeys, and an operator, a link and a vehicle that may
    do anything between two steps: no command while the autopilot shows a mode other
    than AUTO or GUIDED, or disarmed; GUIDED is asked only of an armed AUTO; after a
    look the operator ended, nothing is sent again (until RC_LOOK_ON is set again)."""
    m, victims = _machine_with_path()
    found = candidates(victims.values(), 10.0, S)
    now, hb_s, mode, armed, connected = 100.0, 100.0, ROVER_AUTO, True, True
    acks: dict[int, tuple[int, float]] = {}
    mission: tuple[int | None, float | None] = (None, None)
    last: list[object] = []
    taken_over = False
    for dt, what, operator_mode, arrived in events:
        now += dt
        connected = what != "link down"
        if what == "operator":
            hb_s, mode = now, operator_mode
        elif what == "disarm":
            hb_s, armed = now, False
        elif what in ("obeys", "refuse"):
            hb_s = now
            for c in last:  # the autopilot answers the last step's commands
                if isinstance(c, SetMode):
                    acks = {MAV_CMD_DO_SET_MODE: (0 if what == "obeys" else 4, now)}
                    mode = c.mode if what == "obeys" else mode
                if isinstance(c, RequestMissionCurrent):
                    mission = (5, now)
        ap = _ap(hb_s, mode, armed=armed, acks=acks, mission_seq=mission[0], mission_s=mission[1])
        view = m.look.view if m.look is not None else None
        ne = view.ne if arrived and view is not None else (0.0, 5.5)
        idle = m.phase == Phase.IDLE
        cmds, says = m.step(now, Rover(connected, ne[0], ne[1], 0.0), ap, found, victims)
        if mode not in (ROVER_AUTO, ROVER_GUIDED) or not armed:
            assert cmds == [], (mode, armed, cmds)
        if idle and cmds:
            assert cmds == [SetMode(ROVER_GUIDED)]
            assert mode == ROVER_AUTO and armed and connected and now - hb_s <= 1.5
        if taken_over:
            assert cmds == []
        if any("operator switched" in s.text or "disarmed" in s.text for s in says):
            taken_over = True
            assert m.switched_off
        last = list(cmds)


# -- the [looks] section --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ("[looks]\nview_min_m = 2.0\nview_max_m = 1.5\n", "[looks] view_min_m = 2.0"),
        ("[looks]\nclearance_m = 1.2\n", "[looks] clearance_m = 1.2: must be below view_min_m"),
        ("[looks]\nlook_s = nan\n", "looks.look_s = nan: must be a finite number"),
        ("[looks]\nenabled = 1\n", "looks.enabled = 1: expected true or false"),
        ("[looks]\nlook_budget_s = 900.0\n", "must not exceed mission_budget_s"),
        ("[looks]\nlooks_on = true\n", "[looks] has unknown key 'looks_on'"),
    ],
)
def test_check_config_names_a_bad_looks_setting_in_one_line(
    tmp_path: Path, toml: str, expected: str
) -> None:
    cfg = tmp_path / "companion.toml"
    cfg.write_text(toml)
    result = subprocess.run(
        [sys.executable, "-m", "companion.commands.cli", "check-config", "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], result.stderr


def test_looks_are_off_by_default_and_the_example_leaves_them_off() -> None:
    assert config_from_dict({}).looks.enabled is False
    example = Path(__file__).resolve().parents[1] / "systemd" / "config.example.toml"
    assert load_config(example).looks == LooksConfig()
