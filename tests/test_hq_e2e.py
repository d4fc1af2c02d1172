"""rescue-hq end to end: the real process against simulated robots over loopback UDP.

Each test starts `python -m hq.cli` on 127.0.0.1 port 0 (the HQ prints the bound
port), drives it with hq.simrobot robots (the project's codec on ephemeral ports)
and checks what a robot and an operator rely on: acknowledgements, the registry,
the exports. Waits are on events (a datagram, a line of HQ output) with timeouts.
"""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import pytest
from hqproc import (
    ACCEPTED,
    ACK_TIMEOUT_S,
    DUPLICATE,
    REJECTED,
    REPO,
    HqProcess,  # noqa: F401  (tests/test_companion_with_hq.py imports it here)
    ack_for,
    acks_waiting,
    hq_starter,
)

from fusion.types import TrackState, Urgency
from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.view import hq_victims

ORIGIN = (47.397742, 8.545594, 488.0)  # an EKF origin for robots that report NED only


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[object]:
    yield from hq_starter(tmp_path)


def test_each_report_acked_duplicates_reacked(start_hq, tmp_path: Path) -> None:
    hq = start_hq()
    with SimRobot(1, hq.address) as robot:
        msgs = [robot.report_msg(robot.victim(v, 2.0 * v, 1.0)) for v in (1, 2, 3)]
        for msg in msgs:
            robot.send(msg)
            ack = ack_for(robot, msg.report_seq)
            assert (ack.result, ack.target_system, ack.target_component) == (ACCEPTED, 1, 191)
        robot.send(msgs[1])  # the robot did not get the first ack: same report again
        assert ack_for(robot, msgs[1].report_seq).result == DUPLICATE
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        assert reg.report_count() == 3
        assert sorted(s.report.victim_id for s in reg.sources()) == [1, 2, 3]


def test_robot_resends_until_acked_stored_once(start_hq) -> None:
    hq = start_hq()
    with SimRobot(4, hq.address) as robot:
        msg = robot.report_msg(robot.victim(9, 1.0, 1.0, urgency=Urgency.CRITICAL))
        results = []
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            robot.send(msg)  # resend the same report until an ack gets through
            try:
                results.append(ack_for(robot, msg.report_seq).result)
            except TimeoutError:
                continue
            if len(results) == 3:  # the first two acks were "lost" on the way back
                break
        assert results == [ACCEPTED, DUPLICATE, DUPLICATE]
    hq.stop()
    with Registry(hq.db) as reg:
        assert reg.report_count() == 1
        assert [s.report.urgency for s in reg.sources()] == [Urgency.CRITICAL]


def test_tunnel_wrapped_report_is_acked_inside_a_tunnel(start_hq) -> None:
    hq = start_hq()
    with SimRobot(7, hq.address, tunnel=True) as robot:
        msg = robot.report_msg(robot.victim(2, 3.0, -1.0))
        robot.send(msg)
        rx = robot.wait_for("RESCUE_ACK", ACK_TIMEOUT_S, seq=msg.report_seq)
        assert rx.tunnelled and rx.msg.result == ACCEPTED
    hq.stop()
    with Registry(hq.db) as reg:
        assert [(s.report.robot_sysid, s.report.victim_id) for s in reg.sources()] == [(7, 2)]


def test_out_of_order_report_is_kept_but_does_not_roll_back(start_hq) -> None:
    hq = start_hq()
    with SimRobot(2, hq.address) as robot:
        now = time.time()
        old = robot.report_msg(robot.victim(5, 1.0, 1.0), seq=10, time_unix_s=now - 5)
        new = robot.report_msg(robot.victim(5, 4.0, 4.0), seq=11, time_unix_s=now)
        robot.send(new)
        assert ack_for(robot, 11).result == ACCEPTED
        robot.send(old)  # arrives late
        # kept in the log (nothing received is lost) but not shown: never ACCEPTED
        assert ack_for(robot, 10).result == REJECTED
    hq.stop()
    with Registry(hq.db) as reg:
        assert reg.report_count() == 2
        (src,) = reg.sources()
        assert (src.report_seq, src.report.north_m) == (11, 4.0)


def test_garbage_foreign_and_invalid_input_then_a_good_report(start_hq) -> None:
    hq = start_hq()
    with SimRobot(3, hq.address) as robot:
        m = robot.m
        robot.send_raw(bytes(range(256)) * 3)  # random bytes, with MAVLink start markers
        robot.send_raw(robot.codec.encode(robot.report_msg(robot.victim(1, 0, 0)))[:40])
        foreign = m.MAVLink_tunnel_message(0, 0, 40000, 3, [1, 2, 3] + [0] * 125)
        robot.send(foreign, tunnel=False)  # someone else's private TUNNEL payload
        bad = robot.report_msg(robot.victim(1, 0.0, 0.0))
        bad.urgency = 9  # not a RESCUE_URGENCY
        robot.send(bad)
        assert ack_for(robot, bad.report_seq).result == REJECTED
        good = robot.report_msg(robot.victim(2, 1.0, 1.0))
        robot.send(good)
        assert ack_for(robot, good.report_seq).result == ACCEPTED
    assert hq.stop() == 0
    assert not any("Traceback" in line for line in hq.stderr)
    with Registry(hq.db) as reg:
        assert [s.report.victim_id for s in reg.sources()] == [2]


def test_three_robots_merge_and_exports(start_hq) -> None:
    hq = start_hq("--origin", ",".join(str(v) for v in ORIGIN))
    robots = [SimRobot(sysid, hq.address) for sysid in (1, 2, 3)]
    try:
        # Robots 1 and 2 see the same person 0.3 m apart (sigma 0.5 m); robot 3 another one.
        plan = [
            (robots[0], robots[0].victim(1, 10.0, 5.0, urgency=Urgency.MEDIUM, visibility_pct=30)),
            (robots[1], robots[1].victim(4, 10.2, 5.2, urgency=Urgency.CRITICAL, visibility_pct=8)),
            (robots[2], robots[2].victim(1, -6.0, 2.0, urgency=Urgency.LIGHT, visibility_pct=80)),
        ]
        msgs = [(robot, robot.report_msg(report)) for robot, report in plan]
        for robot, msg in msgs:  # all at once, then collect: acks must reach the right robot
            robot.status(confirmed=1)
            robot.send(msg)
        for robot, msg in msgs:
            ack = ack_for(robot, msg.report_seq)
            assert (ack.target_system, ack.result) == (robot.sysid, ACCEPTED)
        hq.wait_line("report robot 3 victim 1", ACK_TIMEOUT_S)
    finally:
        for robot in robots:
            robot.close()
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        victims = hq_victims(reg)
        robots_heard = sorted(r.sysid for r in reg.robots())
    assert robots_heard == [1, 2, 3]
    assert len(victims) == 2
    merged = victims[0]  # most urgent first
    assert merged.sources == ((1, 1), (2, 4))
    assert merged.urgency == Urgency.CRITICAL and merged.visibility_pct == pytest.approx(8.0)
    # Fused position lies between the two reports (equal covariances: the midpoint).
    assert merged.north_m == pytest.approx(10.1, abs=1e-6)
    assert merged.sigma_m == pytest.approx(0.5 / 2**0.5, rel=1e-6)

    geo = json.loads((hq.export_dir / "victims.geojson").read_text())
    assert geo["type"] == "FeatureCollection"
    props = {f["properties"]["id"]: f["properties"] for f in geo["features"]}
    assert {p["robots"][0] for p in props.values()} == {1, 3}
    assert props[merged.hq_id]["robots"] == [1, 2]
    assert props[merged.hq_id]["urgency"] == "CRITICAL"
    for f in geo["features"]:
        lon, lat, _alt = f["geometry"]["coordinates"]
        assert abs(lat - ORIGIN[0]) < 1e-3 and abs(lon - ORIGIN[1]) < 1e-3  # within ~100 m

    kml = ET.parse(hq.export_dir / "victims.kml").getroot()
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    marks = kml.findall(".//k:Placemark", ns)
    assert len(marks) == 2
    assert {m.find("k:styleUrl", ns).text for m in marks} == {"#critical", "#light"}

    assert not (hq.export_dir / "victims.plan").exists()  # no rally points to upload
    assert (hq.export_dir / "victims.csv").read_text().count("\n") == 3  # header + 2


def test_operator_action_resent_until_the_robot_acks(start_hq) -> None:
    hq = start_hq()
    with SimRobot(5, hq.address) as robot:
        msg = robot.report_msg(robot.victim(3, 1.0, 2.0))
        robot.send(msg)
        ack_for(robot, msg.report_seq)
        mark = subprocess.run(
            [sys.executable, "-m", "hq.cli", "mark", "--db", str(hq.db),
             "--robot", "5", "--victim", "3", "--rescued"],
            cwd=REPO, capture_output=True, text=True, timeout=30,
        )  # fmt: skip
        assert mark.returncode == 0, mark.stderr
        first = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, victim_id=3).msg
        assert (first.target_system, first.action) == (5, 1)  # RESCUED
        again = robot.wait_for("RESCUE_OPERATOR_ACTION", ACK_TIMEOUT_S, victim_id=3).msg
        assert again.action_seq == first.action_seq  # not acked yet: sent again
        robot.ack_action(again)
        hq.wait_line(f"action {first.action_seq} acknowledged by robot 5", ACK_TIMEOUT_S)
    hq.stop()
    with Registry(hq.db) as reg:
        (action,) = reg.actions()
        assert action.acked_unix_s is not None and action.sent_count >= 2
        assert hq_victims(reg)[0].state == TrackState.RESCUED


def test_registry_survives_kill_9_and_restart(start_hq, tmp_path: Path) -> None:
    hq = start_hq()
    with SimRobot(6, hq.address) as robot:
        msgs = [robot.report_msg(robot.victim(v, float(v), 0.0)) for v in range(1, 6)]
        for msg in msgs:
            robot.send(msg)
            assert ack_for(robot, msg.report_seq).result == ACCEPTED
        hq.kill9()  # every acknowledged report must be on disk now
        hq2 = start_hq(db=hq.db)
        robot.hq_address = hq2.address
        robot.send(msgs[-1])  # a resend of an acked report after the restart
        assert ack_for(robot, msgs[-1].report_seq).result == DUPLICATE
    hq2.stop()
    listing = subprocess.run(
        [sys.executable, "-m", "hq.cli", "list", "--db", str(hq.db)],
        cwd=REPO, capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert listing.returncode == 0
    assert all(f"6:{v}" in listing.stdout for v in range(1, 6))
    with Registry(hq.db) as reg:
        assert reg.report_count() == 5


def test_locked_database_means_no_ack_until_stored(start_hq) -> None:
    hq = start_hq()
    with SimRobot(8, hq.address) as robot:
        robot.status()  # first contact creates the robot row before the lock
        msg = robot.report_msg(robot.victim(1, 1.0, 1.0))
        blocker = sqlite3.connect(hq.db, isolation_level=None, timeout=5)
        blocker.execute("BEGIN EXCLUSIVE")
        try:
            robot.send(msg)
            hq.wait_line("not stored, not acknowledged", 10.0, stderr=True)
            assert acks_waiting(robot) == []  # the HQ did not ack what it did not store
        finally:
            blocker.execute("ROLLBACK")
            blocker.close()
        robot.send(msg)  # the robot resends
        assert ack_for(robot, msg.report_seq).result == ACCEPTED
    hq.stop()
    with Registry(hq.db) as reg:
        assert reg.report_count() == 1


def test_signing_unsigned_reports_are_ignored_signed_ones_acked(start_hq, tmp_path: Path) -> None:
    from mavlink_io.signing import load_signing

    key = tmp_path / "hq.key"
    key.write_text(bytes(range(32)).hex() + "\n")  # a fixed test key
    key.chmod(0o600)
    hq = start_hq("--signing-key", str(key))
    with (
        SimRobot(9, hq.address) as unsigned,
        SimRobot(10, hq.address, signing=load_signing(key)) as signed,
    ):
        forged = unsigned.report_msg(unsigned.victim(1, 0.0, 0.0))
        unsigned.send(forged)
        good = signed.report_msg(signed.victim(1, 1.0, 1.0))
        signed.send(good)
        # The robot's codec accepts only a correctly signed RESCUE_ACK: receiving it
        # proves the HQ signs its replies.
        assert ack_for(signed, good.report_seq).result == ACCEPTED
        assert acks_waiting(unsigned) == []
    hq.stop()
    with Registry(hq.db) as reg:
        assert [s.report.robot_sysid for s in reg.sources()] == [10]
