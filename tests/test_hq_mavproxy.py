"""Three robots reach one rescue-hq through MAVProxy as the hub (a real, independent peer).

What MAVProxy (1.8.x, pymavlink 2.4.4x) does with our traffic, as measured here:
- robot -> HQ: every master's packets go to every --out, our RESCUE_* IDs too
  (pymavlink passes a MAVLink 2 frame with an unknown ID on as UNKNOWN_<id>, bytes intact);
- HQ -> robot: MAVProxy routes a packet to the master link on which its
  ``target_system`` last sent a HEARTBEAT. It cannot read target_system out of an
  unknown message, so a direct RESCUE_ACK goes to the primary (first) master only:
  for robots on the other links it is lost. A TUNNEL (common.xml) is routed by its
  target_system to the right robot: through MAVProxy, robots use TUNNEL.
Each robot has its own --master port and sends HEARTBEATs (MAVProxy learns routes).
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_hq_e2e import ACCEPTED, start_hq  # noqa: F401  (the fixture)

from hq.registry import Registry
from hq.simrobot import SimRobot

REPO = Path(__file__).resolve().parents[1]
MAVPROXY = REPO / ".venv" / "bin" / "mavproxy.py"
HUB_TIMEOUT_S = 20.0  # MAVProxy takes 1-3 s to start on this machine; margin for load


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def mavproxy_hub(tmp_path: Path) -> Iterator[object]:
    if not MAVPROXY.exists():
        pytest.skip(f"MAVProxy not installed at {MAVPROXY}")
    procs: list[subprocess.Popen[bytes]] = []

    def start(master_ports: list[int], out_port: int) -> None:
        cmd = [str(MAVPROXY)]
        for port in master_ports:
            cmd += ["--master", f"udpin:127.0.0.1:{port}"]
        cmd += [
            "--out", f"udpout:127.0.0.1:{out_port}",
            "--daemon", "--non-interactive", "--nowait",
            "--state-basedir", str(tmp_path / "mavproxy"),
        ]  # fmt: skip
        procs.append(
            subprocess.Popen(
                cmd, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            )
        )

    yield start
    for proc in procs:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


def deliver_until_acked(robot: SimRobot, msg: object, timeout_s: float) -> object:
    """Send HEARTBEAT + the report until its ack comes back (MAVProxy may still be starting)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        robot.heartbeat()
        robot.send(msg)
        try:
            return robot.wait_for("RESCUE_ACK", 0.5, acked_msgid=43100, seq=msg.report_seq)
        except TimeoutError:
            continue
    raise TimeoutError(f"robot {robot.sysid}: no ack through MAVProxy in {timeout_s} s")


def test_three_robots_through_mavproxy(start_hq, mavproxy_hub) -> None:  # noqa: F811
    if shutil.which(str(MAVPROXY)) is None:
        pytest.skip("mavproxy.py is not executable")
    hq = start_hq()
    ports = [free_udp_port() for _ in range(3)]
    mavproxy_hub(ports, hq.port)
    robots = [
        SimRobot(sysid, ("127.0.0.1", port)) for sysid, port in zip((1, 2, 3), ports, strict=True)
    ]
    try:
        for i, robot in enumerate(robots):
            robot.tunnel = True
            msg = robot.report_msg(robot.victim(1, 5.0 * i, 0.0))
            rx = deliver_until_acked(robot, msg, HUB_TIMEOUT_S)
            assert rx.tunnelled and rx.msg.result == ACCEPTED
            assert rx.msg.target_system == robot.sysid
        # Direct (untunnelled) reports: they reach the HQ, but the HQ's direct acks leave
        # MAVProxy on the primary master link, i.e. towards robot 1, whoever they are for.
        r1, r2 = robots[0], robots[1]
        direct1 = r1.report_msg(r1.victim(50, 1.0, 1.0))
        r1.send(direct1, tunnel=False)
        ack1 = r1.wait_for("RESCUE_ACK", HUB_TIMEOUT_S, seq=direct1.report_seq)
        assert not ack1.tunnelled and ack1.msg.result == ACCEPTED
        direct2 = r2.report_msg(r2.victim(60, 2.0, 2.0))
        r2.send(direct2, tunnel=False)
        hq.wait_line("report robot 2 victim 60", HUB_TIMEOUT_S)  # it did arrive at the HQ
        misrouted = r1.wait_for(
            "RESCUE_ACK", HUB_TIMEOUT_S, any_target=True, seq=direct2.report_seq
        )
        assert misrouted.msg.target_system == 2  # robot 2's ack, delivered to robot 1
    finally:
        for robot in robots:
            robot.close()
    hq.stop()
    with Registry(hq.db) as reg:
        stored = sorted((s.report.robot_sysid, s.report.victim_id) for s in reg.sources())
    assert stored == [(1, 1), (1, 50), (2, 1), (2, 60), (3, 1)]
