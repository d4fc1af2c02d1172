"""The console's closer-look controls in a real headless Chromium against a running
rescue-hq (issue 42): a victim card's "Look closer" and a robot's "No more looks" /
"Looks on" reach the robot over UDP as RESCUE_OPERATOR_ACTIONs, the robot's answer
shows where the operator pressed, and the robot line shows its looks from its
RESCUE_STATUS. Bad requests to the robots' looks address get a clear answer."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bench.hq_console import BrowserUnavailable, HqConsoleProcess, Mission, chromium, wait_js
from fusion.types import Urgency
from hq.records import ACK_RESULT_REJECTED

ROBOT = 1
LOOKS_ON_FLAGS = 0b111 | 128  # vehicle, camera, HQ link; RESCUE_STATUS_FLAGS_LOOKS_ON


@pytest.fixture
def browser() -> Iterator[Any]:
    try:
        driver = chromium((1300, 700))
    except BrowserUnavailable as exc:
        pytest.skip(str(exc))
    try:
        yield driver
    finally:
        driver.quit()


def _status(mission: Mission, flags: int, looks: tuple[int, ...]) -> None:
    robot = mission.robots[ROBOT]
    robot.send(robot.m.MAVLink_rescue_status_message(10, 9.5, 0.0, 40.0, flags, 1, 0, 0, *looks))
    robot.heartbeat()


def _post(url: str, body: object) -> tuple[int, dict[str, Any]]:
    request = urllib.request.Request(
        url, json.dumps(body).encode(), {"Content-Type": "application/json"}, method="POST"
    )
    try:
        with urllib.request.urlopen(request, timeout=10) as resp:
            return resp.status, json.loads(resp.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def _robot_line(browser: Any) -> str:
    return str(
        browser.execute_script(
            f"return document.querySelector('.robot[data-robot=\"{ROBOT}\"]').innerText"
        )
    )


def test_look_closer_and_looks_off_on_from_the_console(browser: Any, tmp_path: Path) -> None:
    hq = HqConsoleProcess(tmp_path, "--link-timeout-s", "60")
    mission = Mission(hq.address, sysids=(ROBOT,))
    try:
        mission.drive(12.0)
        mission.report(ROBOT, 4, 6.0, -3.0, Urgency.MEDIUM, visibility_pct=48.0)
        _status(mission, LOOKS_ON_FLAGS, (2, 1, 0, 0, 1))
        browser.get(hq.url)
        wait_js(browser, "return document.querySelector('#victims > li')", 10, "the card")
        line = wait_js(
            browser,
            f"const r = document.querySelector('.robot[data-robot=\"{ROBOT}\"] .act-looks-off');"
            "return r && r.parentElement.innerText",
            10,
            "the robot's looks",
        )
        assert "looks on: 2 made, 1 confirmed, 1 aborted" in line and "No more looks" in line
        # Look closer at the victim: straight to the robot; it refuses (its looks went off).
        card = browser.execute_script("return document.querySelector('#victims > li').dataset.id")
        browser.execute_script(f"document.querySelector('#victim-{card} .act-look_closer').click()")
        robot = mission.robots[ROBOT]
        look = robot.wait_for("RESCUE_OPERATOR_ACTION", 5.0, action=5).msg
        assert look.victim_id == 4
        # No more looks, from the robot line.
        browser.execute_script(
            f"document.querySelector('.robot[data-robot=\"{ROBOT}\"] .act-looks-off').click()"
        )
        off = robot.wait_for("RESCUE_OPERATOR_ACTION", 5.0, action=6).msg
        assert off.victim_id == 0
        wait_js(
            browser, "return document.querySelector('.looks-sent.pending')", 5, "sending looks off"
        )
        mission.ack(ROBOT, off)
        mission.ack(ROBOT, look, result=ACK_RESULT_REJECTED)
        _status(mission, 0b111, (2, 1, 0, 0, 1))  # the robot now says its looks are off
        wait_js(
            browser,
            "return document.querySelector('.looks-sent.acked') && "
            "document.querySelector('.act-looks-on')",
            5,
            "looks off acknowledged, and the Looks on button",
        )
        text = wait_js(
            browser,
            f"const r = document.querySelector('#victim-{card} .sent .rejected');"
            "return r && r.innerText",
            5,
            "the refused look on the card",
        )
        assert "look closer" in text and "closer looks are off" in text
        assert "looks off: 2 made" in _robot_line(browser)
        assert "no more looks ✓" in _robot_line(browser)
        browser.save_screenshot(str(tmp_path / "console-looks.png"))
        # Looks on again, from the same place.
        browser.execute_script("document.querySelector('.act-looks-on').click()")
        on = robot.wait_for("RESCUE_OPERATOR_ACTION", 5.0, action=7).msg
        assert on.victim_id == 0 and on.action_seq > off.action_seq
        # Requests the console refuses, each saying why.
        base = f"{hq.url}api/robots"
        assert _post(f"{base}/9/looks", {"looks": "off"}) == (
            404,
            {"error": "robot 9 has never been heard"},
        )
        status, answer = _post(f"{base}/{ROBOT}/looks", {"looks": "maybe"})
        assert status == 400 and "looks must be off or on" in answer["error"]
        status, answer = _post(f"{base}/{ROBOT}/looks", ["off"])
        assert status == 400 and "JSON object" in answer["error"]
        status, answer = _post(f"{base}/300/looks", {"looks": "on"})
        assert status == 400 and "outside 1..255" in answer["error"]
    finally:
        mission.close()
        assert hq.stop() == 0, hq.stderr
