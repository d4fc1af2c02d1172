"""The rescue-hq console in a real headless Chromium, against a running rescue-hq.

Chromium and its driver are Debian's (tools/system-packages.sh), driven by
selenium; nothing is downloaded. A simulated mission (three hq.simrobot robots on
UDP, driving and reporting) feeds the HQ. What an operator relies on: victims
appear on the map and in the list, most urgent first; a button on the page sends
the decision to the robot and every open page shows its acknowledgement; a robot
that falls silent gets a banner; with a token configured, nothing works without
it. The module shares one HQ and one browser to stay within a few seconds.
"""

from __future__ import annotations

import json
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bench.hq_console import BrowserUnavailable, HqConsoleProcess, Mission, chromium, wait_js
from fusion.types import Urgency
from hq.records import ACK_RESULT_REJECTED

TOKEN = "operator-token-for-tests"
LINK_TIMEOUT_S = 1.5


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    try:
        driver = chromium()
    except BrowserUnavailable as exc:
        pytest.skip(str(exc))
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="module")
def mission_hq(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[HqConsoleProcess, Mission]]:
    hq = HqConsoleProcess(
        tmp_path_factory.mktemp("console"), "--link-timeout-s", str(LINK_TIMEOUT_S)
    )
    mission = Mission(hq.address)
    try:
        mission.drive(30.0)
        mission.keep_alive(0.3)
        mission.report(1, 1, 5.0, -25.0, Urgency.LIGHT, visibility_pct=70.0)
        mission.report(2, 1, 14.0, 3.0, Urgency.CRITICAL, visibility_pct=10.0, sigma_m=1.5)
        mission.report(3, 1, 8.0, 36.0, Urgency.MEDIUM, visibility_pct=40.0)
        mission.picture(2, 1, 500, _evidence_jpeg())
        yield hq, mission
    finally:
        mission.close()
        assert hq.stop() == 0, hq.stderr


def _evidence_jpeg() -> bytes:
    """A 240x180 JPEG that looks like nothing else: a gradient with a red box."""
    import cv2
    import numpy as np

    img = np.zeros((180, 240, 3), np.uint8)
    img[:, :, 1] = np.linspace(0, 255, 240, dtype=np.uint8)
    cv2.rectangle(img, (60, 45), (180, 135), (40, 40, 230), 2)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 70])
    assert ok
    return bytes(buf)


def _cards(driver: Any) -> list[dict[str, str]]:
    return list(
        driver.execute_script(
            "return [...document.querySelectorAll('#victims > li')].map(li => ({"
            "id: li.dataset.id, urgency: li.dataset.urgency, state: li.dataset.state,"
            "text: li.innerText}))"
        )
    )


def test_victims_appear_on_the_map_and_in_the_list(
    browser: Any, mission_hq: tuple[HqConsoleProcess, Mission]
) -> None:
    hq, mission = mission_hq
    browser.get(hq.url)
    wait_js(
        browser, "return document.querySelectorAll('[data-victim]').length === 3", 10, "3 markers"
    )
    cards = _cards(browser)
    assert [c["urgency"] for c in cards] == ["CRITICAL", "MEDIUM", "LIGHT"]
    assert "robot 2" in cards[0]["text"] and "10 % visible" in cards[0]["text"]
    # Robot 2 sent its picture of the CRITICAL victim: the card shows it, decoded by
    # the browser at its size; the others say plainly that there is none.
    size = wait_js(
        browser,
        f"const img = document.querySelector('#victim-{cards[0]['id']} .picture img');"
        "return img && img.complete && img.naturalWidth ? [img.naturalWidth, img.naturalHeight] "
        ": null",
        10,
        "the evidence picture",
    )
    assert size == [240, 180]
    assert "no picture" not in cards[0]["text"]
    assert all("no picture" in c["text"] for c in cards[1:])
    colours = browser.execute_script(
        "return [...document.querySelectorAll('[data-victim]')].map(e => "
        "[e.dataset.urgency, e.getAttribute('fill')])"
    )
    assert dict(colours) == {"CRITICAL": "#d7191c", "MEDIUM": "#e66100", "LIGHT": "#1a9641"}
    robots = browser.execute_script(
        "return [...document.querySelectorAll('.robot-mark')].map(e => e.dataset.robot)"
    )
    assert sorted(robots) == ["1", "2", "3"]  # each robot's position on the map
    resources = browser.execute_script(
        "return performance.getEntriesByType('resource').map(e => e.name)"
    )
    assert any(r.endswith("/vendor/leaflet.js") for r in resources)
    assert all(r.startswith(hq.url) for r in resources), resources  # nothing from elsewhere
    # a new report shows without reloading
    mission.report(1, 2, 2.0, -20.0, Urgency.CRITICAL)
    wait_js(browser, "return document.querySelectorAll('[data-victim]').length === 4", 5, "V4")
    assert [c["urgency"] for c in _cards(browser)][:2] == ["CRITICAL", "CRITICAL"]


def test_an_action_on_the_page_reaches_the_robot_and_every_page(
    browser: Any, mission_hq: tuple[HqConsoleProcess, Mission]
) -> None:
    hq, mission = mission_hq
    browser.get(hq.url)
    wait_js(browser, "return document.querySelectorAll('#victims > li').length >= 3", 10, "list")
    first = browser.current_window_handle
    browser.switch_to.new_window("tab")  # a second operator's page
    browser.get(hq.url)
    wait_js(browser, "return document.querySelectorAll('#victims > li').length >= 3", 10, "list")
    second = browser.current_window_handle
    browser.switch_to.window(first)
    card = browser.execute_script(
        "return [...document.querySelectorAll('#victims > li')]"
        ".find(li => li.innerText.includes('robot 3')).dataset.id"
    )
    button = f"#victim-{card} .act-rescued"
    browser.execute_script(f"document.querySelector('{button}').click()")
    assert "Press again" in browser.execute_script(
        f"return document.querySelector('{button}').textContent"
    )
    with pytest.raises(TimeoutError):  # one press is not a decision
        mission.robots[3].wait_for("RESCUE_OPERATOR_ACTION", 0.6)
    browser.execute_script(f"document.querySelector('{button}').click()")
    action = mission.robots[3].wait_for("RESCUE_OPERATOR_ACTION", 5.0, victim_id=1).msg
    assert action.action == 1  # RESCUED
    wait_js(
        browser, f"return document.querySelector('#victim-{card} .sent .pending')", 5, "sending"
    )
    mission.ack(3, action)
    for handle in (first, second):
        browser.switch_to.window(handle)
        wait_js(
            browser,
            f"return document.querySelector('#victim-{card}').dataset.state === 'RESCUED' && "
            f"document.querySelector('#victim-{card} .sent .acked')",
            5,
            "the acknowledgement",
        )
    # a note typed on one page shows on the other
    browser.switch_to.window(first)
    browser.find_element("css selector", f"#victim-{card} .act-note").click()
    field = browser.find_element("css selector", f"#victim-{card} .note-input")
    field.send_keys("team B on the way\n")
    browser.switch_to.window(second)
    wait_js(
        browser,
        f"return document.querySelector('#victim-{card} .notes').innerText.includes('team B')",
        5,
        "the note",
    )
    browser.close()
    browser.switch_to.window(first)


def test_an_action_the_robot_rejects_says_so_on_its_card(
    browser: Any, mission_hq: tuple[HqConsoleProcess, Mission]
) -> None:
    hq, mission = mission_hq
    mission.report(1, 7, 12.0, -20.0, Urgency.CRITICAL)
    with urllib.request.urlopen(hq.url + "api/state", timeout=10) as resp:
        victims = json.loads(resp.read())["victims"]
    card = next(v["id"] for v in victims if {"robot": 1, "victim_id": 7} in v["sources"])
    browser.get(hq.url)
    wait_js(browser, f"return document.querySelector('#victim-{card}')", 10, "its card")
    button = f"#victim-{card} .act-rescued"
    browser.execute_script(f"document.querySelector('{button}').click()")
    browser.execute_script(f"document.querySelector('{button}').click()")
    action = mission.robots[1].wait_for("RESCUE_OPERATOR_ACTION", 5.0).msg
    mission.ack(1, action, result=ACK_RESULT_REJECTED)  # the robot no longer knows it
    line = wait_js(
        browser,
        f"const r = document.querySelector('#victim-{card} .sent .rejected');"
        "return r && r.innerText",
        5,
        "the rejection on the card",
    )
    assert "REJECTED" in line and "not applied" in line
    assert not browser.execute_script(
        f"return document.querySelector('#victim-{card} .sent .acked')"
    )
    assert (
        browser.execute_script(f"return document.querySelector('#victim-{card}').dataset.state")
        != "RESCUED"
    )


def test_a_lost_link_shows_its_banner(
    browser: Any, mission_hq: tuple[HqConsoleProcess, Mission]
) -> None:
    hq, mission = mission_hq
    browser.get(hq.url)
    wait_js(browser, "return document.querySelectorAll('.robot').length === 3", 10, "robots")
    assert browser.execute_script("return document.querySelectorAll('.banner').length") == 0
    mission.silent.add(2)
    text = wait_js(
        browser,
        "const b = document.querySelector('.banner.link-lost'); return b && b.innerText",
        LINK_TIMEOUT_S + 3,
        "the banner",
    )
    assert "LINK LOST: robot 2" in text
    assert (
        browser.execute_script("return document.querySelectorAll('.banner.link-lost').length") == 1
    )
    mission.silent.discard(2)
    wait_js(browser, "return document.querySelectorAll('.banner').length === 0", 5, "no banner")


def test_with_a_token_the_page_and_its_requests_need_it(browser: Any, tmp_path: Path) -> None:
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN)
    hq = HqConsoleProcess(tmp_path, "--web-token-file", str(token_file))
    try:
        browser.delete_all_cookies()
        browser.get(hq.url)
        assert browser.find_elements("css selector", "input[name=token]")  # the sign-in form
        status = browser.execute_script("const r = await fetch('/api/state'); return r.status")
        assert status == 401
        field = browser.find_element("css selector", "input[name=token]")
        field.send_keys("not-the-token-at-all\n")
        wait_js(browser, "return document.body.innerText.includes('wrong token')", 5, "refusal")
        field = browser.find_element("css selector", "input[name=token]")
        field.send_keys(TOKEN + "\n")
        wait_js(browser, "return document.querySelector('#conn.ok')", 10, "the live console")
        status = browser.execute_script("const r = await fetch('/api/state'); return r.status")
        assert status == 200
    finally:
        assert hq.stop() == 0, hq.stderr


def test_without_the_map_library_the_page_says_so_and_lists_victims(
    browser: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("RESCUE_HQ_ASSET_DIR", str(tmp_path / "no-assets"))
    hq = HqConsoleProcess(tmp_path)
    mission = Mission(hq.address, (1,))
    try:
        assert "console has no map" in hq.wait_line("console has no map", 5.0)
        mission.report(1, 1, 3.0, 3.0, Urgency.CRITICAL)
        browser.get(hq.url)
        text = wait_js(
            browser,
            "const m = document.querySelector('.map-missing'); return m && m.innerText",
            10,
            "the missing-map notice",
        )
        assert "rescue-hq assets fetch" in text
        wait_js(browser, "return document.querySelectorAll('#victims > li').length === 1", 5, "V1")
    finally:
        mission.close()
        assert hq.stop() == 0, hq.stderr
