"""Closer looks end to end: the companion's look controller (companion/looks/run.py)
on a real VehicleLink over UDP on 127.0.0.1 to the simulated ArduPilot Rover, with a
real VictimTracker and Announcer. The camera is the one part stood in for: while the
rover is within 1.7 m of the candidate and faces it (within 35 degrees), the test
adds the detection a close camera would make, as the processing thread would."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest

from companion.config import LooksConfig
from companion.looks.machine import Phase
from companion.looks.run import Looks
from companion.reporting.announcements import Announcer
from fusion.params import TrackerParams
from fusion.tracker import VictimTracker
from fusion.types import Observation, TrackState
from mavlink_io.linkspec import parse_link
from mavlink_io.reconnect import open_link
from mavlink_io.vehicle import VehicleLink, VehicleSettings
from scenarios.rover import SimRover
from scenarios.world import preset

TIME_SCALE = 4.0  # the rover drives four times faster than real time
GUIDED, AUTO, MANUAL = 15, 10, 0
SETTINGS = LooksConfig(
    enabled=True,
    look_s=1.0,
    tentative_min_s=0.3,
    stuck_s=2.0,
    look_budget_s=30.0,
    ack_timeout_s=1.5,
)


@dataclass
class Rig:
    rover: SimRover
    vehicle: VehicleLink
    tracker: VictimTracker
    announcer: Announcer
    looks: Looks
    switched_off: list[bool] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)
    closest_m: float = math.inf

    def tick(self, see: tuple[float, float] | None) -> None:
        """One processing-thread pass: the close camera's detection, then the look."""
        now = time.time()
        obs = []
        p = self.rover.true_pose()
        if see is not None:
            d = math.dist((p.north_m, p.east_m), see)
            self.closest_m = min(self.closest_m, d)
            bearing = math.atan2(see[1] - p.east_m, see[0] - p.north_m)
            if d < 1.7 and abs(math.remainder(bearing - p.yaw_rad, math.tau)) < math.radians(35):
                obs.append(_obs(now, see))
        self.tracker.update(obs, now, lambda _n, _e: False)
        self.looks.tick(lambda: self.tracker.victims(include_tentative=True))
        self.lines += [a.text for a in self.announcer.take(math.inf)]

    def run(self, seconds: float, see: tuple[float, float] | None = None) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.tick(see)
            time.sleep(0.05)

    def run_until(self, pred: object, timeout_s: float, see: tuple[float, float] | None) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.tick(see)
            if pred():  # type: ignore[operator]
                return
            time.sleep(0.05)
        raise AssertionError(f"not reached within {timeout_s} s; lines {self.lines}")


def _obs(t_unix_s: float, ne: tuple[float, float]) -> Observation:
    return Observation(t_unix_s, ne[0], ne[1], ((0.02, 0.0), (0.0, 0.02)), 80.0, 1.0, 1.2)


@pytest.fixture
def rig() -> Iterator[Rig]:
    rover = SimRover(preset("light"), ["udpin:127.0.0.1:0"], time_scale=TIME_SCALE).start()
    port = rover.local_address(0)[1]
    vehicle = VehicleLink(
        open_link(parse_link(f"udpout:127.0.0.1:{port}")),
        VehicleSettings(heartbeat_timeout_s=1.0),
    )
    announcer = Announcer(
        enabled=True, announce_severity=5, robot_sysid=lambda: 1, wake=threading.Event()
    )
    switched: list[bool] = []
    looks = Looks(SETTINGS, vehicle, announcer, lambda: switched.append(True))
    r = Rig(rover, vehicle, VictimTracker(TrackerParams()), announcer, looks, switched)
    try:
        vehicle.wait_connected(10.0)
        yield r
    finally:
        vehicle.close()
        rover.close()


def _candidate_beside_the_path(rig: Rig) -> tuple[float, float]:
    """Drive a while (the companion records the path), then a possible victim 1.2 m to
    the right of where the rover was 1 s (4 m) ago: one far, weak detection of it."""
    rig.run(1.5)
    p = rig.rover.true_pose()
    beside = (p.north_m - 1.2 * math.sin(p.yaw_rad), p.east_m + 1.2 * math.cos(p.yaw_rad))
    # Right of the heading: (cos(y + 90deg), sin(y + 90deg)) = (-sin y, cos y).
    rig.run(1.0)
    rig.tracker.update([_obs(time.time(), beside)], time.time(), lambda _n, _e: False)
    return beside


def test_a_look_settles_a_candidate_and_the_mission_resumes_at_its_item(rig: Rig) -> None:
    target = _candidate_beside_the_path(rig)
    rig.run_until(lambda: rig.looks.machine.phase == Phase.DRIVING, 10.0, None)
    seq = rig.looks.machine.look.seq  # type: ignore[union-attr]
    assert seq is not None and seq >= 1
    assert rig.rover.mode() == GUIDED
    p = rig.rover.true_pose()
    assert math.dist((p.north_m, p.east_m), target) > 1.7  # out of the close camera's reach
    rig.run_until(lambda: rig.looks.machine.look is None, 40.0, target)
    assert rig.closest_m < 1.7  # the detour brought it there (it may settle on the way)
    victims = rig.tracker.victims()
    assert [v.state for v in victims] == [TrackState.CONFIRMED]
    assert rig.looks.machine.counts.settled == {"confirmed": 1}
    assert rig.looks.line == "1 look, 1 confirmed"
    assert any(
        line.startswith("R1 looking closer at a possible victim") and line.endswith("of here")
        for line in rig.lines
    ), rig.lines
    assert any("possible victim is confirmed" in line for line in rig.lines), rig.lines
    rig.run(1.0)
    assert rig.rover.mode() == AUTO
    assert rig.rover.mission_seq() >= seq
    # The same candidate is never looked at twice, and a confirmed one is no candidate.
    rig.run(2.0)
    assert rig.looks.machine.counts.started == 1


def test_the_operator_switching_to_manual_mid_look_ends_it_and_looks_stay_off(
    rig: Rig,
) -> None:
    _candidate_beside_the_path(rig)
    rig.run_until(lambda: rig.looks.machine.phase == Phase.DRIVING, 10.0, None)
    rig.rover.operator_sets_mode(MANUAL)
    rig.run_until(lambda: rig.looks.machine.look is None, 3.0, None)
    assert rig.switched_off == [True]  # RC_LOOK_ON goes to 0
    assert rig.looks.machine.switched_off
    assert any("operator switched to MANUAL" in line for line in rig.lines), rig.lines
    # A new candidate: no look, the rover stays as the operator left it.
    p = rig.rover.true_pose()
    rig.tracker.update(
        [_obs(time.time(), (p.north_m, p.east_m + 1.0))], time.time(), lambda *_: False
    )
    rig.run(2.0)
    assert rig.rover.mode() == MANUAL
    assert rig.looks.machine.counts.started == 1
    assert rig.looks.machine.phase == Phase.IDLE
    # The operator sets RC_LOOK_ON again and gives the rover back to its mission.
    rig.looks.set_enabled(True)
    rig.rover.operator_sets_mode(AUTO)
    rig.run_until(lambda: rig.looks.machine.counts.started == 2, 10.0, None)
    assert "R1 closer looks on" in rig.lines


def test_link_loss_mid_look_aborts_and_the_mission_resumes_when_it_is_back(rig: Rig) -> None:
    _candidate_beside_the_path(rig)
    rig.run_until(lambda: rig.looks.machine.phase == Phase.DRIVING, 10.0, None)
    rig.rover.drop_link(3.0 * TIME_SCALE)  # 3 s of silence, each way
    rig.run_until(lambda: rig.looks.machine.phase == Phase.LINK_LOST, 3.0, None)
    assert any("aborted: vehicle link lost" in line for line in rig.lines), rig.lines
    rig.run_until(lambda: rig.looks.machine.look is None, 10.0, None)
    rig.run(1.0)
    assert rig.rover.mode() == AUTO
    assert rig.looks.machine.counts.aborted == {"vehicle link lost": 1}
    assert not rig.looks.machine.switched_off  # a link loss is no operator decision


def test_a_viewpoint_the_rover_cannot_reach_is_abandoned_and_the_mission_resumed(
    rig: Rig,
) -> None:
    target = _candidate_beside_the_path(rig)
    rig.rover.block(target[0], target[1], 2.3)  # every viewpoint is well inside
    rig.run_until(lambda: rig.looks.machine.phase == Phase.DRIVING, 10.0, None)
    rig.run_until(lambda: rig.looks.machine.look is None, 20.0, None)
    assert rig.looks.machine.counts.aborted == {"stuck on the way": 1}, rig.lines
    assert any("aborted: stuck on the way; resuming the mission" in x for x in rig.lines)
    rig.run(1.0)
    assert rig.rover.mode() == AUTO


def test_with_looks_off_nothing_happens(rig: Rig) -> None:
    rig.looks.set_enabled(False)
    _candidate_beside_the_path(rig)
    rig.run(3.0)
    assert rig.rover.mode() == AUTO
    assert rig.looks.machine.counts.started == 0
    assert [v.state for v in rig.tracker.victims(include_tentative=True)] == [TrackState.TENTATIVE]
    assert rig.lines == ["R1 closer looks off"]
