"""The simulated autopilot drives GUIDED targets and resumes its mission as ArduPilot
Rover does: checked with pymavlink's mavutil as an independent client over real UDP
on 127.0.0.1, and the motion model's default behaviour is unchanged."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from scenarios.autopilot_drive import MODE_AUTO, MODE_GUIDED, MODE_HOLD, Drive
from scenarios.motion import Trajectory
from scenarios.rover import SimRover
from scenarios.world import preset

WAIT_S = 6.0
GUIDED, AUTO, MANUAL, RTL = 15, 10, 0, 11


def _recv(conn: Any, kind: str, timeout_s: float = WAIT_S, **cond: Any) -> Any:
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        msg = conn.recv_match(type=kind, blocking=True, timeout=left)
        if msg is not None and all(getattr(msg, k) == v for k, v in cond.items()):
            return msg
    raise AssertionError(f"no {kind} {cond} within {timeout_s} s")


@pytest.fixture
def rig() -> Iterator[tuple[SimRover, Any]]:
    rover = SimRover(preset("light"), ["udpin:127.0.0.1:0"], time_scale=4.0).start()
    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{rover.local_address(0)[1]}",
        source_system=1,
        source_component=191,
        dialect="common",
    )
    conn.mav.heartbeat_send(18, 8, 0, 0, 4)
    _recv(conn, "HEARTBEAT")
    yield rover, conn
    conn.close()
    rover.close()


def _set_mode(conn: Any, mode: int) -> Any:
    conn.mav.command_long_send(1, 1, 176, 0, 1, mode, 0, 0, 0, 0, 0)
    return _recv(conn, "COMMAND_ACK", command=176)


def _goto(conn: Any, north_m: float, east_m: float) -> None:
    mask = 0b0000_1111_1111_1000  # position only (velocity, acceleration, yaw ignored)
    conn.mav.set_position_target_local_ned_send(
        0, 1, 1, 1, mask, north_m, east_m, 0, 0, 0, 0, 0, 0, 0, 0, 0
    )


def _wait(pred: Any, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return
        time.sleep(0.05)
    raise AssertionError("condition not reached")


def test_guided_drives_to_the_target_stops_and_auto_resumes_at_the_item(rig: Any) -> None:
    rover, conn = rig
    time.sleep(1.0)
    conn.mav.command_long_send(1, 1, 512, 0, 42, 0, 0, 0, 0, 0, 0)  # REQUEST_MESSAGE
    seq_before = _recv(conn, "MISSION_CURRENT").seq
    assert seq_before >= 1
    assert _set_mode(conn, GUIDED).result == 0
    _recv(conn, "HEARTBEAT", custom_mode=GUIDED)
    p = rover.true_pose()
    target = (p.north_m - 1.0, p.east_m + 1.0)  # behind and to the side: it must turn
    _goto(conn, *target)
    _wait(lambda: math.dist((rover.true_pose().north_m, rover.true_pose().east_m), target) < 0.2)
    time.sleep(1.0)
    still = rover.true_pose()
    assert math.dist((still.north_m, still.east_m), target) < 0.2  # it stays there
    assert math.hypot(still.vn_m_s, still.ve_m_s) < 0.05
    # Where to resume, then AUTO: the mission goes on from that item, not from the start.
    conn.mav.command_long_send(1, 1, 224, 0, seq_before, 0, 0, 0, 0, 0, 0)
    assert _recv(conn, "COMMAND_ACK", command=224).result == 0
    assert _set_mode(conn, AUTO).result == 0
    _recv(conn, "HEARTBEAT", custom_mode=AUTO)
    assert rover.mission_seq() >= seq_before
    conn.mav.mission_set_current_send(1, 1, 2)  # the old message: answered by MISSION_CURRENT
    assert _recv(conn, "MISSION_CURRENT", seq=2).mission_state == 3  # ACTIVE


def test_set_mode_message_is_acked_and_unknown_modes_fail(rig: Any) -> None:
    rover, conn = rig
    conn.mav.set_mode_send(1, 1, MANUAL)
    assert _recv(conn, "COMMAND_ACK", command=11).result == 0
    _recv(conn, "HEARTBEAT", custom_mode=MANUAL)
    assert _set_mode(conn, RTL).result == mavutil.mavlink.MAV_RESULT_FAILED
    assert rover.mode() == MANUAL
    conn.mav.command_long_send(1, 1, 224, 0, 999, 0, 0, 0, 0, 0, 0)
    assert _recv(conn, "COMMAND_ACK", command=224).result == mavutil.mavlink.MAV_RESULT_FAILED


def test_a_position_target_outside_guided_is_ignored_and_an_obstacle_stops_progress(
    rig: Any,
) -> None:
    rover, conn = rig
    time.sleep(0.5)
    _goto(conn, 0.0, 0.0)  # in AUTO: ignored
    assert _set_mode(conn, GUIDED).result == 0
    p = rover.true_pose()
    target = (p.north_m + 3.0, p.east_m)
    rover.block(p.north_m + 1.5, p.east_m, 0.6)
    time.sleep(0.2)
    _goto(conn, *target)
    time.sleep(3.0)  # 12 s of simulation: plenty for 3 m at 0.4 m/s
    q = rover.true_pose()
    assert math.dist((q.north_m, q.east_m), target) > 1.5  # stuck at the obstacle
    assert math.dist((q.north_m, q.east_m), (p.north_m + 1.5, p.east_m)) >= 0.55


def test_drive_without_commands_is_the_route_exactly_and_heading_targets_turn_in_place() -> None:
    world = preset("light")
    base, same = Trajectory.for_world(world), Trajectory.for_world(world)
    drive = Drive(base)
    for t in (0.0, 3.3, 40.0, 90.5):
        assert drive.pose_at(t) == same.pose_at(t)
    assert drive.mission_seq(90.5) == same.target_at(90.5) + 1
    drive.set_mode(MODE_GUIDED, 10.0)
    assert drive.guided_target(10.0, None, 1.0)
    p = drive.pose_at(30.0)
    before = drive.pose_at(10.0)
    assert math.dist((p.north_m, p.east_m), (before.north_m, before.east_m)) < 0.3
    assert abs(math.remainder(p.yaw_rad - 1.0, 2 * math.pi)) < 0.05
    drive.set_mode(MODE_HOLD, 30.0)
    item = drive.route_index(30.0)
    drive.set_mode(MODE_AUTO, 30.0)
    assert drive.route_index(30.0) == item
    assert drive.pose_at(12.0) == drive.pose_at(12.0)  # earlier times keep their poses
