"""The default detector (the real person models) on the rover's own view: frames of
3-D bodies rendered by the scenarios package from the simulated camera (0.3 m above
the floor, 12 degrees down), so a lying body is a low band across the frame, with
the geometry built from the pose exactly as the pipeline builds it. Views are taken
from 2.0-3.0 m at three bearings, three frames each (the detector's extra passes
take turns over frames, as live); rates are asserted over all views, never one lucky
frame. A victim with only a hand out of the rubble (preset "critical") is not found
from these views: docs/VISION.md says so.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.config import DetectorConfig
from companion.vision.backends import make_detector
from companion.vision.base import FrameGeometry
from companion.vision.grid import GridParams, floor_grid
from companion.vision.visibility import assess
from fusion.geolocate import geolocate
from fusion.params import GeolocationParams
from fusion.types import PoseSample, Urgency

scenarios = pytest.importorskip("scenarios.render")
from scenarios.camera import VEHICLE_HEIGHT_M, default_camera  # noqa: E402
from scenarios.render import Renderer  # noqa: E402
from scenarios.world import preset  # noqa: E402

PARAMS = GeolocationParams()
RANGES_M = (2.0, 2.5, 3.0)
BEARINGS_RAD = (0.3, 2.4, 4.4)


def _views(name: str):  # type: ignore[no-untyped-def]
    """(pose, image, geometry, victim) for each range x bearing around each victim."""
    world = preset(name)
    camera = default_camera()
    renderer = Renderer(world, camera, seed=7)
    k = 0
    for victim in world.victims:
        for rng_m in RANGES_M:
            for bearing in BEARINGS_RAD:
                n = victim.visible_north_m - rng_m * math.cos(bearing)
                e = victim.visible_east_m - rng_m * math.sin(bearing)
                pose = PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, bearing)
                image = renderer.render(pose, frame_key=k).image
                k += 1
                yield pose, image, FrameGeometry.from_pose(camera, pose, PARAMS), victim


@pytest.fixture()  # fresh per case: its passes' turns must not depend on the test order
def people():  # type: ignore[no-untyped-def]
    return make_detector(DetectorConfig())


def _floor_error_m(pose: PoseSample, det, victim) -> float:  # type: ignore[no-untyped-def]
    fix = geolocate(default_camera(), pose, det.u_px, det.v_px, PARAMS)
    return min(
        math.hypot(fix.north_m - victim.visible_north_m, fix.east_m - victim.visible_east_m),
        math.hypot(fix.north_m - victim.north_m, fix.east_m - victim.east_m),
    )


@pytest.mark.parametrize(
    ("name", "min_found", "urgency", "min_right"),
    [
        # Orange top, navy trousers, fully visible. LIGHT in 3 of 9 views since the
        # heatmap cap (2026-11-27, 4 or more before): the simulated body's joint
        # heatmaps are weak from the rover's low camera (docs/VISION.md). With the
        # full landmark model (2026-11-28) 4 of 9, and 2 of 9 in the dark zone
        # (lite 4 there; one of full's views reads 49 %, just under the boundary).
        # Each case has a fresh detector: its extra passes take turns over frames, so
        # a detector carried over from the cases before read the dark zone's views 3
        # of 9 right or 2 by the order xdist ran them in (2026-11-29).
        ("light", 5, Urgency.LIGHT, 3),
        ("dark", 5, Urgency.LIGHT, 2),  # the same in a dark zone (8 % light)
        # Half under a slab: found in about half the views (from a low camera a body
        # whose far half is buried looks whole end-on), its class not reliably.
        ("medium", 4, None, 0),
    ],
)
def test_one_detection_per_victim_from_most_views(
    people, name: str, min_found: int, urgency: Urgency | None, min_right: int
) -> None:
    found = right = 0
    views = list(_views(name))
    for pose, image, geometry, victim in views:
        seen = None
        for _ in range(3):
            dets = people.detect(image, geometry, 0.0)
            near = [d for d in dets if _floor_error_m(pose, d, victim) < 1.0]
            # Never two detections for one person (the tracker would make two victims).
            assert len(near) <= 1, f"{name}: {len(near)} detections of one victim"
            seen = seen or (near[0] if near else None)
        if seen is not None:
            found += 1
            a = assess(seen, geometry)
            right += int(a is not None and a.urgency == urgency)
    assert found >= min_found, f"{name}: found in {found} of {len(views)} views"
    assert right >= min_right, f"{name}: right class in {right} of {len(views)} views"


def test_the_working_grid_keeps_far_rows_and_merges_near_ones() -> None:
    camera = default_camera()
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, -VEHICLE_HEIGHT_M, 0.0, 0.0, 0.0)
    geometry = FrameGeometry.from_pose(camera, pose, PARAMS)
    grid = floor_grid(640, 480, geometry, GridParams())
    # Rows above the usable floor (horizon, beyond max range) are dropped ...
    assert geometry.metres_per_px(320, grid.row_v[0] - 4) is None
    assert geometry.metres_per_px(320, grid.row_v[3]) is not None
    # ... far rows (each spans > 12 mm of floor) are all kept, near ones merged 4:1.
    assert grid.row_k[0] == 1 and grid.row_k.max() == 4
    assert grid.work_h < 480 // 2
    # Every frame row below the first is covered exactly once.
    covered = sum(v1 - v0 for v0, v1, _ in grid.bands)
    assert covered == 480 - grid.bands[0][0]
    small = grid.sample(np.zeros((480, 640, 3), np.uint8))
    assert small.shape == (grid.work_h, 320, 3)


def test_a_column_of_metres_per_pixel_is_the_rows_asked_one_by_one() -> None:
    # The person models' far-band search asks each frame for a column at once: the
    # same answers as one call per row, off the floor (None) exactly where those are,
    # and cached alike (a later single call gets the same number).
    pose = PoseSample(0.0, 0.0, 1.0, 1.0, -VEHICLE_HEIGHT_M, 0.02, -0.03, 0.4)
    camera, params = default_camera(), GeolocationParams()
    rows = list(range(0, 480, 5))
    column = FrameGeometry.from_pose(camera, pose, params).metres_per_px_column(320.0, rows)
    one_by_one = FrameGeometry.from_pose(camera, pose, params)
    assert column == [one_by_one.metres_per_px(320.0, v) for v in rows]
    assert any(m is None for m in column) and any(m is not None for m in column)
    assert FrameGeometry.from_pose(camera, pose, params).metres_per_px_column(math.inf, rows) == [
        None
    ] * len(rows)
