"""``rescue-companion replay`` writes where the camera looked: a ``coverage`` member in
its JSON and the grid under the mission map (a real recording, the real CLI)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.coverage import p_of_document
from scenarios.live import _patrol
from scenarios.record import record
from scenarios.world import preset


@pytest.fixture(scope="module")
def replayed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    """An 8 s recording of the rover driving north towards a victim, replayed."""
    mission = tmp_path_factory.mktemp("mission")
    record(_patrol(preset("light")), mission, duration_s=8.0, start_unix_s=1.767e9, thermal=False)
    out = tmp_path_factory.mktemp("replay") / "victims.json"
    result = subprocess.run(
        [
            sys.executable, "-m", "companion.commands.cli", "replay",
            "--config", str(mission / "camera.toml"),
            "--tlog", str(mission / "mission.tlog"),
            "--frames", str(mission / "frames"),
            "--out", str(out),
        ],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    return mission, json.loads(out.read_text())


def test_coverage_member_holds_the_cells_ahead_of_the_route(
    replayed: tuple[Path, dict[str, object]],
) -> None:
    mission, doc = replayed
    cov = doc["coverage"]
    assert isinstance(cov, dict)
    p = p_of_document(cov)
    assert p.shape == tuple(cov["shape"])
    s = cov["cell_m"]
    n0, e0 = cov["origin_index"]
    victim = json.loads((mission / "ground_truth.json").read_text())["victims"][0]
    # The victim lies 2.5 m ahead of the start, in plain view: searched well.
    r = math.floor(victim["north_m"] / s) - n0
    c = math.floor(victim["east_m"] / s) - e0
    assert p[r, c] >= 0.9
    # Behind the start (the rover faces north and never turns round in 8 s): unseen.
    start_n = victim["north_m"] - 2.5
    behind = math.floor((start_n - 1.0) / s) - n0
    if behind >= 0:
        assert p[behind, c] == 0.0
    assert cov["searched_well_m2"] > 2.0
    assert cov["looked_at_m2"] >= cov["glanced_at_m2"] >= cov["searched_well_m2"]
    assert len(json.dumps(cov)) < 20_000  # compact


def test_map_shows_the_grid(replayed: tuple[Path, dict[str, object]], tmp_path: Path) -> None:
    mission, _doc = replayed
    png = next(mission.parent.glob("replay*/victims.png"), None)
    assert png is not None
    img = cv2.imread(str(png))
    well = np.all(img == np.array([170, 215, 160], np.uint8), axis=2)
    assert well.sum() > 500  # the searched-well shade fills part of the floor
