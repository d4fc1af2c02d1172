"""One number per victim: the HQ's acknowledgement names its number for the person,
and the robot's announcements after it say the HQ's label (QGC's map label, the
console card); before the HQ has answered they say the robot's own number. End to
end on loopback: the real companion, the simulator and a real rescue-hq. The same
run shows the searched-area map reaching the HQ."""

from __future__ import annotations

import json
import re
import signal
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import pytest
from hqproc import ack_for, mark, start_companion
from test_hq_e2e import HqProcess, start_hq  # noqa: F401  (the fixture)

from fusion.types import TrackState, Urgency
from hq.registry import Registry
from hq.simrobot import SimRobot
from mavlink_io import statustext
from scenarios.live import LiveSim
from scenarios.world import preset


def test_the_hq_acknowledgement_names_its_number_and_the_label_matches_the_console(
    start_hq: Callable[..., HqProcess],  # noqa: F811
) -> None:
    hq = start_hq("--web", "127.0.0.1:0")
    url = hq.wait_line("console on", 15.0).split("console on ", 1)[1].strip()
    with SimRobot(2, hq.address) as robot:
        report = robot.report_msg(robot.victim(7, 3.0, 1.0, urgency=Urgency.CRITICAL))
        robot.send(report)
        ack = ack_for(robot, report.report_seq)
    with Registry(hq.db) as reg:
        hq_id = reg.hq_id_of(2, 7)
    assert hq_id is not None and ack.hq_victim_id == hq_id
    rep = robot.victim(7, 3.0, 1.0, urgency=Urgency.CRITICAL)
    said = statustext.victim_text(rep, ack.hq_victim_id)
    assert said.startswith(f"R2 CRITICAL victim CRIT{hq_id:02d},")
    assert statustext.victim_text(rep).startswith("R2 CRITICAL victim 7,")  # before the answer
    with urllib.request.urlopen(url + "api/state", timeout=10) as resp:
        state = json.loads(resp.read())
    (card,) = state["victims"]
    assert card["label"] == f"CRIT{hq_id:02d}"  # the card and the map say what is heard


def test_retired_and_long_numbers_name_the_victim_as_qgc_does() -> None:
    with SimRobot(3, ("127.0.0.1", 9)) as robot:
        rep = robot.victim(3, 0.0, 0.0)
        rescued = robot.victim(3, 0.0, 0.0, state=TrackState.RESCUED)
    assert statustext.victim_name(rescued, 12) == "RESC12"
    assert statustext.victim_name(rep, 1_000_003) == f"{rep.urgency.name[0]}1000003"
    assert statustext.victim_name(rep, None) == "3"


@pytest.mark.slow
def test_end_to_end_the_robot_says_the_hq_number_after_the_hq_answered(
    tmp_path: Path,
    start_hq: Callable[..., HqProcess],  # noqa: F811
) -> None:
    hq = start_hq()
    with LiveSim(preset("light"), patrol_first_victim=True, speed_m_s=0.25) as sim:
        proc, log = start_companion(
            tmp_path, sim.vehicle_url, sim.camera_source, hq.port, "[coverage]\nperiod_s = 1.0\n"
        )
        try:
            line = hq.wait_line("report robot 1 victim", 60.0)
            victim_id = int(re.search(r"victim (\d+)", line).group(1))  # type: ignore[union-attr]
            with Registry(hq.db) as reg:
                hq_id = reg.hq_id_of(1, victim_id)
            assert hq_id is not None
            mark(hq.db, 1, victim_id, "rescued")
            wanted = f"announce: R1 victim RESC{hq_id:02d} RESCUED"
            deadline = time.monotonic() + 30.0
            while wanted not in log.read_text():
                assert time.monotonic() < deadline, log.read_text()[-3000:]
                time.sleep(0.2)
            # The map comes too, over the same link, after the reports (300 B/s).
            deadline = time.monotonic() + 30.0
            cells: list[tuple[int, int, int]] = []
            while len(cells) <= 100 and time.monotonic() < deadline:
                with Registry(hq.db) as reg:
                    cells = reg.coverage().get(1, [])
                time.sleep(0.5)
        finally:
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=15) == 0, log.read_text()[-3000:]
    text = log.read_text()
    first = re.search(r"announce: R1 \w+ victim (\S+?),", text)
    assert first is not None and first.group(1) == str(victim_id)  # before the HQ answered
    assert len(cells) > 100  # the floor the rover looked at, at the HQ
