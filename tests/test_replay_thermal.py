"""``rescue-companion replay --thermal-frames``: both cameras of a recorded mission
through one tracker, in capture-time order."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.commands.replay import replay, result_document
from companion.config_load import load_config
from scenarios.score import load_report, load_truth, score


@pytest.fixture(scope="module")
def mission(light_patrol: Path) -> Path:
    """The shared 25 s recording of a patrol across a fully visible victim."""
    return light_patrol


def _replay_cli(mission: Path, out: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable, "-m", "companion.commands.cli", "replay",
            "--config", str(mission / "camera.toml"),
            "--tlog", str(mission / "mission.tlog"),
            "--frames", str(mission / "frames"),
            "--out", str(out),
            *extra,
        ],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip


def test_a_person_seen_by_both_cameras_is_one_victim_with_both_cues(
    mission: Path, tmp_path: Path
) -> None:
    out = tmp_path / "victims.json"
    result = _replay_cli(mission, out, "--thermal-frames", str(mission / "thermal"))
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["thermal_frames"] > 150  # 25 s at 8.7 frames/s, less the first pose's wait
    s = score(load_truth(mission / "ground_truth.json"), load_report(out))
    assert s.recall == 1.0 and s.false_victims == 0 and not s.duplicates
    (victim,) = doc["victims"]
    assert {"colour_body", "warm"} <= set(victim["cues"])
    assert "warm" in result.stdout.splitlines()[-1]

    # The same inputs give the same document (one clock for both cameras).
    config = load_config(mission / "camera.toml")
    again = replay(config, mission / "mission.tlog", mission / "frames", mission / "thermal")
    assert json.loads(json.dumps(result_document(again))) == doc


def test_thermal_frames_without_a_thermal_section_are_refused_in_one_line(
    mission: Path, tmp_path: Path
) -> None:
    colour_only = tmp_path / "colour.toml"
    text = (mission / "camera.toml").read_text()
    colour_only.write_text(text[: text.index("# The thermal camera")])
    result = subprocess.run(
        [
            sys.executable, "-m", "companion.commands.cli", "replay",
            "--config", str(colour_only),
            "--tlog", str(mission / "mission.tlog"),
            "--frames", str(mission / "frames"),
            "--thermal-frames", str(mission / "thermal"),
            "--out", str(tmp_path / "out.json"),
        ],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2
    assert "no [thermal] section" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_thermal_folder_of_8_bit_pictures_is_skipped_and_the_colour_replay_goes_on(
    mission: Path, tmp_path: Path
) -> None:
    import cv2
    import numpy as np

    bad = tmp_path / "thermal"
    bad.mkdir()
    for i, path in enumerate(sorted((mission / "thermal").iterdir())[:20]):
        cv2.imwrite(str(bad / path.name), np.full((120, 160), 40 + i, np.uint8))
    out = tmp_path / "victims.json"
    result = _replay_cli(mission, out, "--thermal-frames", str(bad))
    assert result.returncode == 0, result.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["thermal_frames"] == 0 and doc["thermal_frames_skipped"] == 20
    assert "8-bit" in result.stderr and "Traceback" not in result.stderr
    (victim,) = doc["victims"]
    assert "colour_body" in victim["cues"] and "warm" not in victim["cues"]
