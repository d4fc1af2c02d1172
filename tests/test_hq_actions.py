"""Operator actions: numbers never reused, and the robot's answer reported as it is.

A robot drops an action_seq it has seen from this HQ (DUPLICATE), so an HQ that
starts again on a new registry (the old one lost, or moved aside as corrupt) must
not number its actions from 1 again. And a robot that answers REJECTED has not
applied the decision: the HQ must say so, not "acknowledged".
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hqproc import (
    ACK_TIMEOUT_S,
    DUPLICATE,
    REJECTED,
    REPO,
    HqProcess,
    ack_for,
    answer_action,
    hq_starter,
)

from fusion.types import TrackState
from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.view import hq_victims


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


def _mark(db: Path, robot: int, victim: int) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "hq.cli", "mark", "--db", str(db),
         "--robot", str(robot), "--victim", str(victim), "--rescued"],
        cwd=REPO, capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr


def test_action_numbers_are_not_reused_on_a_new_registry(start_hq, tmp_path: Path) -> None:
    seen: list[int] = []
    for n, db in enumerate((tmp_path / "first.sqlite", tmp_path / "second.sqlite")):
        hq = start_hq(db=db)
        with SimRobot(5, hq.address) as robot:
            report = robot.report_msg(robot.victim(3, 1.0, 2.0), seq=10 + n)
            robot.send(report)
            ack_for(robot, report.report_seq)
            _mark(db, 5, 3)
            action = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, victim_id=3).msg
            seen.append(action.action_seq)
            robot.ack_action(action)
            hq.wait_line(f"action {action.action_seq} acknowledged by robot 5", ACK_TIMEOUT_S)
        assert hq.stop() == 0
    assert seen[1] > seen[0], seen  # the robot would drop a reused number as a duplicate


def test_a_rejected_action_is_reported_rejected(start_hq) -> None:
    hq = start_hq()
    with SimRobot(6, hq.address) as robot:
        for victim in (1, 2):
            report = robot.report_msg(robot.victim(victim, float(victim), 0.0))
            robot.send(report)
            ack_for(robot, report.report_seq)
        _mark(hq.db, 6, 1)
        first = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, victim_id=1).msg
        answer_action(robot, first, REJECTED)
        line = hq.wait_line(f"action {first.action_seq} ", ACK_TIMEOUT_S)
        assert "REJECTED by robot 6" in line and "acknowledged" not in line
        _mark(hq.db, 6, 2)
        second = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, victim_id=2).msg
        answer_action(robot, second, DUPLICATE)  # applied before; its first ack was lost
        line = hq.wait_line(f"action {second.action_seq} ", ACK_TIMEOUT_S)
        assert "acknowledged by robot 6" in line
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        results = {a.victim_id: a.ack_result for a in reg.actions()}
        states = {v.sources: v.state for v in hq_victims(reg)}
    assert results == {1: REJECTED, 2: DUPLICATE}
    # The robot did not apply the rejected decision: the HQ does not show it as done.
    assert states[((6, 1),)] == TrackState.CONFIRMED
    assert states[((6, 2),)] == TrackState.RESCUED


def test_a_version_1_registry_is_upgraded_in_place(tmp_path: Path) -> None:
    import sqlite3

    path = tmp_path / "v1.sqlite"
    Registry(path).close()
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("ALTER TABLE actions DROP COLUMN ack_result")  # what version 1 wrote
    db.execute("UPDATE meta SET value='1' WHERE key='schema_version'")
    db.close()
    with Registry(path) as reg:
        assert reg.actions() == []
        assert not reg.ack_action(1, 0.0, REJECTED)  # the column exists: no error


def test_a_replaced_registry_numbers_actions_above_the_lost_one(tmp_path: Path) -> None:
    from hq.records import IncomingReport, OperatorAction
    from hq.simrobot import SimRobot as _Robot

    with _Robot(4, ("127.0.0.1", 9)) as robot:  # only to build a valid report
        report = robot.victim(1, 1.0, 1.0)
    db = tmp_path / "hq.sqlite"
    numbers = []
    for _ in range(2):  # a burst of actions, then the registry is lost at once
        with Registry(db) as reg:
            reg.store_reports([IncomingReport(report, 1, 1, 0, 191, 0.0)])
            numbers += [reg.add_action(4, 1, OperatorAction.RESCUED) for _ in range(5)]
        db.unlink()
    assert numbers == sorted(set(numbers)), numbers  # all distinct, increasing
