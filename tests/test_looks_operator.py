"""The HQ operator's closer-look actions on the robot (issue 42): "look closer at victim
N", "no more looks" and "looks on", as RESCUE_OPERATOR_ACTIONs handed to the
companion's ``Ground`` on the processing thread.

Real parts: the look controller on a real VehicleLink over UDP on 127.0.0.1 to the
simulated ArduPilot Rover (tests/test_looks_e2e.py's rig), a real tracker and
announcer, and RC_LOOK_ON served by the companion's real parameter table and
parameter protocol, applied to the looks exactly as the service applies it. The
actions arrive as decoded MAVLink messages from the HQ's system ID; what the robot
answers is the RESCUE_ACK it sends. The close camera is stood in for as in the rig.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import random
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from test_looks_e2e import AUTO, GUIDED, SETTINGS, TIME_SCALE, Rig, _obs

from companion.config import Config, PicturesConfig
from companion.looks.choose import Kind
from companion.looks.machine import Phase
from companion.looks.run import Looks
from companion.reporting.announcements import Announcements, Announcer
from companion.reporting.pictures import resume
from companion.reporting.policy import ReportPolicy
from companion.service.ground import Ground
from companion.service.params import Settings
from companion.storage.ledger import Ledger
from companion.storage.recovery import load_state
from fusion.params import TrackerParams
from fusion.types import TrackState
from mavlink_io import dialect
from mavlink_io.linkspec import parse_link
from mavlink_io.params import ParamServer
from mavlink_io.reconnect import open_link
from mavlink_io.reliable import Outbox
from mavlink_io.vehicle import VehicleLink, VehicleSettings
from scenarios.rover import SimRover
from scenarios.world import preset

M = dialect.load()
HQ_SYSID = 250
ACCEPTED, DUPLICATE, REJECTED = 0, 1, 2
LOOK_CLOSER = M.RESCUE_OPERATOR_ACTION_LOOK_CLOSER
LOOKS_OFF = M.RESCUE_OPERATOR_ACTION_LOOKS_OFF
LOOKS_ON = M.RESCUE_OPERATOR_ACTION_LOOKS_ON
COMPONENT = 191


class _Radio:
    """The way to the HQ: what the robot answers is kept."""

    def __init__(self) -> None:
        self.acks: list[Any] = []

    def send_dialect(self, msg: Any) -> None:
        if msg.get_type() == "RESCUE_ACK":
            self.acks.append(msg)


@dataclasses.dataclass
class Robot:
    rig: Rig
    ground: Ground
    server: ParamServer
    actions: queue.Queue[Any]
    radio: _Radio
    seq: int = 1000

    def act(self, action: int, victim_id: int = 0, seq: int | None = None) -> int:
        """One RESCUE_OPERATOR_ACTION from the HQ, handled as the processing thread
        does; the result of the one RESCUE_ACK it is answered with."""
        if seq is None:
            self.seq += 1
            seq = self.seq
        msg = M.MAVLink_rescue_operator_action_message(1, COMPONENT, victim_id, seq, action)
        hq = M.MAVLink(None, HQ_SYSID, 190)
        self.actions.put(hq.parse_buffer(msg.pack(hq))[0])  # as decoded from the radio
        self.ground.handle_actions()
        (ack,) = self.radio.acks
        self.radio.acks.clear()
        assert (ack.seq, ack.acked_msgid, ack.target_system) == (seq, 43102, HQ_SYSID)
        return int(ack.result)

    def rc_look_on(self) -> float:
        """RC_LOOK_ON as QGC reads it (PARAM_REQUEST_READ by name)."""
        ask = M.MAVLink_param_request_read_message(1, COMPONENT, b"RC_LOOK_ON", -1)
        handled = self.server.handle(ask)
        assert handled is not None
        (value,) = handled.replies
        return float(value.param_value)


def _robot(looks_on: bool, state_dir: Path) -> Iterator[Robot]:
    rover = SimRover(preset("light"), ["udpin:127.0.0.1:0"], time_scale=TIME_SCALE).start()
    port = rover.local_address(0)[1]
    vehicle = VehicleLink(
        open_link(parse_link(f"udpout:127.0.0.1:{port}")),
        VehicleSettings(heartbeat_timeout_s=1.0),
    )
    announcer = Announcer(
        enabled=True, announce_severity=5, robot_sysid=lambda: 1, wake=threading.Event()
    )
    # Every line is kept: the rig takes them all at once, and the rate limit of the
    # STATUSTEXT lines (tested in test_companion_announcements) would hold back some.
    announcer.waiting = Announcements(burst=1000)
    config = Config(looks=dataclasses.replace(SETTINGS, enabled=looks_on))
    holder: list[Looks] = []
    # The service's wiring (companion/service/run.py): a changed setting is applied to
    # the looks, and a take-over sets RC_LOOK_ON to 0.
    settings = Settings(
        config, None, lambda c: holder[0].set_enabled(c.looks.enabled), lambda _s: None
    )
    switched: list[bool] = []

    def taken_over() -> None:
        switched.append(True)
        settings.set("RC_LOOK_ON", 0.0)

    looks = Looks(config.looks, vehicle, announcer, taken_over)
    holder.append(looks)
    server = ParamServer(settings, COMPONENT, M)
    actions: queue.Queue[Any] = queue.Queue()
    radio = _Radio()
    # The robot's saved state, for the decisions about a victim (the fuzz sends them).
    policy = ReportPolicy(2.0)
    state = load_state(state_dir, TrackerParams(), policy)
    tracker = state.tracker
    chooser, sender = resume(PicturesConfig(), state.store, lambda _c: None, signed=False)
    wake = threading.Event()
    ledger = Ledger(
        store=state.store,
        tracker=tracker,
        policy=policy,
        outbox=Outbox(lambda _msg: None, store=state.store),
        chooser=chooser,
        picture_sender=sender,
        announcer=announcer,
        vehicle=vehicle,
        robot_sysid=lambda: 1,
        report_seq=state.report_seq,
        floor_down_m=0.0,
        wake_reporter=wake,
        m=M,
    )
    ground = Ground(
        actions=actions,
        requests=queue.Queue(),
        tracker=tracker,
        policy=policy,
        ledger=ledger,
        param_server=server,
        video=None,  # type: ignore[arg-type]
        vehicle=vehicle,
        links=radio,  # type: ignore[arg-type]
        announcer=announcer,
        m=M,
        looks=looks,
    )
    rig = Rig(rover, vehicle, tracker, announcer, looks, switched)
    try:
        vehicle.wait_connected(10.0)
        yield Robot(rig, ground, server, actions, radio)
    finally:
        vehicle.close()
        rover.close()
        state.store.close()


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[Robot]:
    yield from _robot(True, tmp_path)


@pytest.fixture
def robot_looks_off(tmp_path: Path) -> Iterator[Robot]:
    yield from _robot(False, tmp_path)


def _both_sides_of_the_path(rig: Rig) -> tuple[float, float, float, float]:
    """Drive a while (the path is recorded), then two points 1.2 m left and right of
    where the rover was 1 s (4 m) ago."""
    rig.run(1.5)
    p = rig.rover.true_pose()
    s, c = math.sin(p.yaw_rad), math.cos(p.yaw_rad)
    rig.run(1.0)
    return p.north_m + 1.2 * s, p.east_m - 1.2 * c, p.north_m - 1.2 * s, p.east_m + 1.2 * c


def _confirmed(rig: Rig, ne: tuple[float, float]) -> int:
    """A victim the tracker confirms (clearly seen, nothing doubtful: no candidate of
    the companion's own); its victim ID."""
    for k in range(4):
        t = time.time() + 0.05 * k
        rig.tracker.update([_obs(t, ne)], t, lambda _n, _e: False)
    (victim,) = rig.tracker.victims()
    assert victim.state == TrackState.CONFIRMED
    return victim.victim_id


def test_look_closer_goes_first_no_more_looks_aborts_it_and_looks_on_allows_them_again(
    robot: Robot,
) -> None:
    rig = robot.rig
    left_n, left_e, right_n, right_e = _both_sides_of_the_path(rig)
    asked = _confirmed(rig, (left_n, left_e))
    # A possible victim the companion would look at itself, on the other side.
    rig.tracker.update([_obs(time.time(), (right_n, right_e))], time.time(), lambda *_: False)
    assert robot.act(LOOK_CLOSER, asked) == ACCEPTED
    assert robot.act(LOOK_CLOSER, asked, seq=robot.seq) == DUPLICATE  # resent: not again
    rig.run_until(lambda: rig.looks.machine.phase == Phase.DRIVING, 10.0, None)
    look = rig.looks.machine.look
    assert look is not None and look.candidate.victim_id == asked
    assert look.candidate.kind == Kind.ASKED
    assert f"R1 closer look at victim {asked} next (the operator asked)" in rig.lines
    assert any(
        line.startswith(f"R1 looking closer at victim {asked} (the operator asked)")
        for line in rig.lines
    ), rig.lines
    assert rig.rover.mode() == GUIDED
    # "No more looks" mid-look: what RC_LOOK_ON = 0 does.
    assert robot.act(LOOKS_OFF) == ACCEPTED
    assert robot.rc_look_on() == 0.0
    rig.run_until(lambda: rig.looks.machine.look is None, 15.0, None)
    assert rig.looks.machine.counts.aborted == {"looks switched off": 1}
    assert "R1 closer look aborted: looks switched off; resuming the mission" in rig.lines
    rig.run(0.5)
    assert rig.rover.mode() == AUTO
    assert rig.looks.tally.made == 1 and rig.looks.tally.aborted == 1
    assert not rig.looks.tally.on
    assert rig.switched_off == []  # the operator's own switch, not a take-over
    # The possible victim waits; nothing starts while looks are off.
    rig.run(1.0)
    assert rig.looks.machine.counts.started == 1
    # "Looks on": the companion's own candidate gets its look.
    assert robot.act(LOOKS_ON) == ACCEPTED
    assert robot.rc_look_on() == 1.0
    rig.run_until(lambda: rig.looks.machine.counts.started == 2, 10.0, None)
    assert "R1 closer looks on" in rig.lines
    look = rig.looks.machine.look
    assert look is not None and look.candidate.kind == Kind.TENTATIVE
    assert math.dist(look.candidate.ne, (right_n, right_e)) < 0.3
    assert rig.looks.tally.on


def test_look_closer_with_looks_off_only_says_so(robot_looks_off: Robot) -> None:
    robot = robot_looks_off
    rig = robot.rig
    left_n, left_e, _, _ = _both_sides_of_the_path(rig)
    victim = _confirmed(rig, (left_n, left_e))
    assert robot.act(LOOK_CLOSER, victim) == REJECTED
    rig.run(1.0)
    assert (
        f"R1 closer looks are off: no look at victim {victim}; the operator must switch "
        "them on (RC_LOOK_ON = 1, or looks on at the HQ)"
    ) in rig.lines
    assert rig.looks.machine.request is None
    assert rig.looks.machine.counts.started == 0
    assert rig.rover.mode() == AUTO
    assert robot.rc_look_on() == 0.0  # nothing else changed
    # "Looks on" also ends a take-over's switch-off, as RC_LOOK_ON = 1 does.
    rig.looks.machine.operator_took_over()
    assert robot.act(LOOKS_ON) == ACCEPTED
    assert rig.looks.machine.allowed and robot.rc_look_on() == 1.0
    # A victim the operator has resolved, or one the robot never had: no look.
    rig.tracker.mark(victim, TrackState.RESCUED, time.time())
    assert robot.act(LOOK_CLOSER, victim) == REJECTED
    rig.run(0.1)
    assert f"R1 no closer look at victim {victim}: it is RESCUED" in rig.lines
    assert robot.act(LOOK_CLOSER, 999) == REJECTED
    assert robot.act(LOOKS_OFF, victim_id=victim) == REJECTED  # looks off is for victim 0
    assert robot.rc_look_on() == 1.0
    assert rig.looks.machine.request is None


def test_any_action_value_gets_one_answer_and_looks_end_as_the_last_switch_said(
    robot_looks_off: Robot,
) -> None:
    """Seeded fuzz of the action values at the robot's entry point: every action type
    0..255 and victim IDs at their limits. Each gets exactly one RESCUE_ACK with a
    result the dialect names; RC_LOOK_ON ends as the last accepted looks off/on said,
    and the rover is never taken while looks are off."""
    robot = robot_looks_off
    rig = robot.rig
    rng = random.Random(42)
    last: float = 0.0
    for _ in range(300):
        action = rng.choice((LOOK_CLOSER, LOOKS_OFF, LOOKS_ON, rng.randint(0, 255)))
        victim = rng.choice((0, 0, 1, 2**32 - 1, rng.randint(0, 2**32 - 1)))
        if action == LOOKS_ON and rng.random() < 0.8:
            continue  # mostly off: a look closer then only says so
        result = robot.act(action, victim)
        assert result in (ACCEPTED, REJECTED), (action, victim, result)
        if result == ACCEPTED and action in (LOOKS_OFF, LOOKS_ON):
            last = 1.0 if action == LOOKS_ON else 0.0
        assert robot.rc_look_on() == last
        assert rig.looks.machine.allowed == (last == 1.0)
    rig.looks.set_enabled(False)
    rig.run(0.3)
    assert rig.rover.mode() == AUTO
