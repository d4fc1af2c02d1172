"""The console in a real headless Chromium shows a warm victim as the operator needs
it: what saw it (``seen: colour part · warm``) and its thermal view beside its colour
view, each the picture the robot sent; a victim without a thermal view shows one
picture only, and one whose robot does not say what saw it says ``not known``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from bench.hq_console import BrowserUnavailable, HqConsoleProcess, chromium, wait_js
from fusion.types import Cue, Sensor, Urgency
from hq.simrobot import SimRobot
from mavlink_io import picture


def _jpeg(width: int, height: int, channel: int) -> bytes:
    img = np.zeros((height, width, 3), np.uint8)
    img[:, :, channel] = np.linspace(30, 255, width, dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 70])
    assert ok
    return bytes(buf)


def _send_picture(robot: SimRobot, victim: int, pid: int, jpeg: bytes, kind: Sensor) -> None:
    m = robot.codec.module
    chunks = picture.split(pid, victim, jpeg, kind)
    for c in chunks[:-1]:
        robot.send(c.to_msg(m))
    robot.send(chunks[-1].asking().to_msg(m))
    ack = robot.wait_for("RESCUE_PICTURE_ACK", 5.0, picture_id=pid).msg
    assert ack.result == picture.RESULT_STORED


def test_the_card_shows_what_saw_the_victim_and_the_thermal_view_beside_the_colour_one(
    tmp_path: Path,
) -> None:
    try:
        browser = chromium()
    except BrowserUnavailable as exc:
        pytest.skip(str(exc))
    hq = HqConsoleProcess(tmp_path)
    try:
        with SimRobot(2, hq.address, tunnel=True) as robot:
            for victim, north, cues in ((1, 4.0, Cue.COLOUR_PART | Cue.WARM), (2, -9.0, Cue(0))):
                msg = robot.report_msg(
                    robot.victim(victim, north, 2.0, urgency=Urgency.CRITICAL, cues=cues)
                )
                robot.send(msg)
                robot.wait_for("RESCUE_ACK", 5.0, seq=msg.report_seq)
            _send_picture(robot, 1, 30, _jpeg(240, 180, 1), Sensor.COLOUR)
            _send_picture(robot, 1, 31, _jpeg(334, 216, 2), Sensor.THERMAL)
            _send_picture(robot, 2, 32, _jpeg(240, 180, 1), Sensor.COLOUR)
        browser.get(hq.url)
        script = (
            "const cards = [...document.querySelectorAll('#victims > li')];"
            "if (cards.length !== 2) return null;"
            "return cards.map(li => {"
            " const imgs = [...li.querySelectorAll('.picture:not([hidden]) img')];"
            " if (!imgs.every(i => i.complete && i.naturalWidth)) return null;"
            " return {text: li.innerText, pics: imgs.map(i => {"
            "  const r = i.getBoundingClientRect();"
            "  return [i.closest('.picture').classList.contains('thermal'), i.naturalWidth,"
            "          Math.round(r.left), Math.round(r.right), Math.round(r.top)]; })};"
            "})"
        )
        cards: Any = wait_js(
            browser,
            f"const got = (() => {{ {script} }})();"
            "return got && got.every(c => c) && got[0].pics.length + got[1].pics.length === 3"
            " ? got : null",
            15,
            "two cards with three pictures",
        )
        warm = next(c for c in cards if "seen: colour part · warm" in c["text"])
        other = next(c for c in cards if c is not warm)
        assert "seen: not known" in other["text"]
        (colour, thermal) = sorted(warm["pics"])  # False (colour) first
        assert (colour[0], colour[1]) == (False, 240) and (thermal[0], thermal[1]) == (True, 334)
        assert thermal[2] >= colour[3] and thermal[4] == colour[4]  # beside it, same row
        assert [p[0] for p in other["pics"]] == [False]  # no thermal view: one picture
    finally:
        browser.quit()
        assert hq.stop() == 0, hq.stderr
