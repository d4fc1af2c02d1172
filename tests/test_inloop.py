"""The companion in the simulator's loop (scenarios/inloop.py): a recorded mission in
simulated time whose rover really drives the closer looks the companion asks for.

A short world: one person wholly under a blanket 1.2 m beside the route, which only
the thermal camera sees (a warm find: a candidate for a closer look). The real
pipeline (the default person models and the thermal detector) runs on every frame;
the autopilot is the simulated ArduPilot Rover, spoken to in MAVLink bytes.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pytest

import scenarios  # noqa: F401  (BLAS single-threaded before numpy, as rescue-sim does)
from companion.config import Config
from mavlink_io.tlog import read_tlog
from scenarios.inloop import InLoopCompanion, recording_config
from scenarios.record import record
from scenarios.worldfile import load_world_text

WORLD = """
format = "rescue-sim-world/1"
name = "one_under_a_blanket"
seed = 3
size_m = [6.0, 4.0]
start_ne_m = [0.6, 1.0]
start_heading_deg = 0.0
route_ne_m = [[0.6, 1.0], [5.4, 1.0]]

[origin]
lat_deg = 40.071
lon_deg = -105.2296
alt_m = 1580.0

[floor]
colour = "#7d7870"
temperature_c = 18.0

[[victims]]
victim_id = 1
north_m = 3.0
east_m = 2.2
heading_deg = 0.0
height_m = 1.7
skin = "#c68642"
top = "#3c5a96"
trousers = "#323c5a"
shoes = "#282422"
hair = "#261e18"
posture = "back"
pattern = "plain"
sleeves = "long"
dust = 0.0
left_arm_deg = 15.0
right_arm_deg = 12.0
leg_spread_deg = 3.0
skin_c = 34.0

[[debris]]
kind = "cloth"
colour = "#6e5a46"
polygon_ne_m = [[4.0, 2.6], [4.0, 1.8], [2.0, 1.8], [2.0, 2.6]]
heat_through = 0.55
"""
START_UNIX_S = 1_700_000_000.0
FPS = 5.0


def _modes(tlog: Path) -> list[tuple[float, int]]:
    """The autopilot's custom mode at each change, from its HEARTBEATs in the tlog."""
    out: list[tuple[float, int]] = []
    for t, msg in read_tlog(tlog):
        heartbeat = msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1
        if heartbeat and (not out or out[-1][1] != msg.custom_mode):
            out.append((t - START_UNIX_S, msg.custom_mode))
    return out


@pytest.fixture(scope="module")
def looked(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, InLoopCompanion]:
    out = tmp_path_factory.mktemp("looks_on")
    companion = InLoopCompanion(recording_config(out, FPS), looks=True, thermal=True)
    record(load_world_text(WORLD, "test"), out, fps=FPS, start_unix_s=START_UNIX_S,
           companion=companion)  # fmt: skip
    return out, companion


def test_a_warm_find_beside_the_route_gets_a_closer_look_that_drives_the_rover(
    looked: tuple[Path, InLoopCompanion],
) -> None:
    out, companion = looked
    assert companion.events, f"no closer look; the companion said {companion.said}"
    look = companion.events[0]
    settings = Config().looks
    assert settings.view_min_m - 0.05 <= math.dist(look.view_ne_m, look.candidate_ne_m)
    assert math.dist(look.view_ne_m, look.candidate_ne_m) <= settings.view_max_m + 0.05
    # The autopilot was told: GUIDED for the look, then AUTO again, in that order.
    modes = [m for _t, m in _modes(out / "mission.tlog")]
    assert modes[:3] == [10, 15, 10]
    # The rover really went to the viewpoint (the true path passes within 0.3 m of it).
    truth = json.loads((out / "ground_truth.json").read_text())
    path = [(n, e) for _t, n, e, _yaw in truth["true_path_unix_n_e_yaw"]]
    assert min(math.dist(p, look.view_ne_m) for p in path) < 0.3
    # ... and finished its mission after it: the recording ends at the route's end.
    assert math.dist(path[-1], (5.4, 1.0)) < 0.3
    assert look.outcome, "the look ended without saying what it settled"


def test_the_person_under_the_blanket_is_reported_where_they_lie(
    looked: tuple[Path, InLoopCompanion],
) -> None:
    _out, companion = looked
    result = companion.result()
    near = [v for v in result.victims if math.dist((v.north_m, v.east_m), (3.0, 2.2)) < 0.6]
    assert len(near) == 1 and near[0].victim_id in result.first_reported_unix_s


def test_with_looks_off_the_rover_drives_its_route_as_a_recording_without_anyone(
    tmp_path: Path,
) -> None:
    world = load_world_text(WORLD, "test")
    alone = tmp_path / "alone"
    record(world, alone, fps=FPS, start_unix_s=START_UNIX_S, thermal=False)
    off = tmp_path / "off"
    config = recording_config(off, FPS)  # the cheap detector: what is driven is the question here
    config = dataclasses.replace(
        config, detector=dataclasses.replace(config.detector, backend="classic")
    )
    companion = InLoopCompanion(config, looks=False, thermal=False)
    record(world, off, fps=FPS, start_unix_s=START_UNIX_S, thermal=False, companion=companion)
    assert companion.events == [] and [m for _t, m in _modes(off / "mission.tlog")] == [10]
    path_alone = json.loads((alone / "ground_truth.json").read_text())["true_path_unix_n_e_yaw"]
    path_off = json.loads((off / "ground_truth.json").read_text())["true_path_unix_n_e_yaw"]
    assert path_off[: len(path_alone)] == path_alone
    assert (
        sorted(p.name for p in (off / "frames").iterdir())[: len(path_alone)]
        == sorted(p.name for p in (alone / "frames").iterdir())[: len(path_alone)]
    )
