"""rescue-hq and the closer looks (issue 42): the operator's `rescue-hq look` and
`rescue-hq looks` reach the robot over real UDP and the robot's answers are
recorded; RESCUE_STATUS carries the robot's look counts (extension fields), which
the HQ checks where they enter, keeps, and shows, and still takes a status from a
robot older than them."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hqproc import ACK_TIMEOUT_S, REJECTED, REPO, HqProcess, ack_for, answer_action, hq_starter

from fusion.types import TrackState
from hq import cli, wire
from hq.records import BadRecord, OperatorAction, RobotStatus
from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.view import hq_victims
from mavlink_io import dialect
from mavlink_io.codec import Codec

M = dialect.load()
ROBOT = 5


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


def _hq_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hq.cli", *args],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip


def _status(looks: tuple[int, int, int, int, int] | None, flags: int = 0b111) -> object:
    base = (10, 9.5, 0.0, 40.0, flags, 2, 1, 0)
    if looks is None:  # what a robot older than the look counts sends
        return M.MAVLink_rescue_status_message(*base)
    return M.MAVLink_rescue_status_message(*base, *looks)


def test_look_and_looks_reach_the_robot_and_its_answers_and_counts_are_kept(
    start_hq, capsys: pytest.CaptureFixture[str]
) -> None:
    hq = start_hq()
    db = str(hq.db)
    with SimRobot(ROBOT, hq.address) as robot:
        report = robot.report_msg(robot.victim(3, 1.0, 2.0))
        robot.send(report)
        ack_for(robot, report.report_seq)
        done = _hq_cli("look", "--db", db, "--robot", str(ROBOT), "--victim", "3")
        assert done.returncode == 0, done.stderr
        assert f"LOOK_CLOSER robot {ROBOT} victim 3 recorded" in done.stdout
        look = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, action=5).msg
        assert look.victim_id == 3
        robot.ack_action(look)
        hq.wait_line(f"action {look.action_seq} acknowledged by robot {ROBOT}", ACK_TIMEOUT_S)
        done = _hq_cli("looks", "--db", db, "--robot", str(ROBOT), "off")
        assert done.returncode == 0, done.stderr
        assert f"LOOKS_OFF robot {ROBOT} recorded" in done.stdout
        off = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, action=6).msg
        assert off.victim_id == 0  # the whole robot
        robot.ack_action(off)
        hq.wait_line(f"action {off.action_seq} acknowledged by robot {ROBOT}", ACK_TIMEOUT_S)
        # Looks are off now: the robot answers a look closer REJECTED, and the HQ says so.
        assert _hq_cli("look", "--db", db, "--id", "1").returncode == 0
        refused = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, action=5).msg
        assert refused.action_seq > look.action_seq
        answer_action(robot, refused, REJECTED)
        line = hq.wait_line(f"action {refused.action_seq} ", ACK_TIMEOUT_S)
        assert f"REJECTED by robot {ROBOT}" in line
        assert _hq_cli("looks", "--db", db, "--robot", str(ROBOT), "on").returncode == 0
        on = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, action=7).msg
        assert on.victim_id == 0
        robot.ack_action(on)
        hq.wait_line(f"action {on.action_seq} acknowledged by robot {ROBOT}", ACK_TIMEOUT_S)
        # Its status with the look counts, then (another robot) an old-format one.
        robot.send(_status((3, 1, 1, 0, 1), flags=0b111 | M.RESCUE_STATUS_FLAGS_LOOKS_ON))
        with SimRobot(ROBOT + 1, hq.address) as old:
            packed = _status(None).pack(M.MAVLink(None, ROBOT + 1, 191))  # type: ignore[attr-defined]
            assert packed[1] <= 24  # no extension bytes on the wire
            old.send_raw(packed)
            deadline = time.monotonic() + ACK_TIMEOUT_S
            while True:
                with Registry(hq.db) as reg:
                    statuses = {r.sysid: r.status for r in reg.robots()}
                if all(statuses.get(s) is not None for s in (ROBOT, ROBOT + 1)):
                    break
                assert time.monotonic() < deadline, statuses
                time.sleep(0.05)
    assert hq.stop() == 0
    new, older = statuses[ROBOT], statuses[ROBOT + 1]
    assert new is not None and older is not None
    assert (new.looks_made, new.looks_confirmed, new.looks_rejected) == (3, 1, 1)
    assert (new.looks_urgency_changed, new.looks_aborted) == (0, 1)
    assert new.look_words() == "looks on: 3 made, 1 confirmed, 1 rejected, 1 aborted"
    assert older.looks_made == 0 and not older.looks_on and older.victims_confirmed == 2
    with Registry(hq.db) as reg:
        actions = [(a.action, a.victim_id, a.ack_result) for a in reg.actions()]
        (victim,) = hq_victims(reg)
    assert actions == [
        (OperatorAction.LOOK_CLOSER, 3, 0),
        (OperatorAction.LOOKS_OFF, 0, 0),
        (OperatorAction.LOOK_CLOSER, 3, REJECTED),
        (OperatorAction.LOOKS_ON, 0, 0),
    ]
    assert victim.state == TrackState.CONFIRMED  # a look decides nothing about the person
    capsys.readouterr()
    assert cli.main(["list", "--db", db]) == 0
    assert "looks on: 3 made, 1 confirmed, 1 rejected, 1 aborted" in capsys.readouterr().out
    # The commands refuse what they cannot record, in one line.
    for args, why in (
        (("looks", "--robot", "9", "off"), "robot 9 has never been heard"),
        (("look", "--robot", str(ROBOT), "--victim", "4"), f"robot {ROBOT} has reported no"),
        (("look", "--id", "7"), "no HQ victim 7"),
        (("look", "--robot", str(ROBOT)), "give either --robot N --victim ID, or --id HQ_ID"),
    ):
        assert cli.main([args[0], "--db", db, *args[1:]]) == 2
        err = capsys.readouterr().err
        assert why in err and len(err.strip().splitlines()) == 1, err


def test_status_look_counts_round_trip_and_are_checked_where_they_enter() -> None:
    sender, receiver = Codec(ROBOT, 191, None, M), Codec(245, 190, None, M)
    flags = 0b111 | M.RESCUE_STATUS_FLAGS_LOOKS_ON
    (msg,) = receiver.feed(sender.encode(_status((7, 2, 1, 3, 1), flags)))
    status = wire.status_from_msg(msg)
    assert status.looks_on
    counts = (status.looks_made, status.looks_confirmed, status.looks_rejected)
    assert (*counts, status.looks_urgency_changed, status.looks_aborted) == (7, 2, 1, 3, 1)
    assert RobotStatus.from_json(status.to_json()) == status
    # A robot older than the counts: they read 0, the rest is as sent.
    (old,) = receiver.feed(sender.encode(_status(None)))
    older = wire.status_from_msg(old)
    assert older.looks_made == 0 and older.fps == 9.5 and older.victims_confirmed == 2
    assert older.look_words() == "looks off"
    # A status stored by an HQ older than the counts reads them as 0.
    stored = json.loads(older.to_json())
    for key in [k for k in stored if k.startswith("looks_")]:
        del stored[key]
    assert RobotStatus.from_json(json.dumps(stored)) == older
    # More looks settled or aborted than made: a damaged or forged status, refused.
    (bad,) = receiver.feed(sender.encode(_status((1, 1, 1, 0, 0))))
    with pytest.raises(wire.BadMessage, match="2 settled or aborted of 1 made"):
        wire.status_from_msg(bad)
    stored["looks_made"] = 1.5
    with pytest.raises(BadRecord, match="looks_made"):
        RobotStatus.from_json(json.dumps(stored))
