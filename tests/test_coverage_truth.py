"""The simulator's truth of which floor cells a camera saw (scenarios/coverage_truth.py),
against the claim (companion/coverage.py): the claim over-claims behind tall debris
only, as docs/COVERAGE.md says."""

from __future__ import annotations

import numpy as np

from companion.coverage import COLOUR_LIT, footprint
from fusion.coverage import CoverageGrid
from fusion.params import GeolocationParams
from fusion.types import PoseSample
from scenarios.camera import VEHICLE_HEIGHT_M, default_camera
from scenarios.coverage_truth import CoverageTruth
from scenarios.world import Debris, World

POSE = PoseSample(0.0, 0.0, 1.0, 5.0, -VEHICLE_HEIGHT_M, 0.0, 0.0, 0.0)  # facing north


def _cells(a: np.ndarray) -> set[tuple[int, int]]:
    return set(map(tuple, a.tolist()))


def test_racking_hides_the_floor_behind_it_and_the_claim_does_not_know() -> None:
    camera = default_camera()
    racking = Debris.box("racking", (90, 90, 100), 3.0, 5.0, 0.5, 1.0, 0.0)  # 2.2 m tall
    open_world = World(size_m=(12.0, 10.0))
    blocked = World(size_m=(12.0, 10.0), debris=(racking,))
    seen_open = _cells(CoverageTruth(open_world, camera).frame(POSE).cells)
    seen_blocked = _cells(CoverageTruth(blocked, camera).frame(POSE).cells)
    behind = {(n, e) for n in range(16, 24) for e in (19, 20)}  # 4-6 m north, right behind it
    beside = {(n, e) for n in range(8, 10) for e in (19, 20)}  # 2-2.5 m north, in front of it
    assert behind <= seen_open and beside <= seen_open
    assert not behind & seen_blocked  # occluded
    assert beside <= seen_blocked
    claim = _cells(footprint(camera, POSE, GeolocationParams(), CoverageGrid(), COLOUR_LIT).cells)
    assert behind <= claim  # the claim has no depth: it counts them (over-claim)
    # In the open, claim and truth are the same floor, up to the image's 10 px margin
    # and the cells half in view.
    assert len(claim - seen_open) <= 0.1 * len(claim)
    assert len(seen_open - claim) <= 0.15 * len(seen_open)


def test_off_the_world_is_never_seen() -> None:
    world = World(size_m=(3.0, 10.0))  # the floor ends 2 m ahead
    seen = CoverageTruth(world, default_camera()).frame(POSE)
    assert len(seen.cells) > 20
    assert seen.cells[:, 0].max() < 12  # north of 3 m is not floor
    assert seen.range_m.max() <= 7.5
