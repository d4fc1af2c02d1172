"""The searched-area map on the rescue-hq console, in a real headless Chromium against a
running rescue-hq fed by simulated robots over UDP: the three shades under the
victims, the share searched, the largest unsearched places near the robots, and the
GeoJSON download."""

from __future__ import annotations

import json
import os
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bench.hq_console import BrowserUnavailable, HqConsoleProcess, Mission, chromium, wait_js
from fusion.coverage import CoverageDelta, CoverageGrid
from fusion.types import Urgency
from mavlink_io import coverage
from mavlink_io.dialect import RESCUE_COVERAGE_ID

CELL_M = 0.25


def _looked_along(mission: Mission, sysid: int, p: float, until_s: float) -> CoverageGrid:
    """Cells within 2 m of the robot's lanes up to ``until_s`` of mission time, with
    chance ``p`` each, and a look from every metre (so a lane is searched well)."""
    grid = CoverageGrid()
    for t in np.arange(0.0, until_s, 1.0):
        n, e = mission.where(sysid, float(t))
        nn, ee = np.meshgrid(
            np.arange(np.floor((n - 2) / CELL_M), np.ceil((n + 2) / CELL_M)),
            np.arange(np.floor((e - 2) / CELL_M), np.ceil((e + 2) / CELL_M)),
            indexing="ij",
        )
        cells = np.column_stack([nn.ravel(), ee.ravel()]).astype(np.int64)
        grid.add_look(cells, np.full(len(cells), p))
    return grid


def _send_map(mission: Mission, sysid: int, delta: CoverageDelta) -> None:
    robot = mission.robots[sysid]
    for seq, piece in enumerate(coverage.pieces(delta), start=1):
        robot.send(coverage.piece_msg(robot.m, seq, piece))
        robot.wait_for("RESCUE_ACK", 5.0, acked_msgid=RESCUE_COVERAGE_ID, seq=seq)


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


def test_the_console_draws_the_searched_area_under_the_victims(
    browser: Any, tmp_path: Path
) -> None:
    hq = HqConsoleProcess(tmp_path)
    mission = Mission(hq.address, sysids=(1, 2))
    try:
        mission.drive(30.0)
        mission.keep_alive(0.3)
        mission.report(1, 1, 5.0, -30.0, Urgency.CRITICAL, visibility_pct=8.0)
        with mission._lock:
            # Robot 1 searched its first lane well and glanced at the second; robot 2
            # only glanced at its lanes (one look of 0.3 each metre: the lanes overlap).
            _send_map(mission, 1, _looked_along(mission, 1, 0.5, 30.0).delta_since(0))
            _send_map(mission, 2, _looked_along(mission, 2, 0.2, 30.0).delta_since(0))
        browser.get(hq.url)
        c = wait_js(
            browser,
            "return window.hqCoverage && window.hqCoverage.box && window.hqCoverage",
            15,
            "the map",
        )
        s = c["summary"]
        assert 0.0 < s["searched_well_share"] < s["glanced_at_share"] < 1.0
        share = browser.execute_script(
            "return document.getElementById('coverage-share').textContent"
        )
        assert f"{round(100 * s['searched_well_share'])} % searched well" in share
        # The shades are an image in their own pane, under the victims' markers.
        z = browser.execute_script(
            "const p = document.querySelector('.leaflet-coverage-pane');"
            "return [getComputedStyle(p).zIndex, p.querySelectorAll('img.coverage-layer').length,"
            " getComputedStyle(document.querySelector('.leaflet-overlay-pane')).zIndex]"
        )
        assert z[1] == 1 and int(z[0]) < int(z[2])
        # The unsearched places the console points out are near the robots, largest first.
        places = c["places"]
        assert places and all(p["distance_m"] <= 20.0 for p in places)
        assert [p["area_m2"] for p in places] == sorted(
            (p["area_m2"] for p in places), reverse=True
        )
        shown = browser.execute_script(
            "return [...document.querySelectorAll('#coverage-legend .place')].map(e => e.textContent)"
        )
        assert len(shown) == len(places) and "unsearched" in shown[0]
        browser.execute_script("fitAll()")
        shot = Path(os.environ.get("HQ_COVERAGE_SCREENSHOT", tmp_path / "coverage.png"))
        browser.save_screenshot(str(shot))
        # The download: one polygon per cell looked at, in local metres (no origin).
        with urllib.request.urlopen(hq.url + "export/coverage.geojson", timeout=10) as resp:
            doc = json.loads(resp.read())
        assert doc["properties"]["coordinates"] == "local NED metres"
        assert len(doc["features"]) == c["cells"].count("0") + c["cells"].count("1") + c[
            "cells"
        ].count("2")
    finally:
        mission.close()
        assert hq.stop() == 0, hq.stderr
