"""The camera's footprint on the floor (companion/coverage.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.coverage import (
    COLOUR_LIT,
    CoverageMapper,
    DetectionCurve,
    block_luma,
    footprint,
)
from fusion.camera import CameraModel, Intrinsics, Mount
from fusion.coverage import CoverageGrid
from fusion.params import GeolocationParams
from fusion.types import PoseSample, Sensor
from scenarios.camera import VEHICLE_HEIGHT_M, default_camera

FLAT = DetectionCurve((1.0, 20.0), (0.5, 0.5))


def _pose(north_m: float = 0.0, east_m: float = 0.0, yaw_rad: float = 0.0) -> PoseSample:
    return PoseSample(0.0, 0.0, north_m, east_m, -VEHICLE_HEIGHT_M, 0.0, 0.0, yaw_rad)


def test_camera_looking_straight_down_covers_the_square_below_it() -> None:
    # 90 deg across, 200 px: the image's edges 10 px in are at x/z = +-0.9, so from
    # 2 m up the cells whose centres lie within 1.8 m of the point below, each way.
    camera = CameraModel(Intrinsics.from_fov(200, 200, 90.0), Mount(pitch_rad=-math.pi / 2))
    geo = GeolocationParams(floor_down_m=2.0, max_range_m=20.0)
    grid = CoverageGrid(cell_m=0.25)
    look = footprint(camera, PoseSample(0, 0, 0.0, 0.0, 0.0, 0, 0, 0.3), geo, grid, FLAT)
    got = set(map(tuple, look.cells.tolist()))
    want = {(n, e) for n in range(-8, 8) for e in range(-8, 8)}
    # yawed by 0.3 rad the square turns: every cell of the inscribed disc is in it,
    # nothing beyond the circumscribed one.
    centres = grid.centres_ne_m(np.array(sorted(want)))
    inner = {c for c, xy in zip(sorted(want), centres, strict=True) if np.hypot(*xy) < 1.75}
    assert inner <= got
    assert all(np.hypot(*xy) <= 1.8 * math.sqrt(2) for xy in grid.centres_ne_m(look.cells))
    assert np.allclose(look.p, 0.5)
    # Unyawed: exactly the 14 x 14 cells of centres within 1.8 m.
    look = footprint(camera, PoseSample(0, 0, 0.0, 0.0, 0.0, 0, 0, 0.0), geo, grid, FLAT)
    assert set(map(tuple, look.cells.tolist())) == {
        (n, e) for n in range(-7, 7) for e in range(-7, 7)
    }


def test_rover_camera_sees_ahead_out_to_the_detection_range() -> None:
    camera, geo, grid = default_camera(), GeolocationParams(), CoverageGrid()
    look = footprint(camera, _pose(yaw_rad=math.pi / 2), geo, grid, COLOUR_LIT)  # facing east
    ne = grid.centres_ne_m(look.cells)
    assert len(look.cells) > 200
    assert ne[:, 1].min() > 0.3  # the floor right under and behind the camera is not seen
    assert look.range_m.max() <= COLOUR_LIT.max_range_m
    assert ne[:, 1].max() > 6.0
    # Within the 70 deg field of view (35 deg each side of east), with a cell's slack.
    bearing = np.degrees(np.arctan2(ne[:, 0], ne[:, 1] - 0.15))
    assert np.abs(bearing).max() < 39.0
    far = look.range_m > 6.6
    assert np.all(look.p[far] < look.p[look.range_m < 3.0].min())


def test_dark_cells_take_the_dark_curve() -> None:
    camera, geo, grid = default_camera(), GeolocationParams(), CoverageGrid()
    dark = DetectionCurve((1.0, 2.0, 3.0), (0.9, 0.5, 0.0))
    lit = np.full((60, 80), 0.5)
    black = np.full((60, 80), 0.05)
    bright = footprint(camera, _pose(), geo, grid, COLOUR_LIT, lit, dark)
    dim = footprint(camera, _pose(), geo, grid, COLOUR_LIT, black, dark)
    assert np.allclose(bright.p, COLOUR_LIT.at(bright.range_m))
    assert np.allclose(dim.p, dark.at(dim.range_m))
    assert dim.p[dim.range_m > 3.0].max() == 0.0
    image = np.zeros((480, 640, 3), np.uint8)
    image[:, 320:] = 200
    luma = block_luma(image)
    assert luma.shape == (60, 80) and luma[0, 0] == 0.0 and luma[0, 79] == pytest.approx(200 / 255)


def test_a_look_counts_from_a_new_viewpoint_only() -> None:
    mapper = CoverageMapper(CoverageGrid(), GeolocationParams(), default_camera())
    assert mapper.add(_pose(), Sensor.COLOUR) > 0
    assert mapper.add(_pose(0.05), Sensor.COLOUR) == 0  # 5 cm on: the same view
    assert mapper.add(_pose(0.25), Sensor.COLOUR) > 0
    assert mapper.add(_pose(0.25, yaw_rad=0.3), Sensor.COLOUR) > 0  # turned 17 deg
    assert mapper.add(None, Sensor.COLOUR) == 0  # no pose, no look
    assert mapper.add(_pose(5.0), Sensor.THERMAL) == 0  # no thermal camera


def test_curve_refuses_nonsense() -> None:
    with pytest.raises(ValueError, match="must increase"):
        DetectionCurve((2.0, 1.0), (0.5, 0.5))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        DetectionCurve((1.0, 2.0), (0.5, 1.5))
    assert DetectionCurve((1.0, 2.0, 3.0), (0.5, 0.2, 0.0)).max_range_m == 3.0


def test_thermal_frames_add_the_thermal_cameras_footprint() -> None:
    from companion.coverage import THERMAL
    from scenarios.camera import default_thermal_camera

    grid = CoverageGrid()
    mapper = CoverageMapper(grid, GeolocationParams(), default_camera(), default_thermal_camera())
    assert mapper.add(_pose(), Sensor.THERMAL) > 100
    # Its own viewpoint record: the colour camera's first frame counts too.
    assert mapper.add(_pose(), Sensor.COLOUR) > 100
    ahead = grid.cell_of(np.array([4.5]), np.array([0.0]))
    # Both looked at a cell 4.4 m ahead: independent chances, thermal's and colour's.
    want = 1 - (1 - THERMAL.at(np.array([4.41]))[0]) * (1 - COLOUR_LIT.at(np.array([4.41]))[0])
    assert grid.p_at(ahead)[0] == pytest.approx(want, abs=0.02)


def test_a_strong_lens_claims_no_floor_folded_back_into_its_image() -> None:
    # bench/accuracy.py's cheap wide-angle lens: its polynomial maps points far outside
    # the view (beside and under the camera) back into the image.
    import dataclasses

    from bench.accuracy import WIDE_LENS_DISTORTION

    base = default_camera()
    wide = dataclasses.replace(
        base, intrinsics=dataclasses.replace(base.intrinsics, distortion=WIDE_LENS_DISTORTION)
    )
    grid = CoverageGrid()
    look = footprint(wide, _pose(), GeolocationParams(), grid, COLOUR_LIT)
    ne = grid.centres_ne_m(look.cells)
    assert len(ne) > 200
    # Every cell ahead of the camera, within its field of view (wider than 70 deg
    # now: the lens's barrel widens it), and none at the camera's feet.
    bearing = np.degrees(np.arctan2(ne[:, 1], ne[:, 0] - 0.15))
    assert np.abs(bearing).max() < 60.0
    assert ne[:, 0].min() > 0.3
