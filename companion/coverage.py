"""Each frame's footprint on the floor, added to the mission's coverage grid.

For a frame with a pose, the cells of the floor the camera sees (cell centres that
project into the image, in front of the camera) out to the range at which its
detector still finds a lying adult get that detector's chance of finding one there,
``DetectionCurve.at(range_m)``, measured in the simulator on whole lying adults
(bench/coverage.py, docs/COVERAGE.md). For the colour camera the chance falls to the
dark curve where the frame is dark at that cell (its luma, 8x8-pixel blocks:
``DARK_LUMA`` and below dark, ``LIT_LUMA`` and above lit, linear between), as the
person models find little in the dark (docs/VISION.md).

A look counts only from a new viewpoint: the camera moved ``min_move_m`` or turned
``min_turn_deg`` since that camera's last counted look. The curves are chances per
view (three frames as live), and frames of a rover standing still are not
independent chances: without this, a rover parked 6 m from a corner would "search
it well" in a few seconds.

What it cannot know it does claim: the camera has no depth, so the cells behind
tall debris, a wall or a pile are in the footprint though nothing of them shows.
bench/coverage.py measures how much that over-claims against the simulator's truth.

Pure but for OpenCV's resize of the luma; owned by the processing thread.
"""

from __future__ import annotations

import base64
import functools
import math
import threading
import zlib
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from fusion.camera import CameraModel, rotation_zyx
from fusion.coverage import CellIndex, CoverageDelta, CoverageGrid
from fusion.params import GeolocationParams
from fusion.types import PoseSample, Sensor

DARK_LUMA = 0.12  # an 8x8 block this dark or darker: the dark curve
LIT_LUMA = 0.25  # this bright or brighter: the lit curve (the enhancer's own threshold)
_LUMA_BLOCK_PX = 8
_EDGE_MARGIN_PX = 10.0  # a cell closer to the image's edge than this is not counted


@dataclass(frozen=True)
class DetectionCurve:
    """The chance per view of finding a lying adult at a range: linear between the
    measured points, the first point's value nearer, 0 beyond the last point."""

    ranges_m: tuple[float, ...]
    p: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.ranges_m) != len(self.p) or len(self.p) < 2:
            raise ValueError("a detection curve needs two or more (range, p) points")
        if any(b <= a for a, b in zip(self.ranges_m, self.ranges_m[1:], strict=False)):
            raise ValueError(f"ranges_m {self.ranges_m}: must increase")
        if not all(0.0 <= p <= 1.0 for p in self.p):
            raise ValueError(f"p {self.p}: must lie in [0, 1]")

    @property
    def max_range_m(self) -> float:
        """The farthest range with a chance above 0."""
        nonzero = [r for r, p in zip(self.ranges_m, self.p, strict=True) if p > 0.0]
        if not nonzero:
            return 0.0
        k = self.ranges_m.index(nonzero[-1])
        return self.ranges_m[min(k + 1, len(self.ranges_m) - 1)]

    def at(self, range_m: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.interp(range_m, self.ranges_m, self.p, left=self.p[0], right=0.0)


# Measured 2026-11-29 (bench/coverage.py, docs/COVERAGE.md): the default people
# detector, whole lying adults (the postures, sizes, skins and clothes of
# bench/sim_burial.py) from the rover's camera (0.3 m up, 12 deg down) at four
# bearings, three frames a view, found within 1 m: 24 views a range.
_RANGES_M = (1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5)
COLOUR_LIT = DetectionCurve(_RANGES_M, (0.875, 0.958, 0.958, 0.625, 0.375, 0.125, 0.0))
# Dark: the simulator loses no body at 5 % light, real frames do: at 12 % light the
# models find 6 of 11 real lying people (enhanced) against 11 of 11 lit
# (docs/VISION.md, "Dark"). So the lit curve times 6/11.
COLOUR_DARK = DetectionCurve(_RANGES_M, tuple(round(p * 6 / 11, 3) for p in COLOUR_LIT.p))
# The thermal detector (since c734f6e), the Lepton beside the colour camera, two
# frames a view, 24 views a range.
THERMAL = DetectionCurve(_RANGES_M, (0.792, 0.5, 0.458, 0.417, 0.375, 0.333, 0.333))


@dataclass(frozen=True)
class Footprint:
    """One look: global cell indices (K, 2), each cell's chance and its range."""

    cells: NDArray[np.int64]
    p: NDArray[np.float64]
    range_m: NDArray[np.float64]


def block_luma(image: NDArray[np.uint8]) -> NDArray[np.float64]:
    """The mean luma (0..1) of each 8x8 block of a BGR frame (of four of its pixels)."""
    h, w = image.shape[:2]
    small = cv2.resize(
        image[::4, ::4],  # every fourth pixel: four samples a block are enough
        (max(1, w // _LUMA_BLOCK_PX), max(1, h // _LUMA_BLOCK_PX)),
        interpolation=cv2.INTER_AREA,
    )
    return cv2.cvtColor(small, cv2.COLOR_BGR2GRAY).astype(float) / 255.0


@functools.lru_cache(maxsize=8)
def _half_fov_rad(camera: CameraModel) -> float:
    """Half the horizontal field of view, from the image's corners (distortion
    included), plus 5 degrees of slack."""
    k = camera.intrinsics
    corners = np.array(
        [
            [-0.5, -0.5],
            [k.width_px - 0.5, -0.5],
            [-0.5, k.height_px - 0.5],
            [k.width_px - 0.5, k.height_px - 0.5],
        ]
    )
    rays = camera.rays_camera(corners)
    widest = float(np.max(np.abs(np.arctan2(rays[:, 0], rays[:, 2]))))
    return widest + math.radians(5.0)


@functools.lru_cache(maxsize=8)
def _view_bounds(camera: CameraModel) -> tuple[float, float]:
    """The largest |x/z| and |y/z| (undistorted) of the image's border pixels."""
    k = camera.intrinsics
    u = np.linspace(-0.5, k.width_px - 0.5, 65)
    v = np.linspace(-0.5, k.height_px - 0.5, 49)
    border = np.vstack(
        [
            np.column_stack([u, np.full(len(u), -0.5)]),
            np.column_stack([u, np.full(len(u), k.height_px - 0.5)]),
            np.column_stack([np.full(len(v), -0.5), v]),
            np.column_stack([np.full(len(v), k.width_px - 0.5), v]),
        ]
    )
    rays = camera.rays_camera(border)
    xy = np.abs(rays[:, :2] / rays[:, 2:3])
    return float(xy[:, 0].max()), float(xy[:, 1].max())


def footprint(
    camera: CameraModel,
    pose: PoseSample,
    geo: GeolocationParams,
    grid: CoverageGrid,
    curve: DetectionCurve,
    luma: NDArray[np.float64] | None = None,
    dark: DetectionCurve | None = None,
) -> Footprint:
    """The floor cells this camera sees from ``pose`` (their centres in the image,
    at least 10 px inside its edges, within the curve's range and ``geo``'s
    [min_range_m, max_range_m] of the camera) and each one's chance. With ``luma``
    (``block_luma`` of the frame) and ``dark``, a dark cell takes the dark curve."""
    reach_m = min(curve.max_range_m, geo.max_range_m)
    empty = Footprint(np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0))
    if reach_m <= 0.0:
        return empty
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    centre, r_ned_cam = camera.camera_pose_ned(vehicle, r_ned_body)
    floor_down_m = pose.down_m + geo.floor_down_m
    height_m = floor_down_m - centre[2]
    if height_m <= 0.0 or height_m >= reach_m:
        return empty
    radius_m = math.sqrt(reach_m**2 - height_m**2)
    s = grid.cell_m
    # Candidates: the cells of the bounding box of the floor sector ahead (the whole
    # disc when the camera looks nearly straight down), then only the near ones.
    axis = r_ned_cam[:2, 2]  # the optical axis on the floor
    half_rad = _half_fov_rad(camera)
    sector = float(np.hypot(*axis)) > 0.2 and half_rad < math.radians(80.0)
    if sector:
        heading = math.atan2(axis[1], axis[0])
        angles = heading + np.linspace(-half_rad, half_rad, 9)
        ends = centre[:2] + radius_m * np.column_stack([np.cos(angles), np.sin(angles)])
        corners = np.vstack([ends, centre[:2][None, :]])
        lo = np.floor(corners.min(axis=0) / s).astype(np.int64)
        hi = np.floor(corners.max(axis=0) / s).astype(np.int64)
    else:
        lo = np.floor((centre[:2] - radius_m) / s).astype(np.int64)
        hi = np.floor((centre[:2] + radius_m) / s).astype(np.int64)
    nn, ee = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    cells = np.column_stack([nn.ravel(), ee.ravel()])
    ne = grid.centres_ne_m(cells)
    d_ne = ne - centre[:2]
    range_m = np.sqrt(np.einsum("ij,ij->i", d_ne, d_ne) + height_m**2)
    near = (range_m <= reach_m) & (range_m >= geo.min_range_m)
    if sector:  # within the sector, with a cell's slack
        along = d_ne @ (axis / np.hypot(*axis))
        slack = math.sin(half_rad) * np.hypot(d_ne[:, 0], d_ne[:, 1]) + s
        across = np.abs(d_ne @ (np.array([-axis[1], axis[0]]) / np.hypot(*axis)))
        near &= (along > -s) & (across <= slack)
    cells, ne, range_m = cells[near], ne[near], range_m[near]
    points = np.column_stack([ne, np.full(len(ne), floor_down_m)])
    px, inside = camera.project_ned(points, vehicle, r_ned_body)
    # Within the view's undistorted bounds: a strong lens's polynomial folds points far
    # outside the view (beside or under the camera) back into the image.
    rel = (points - centre) @ r_ned_cam
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = np.abs(rel[:, :2] / rel[:, 2:3])
    bound_x, bound_y = _view_bounds(camera)
    inside &= (xy[:, 0] <= bound_x) & (xy[:, 1] <= bound_y)
    k = camera.intrinsics
    m = _EDGE_MARGIN_PX
    inside &= (
        (px[:, 0] >= m - 0.5)
        & (px[:, 0] <= k.width_px - 0.5 - m)
        & (px[:, 1] >= m - 0.5)
        & (px[:, 1] <= k.height_px - 0.5 - m)
    )
    cells, range_m, px = cells[inside], range_m[inside], px[inside]
    p = curve.at(range_m)
    if luma is not None and dark is not None and len(p):
        bu = np.clip((px[:, 0] * luma.shape[1] / k.width_px).astype(int), 0, luma.shape[1] - 1)
        bv = np.clip((px[:, 1] * luma.shape[0] / k.height_px).astype(int), 0, luma.shape[0] - 1)
        lit = np.clip((luma[bv, bu] - DARK_LUMA) / (LIT_LUMA - DARK_LUMA), 0.0, 1.0)
        p = lit * p + (1.0 - lit) * dark.at(range_m)
    return Footprint(cells, p, range_m)


class SharedGrid(CoverageGrid):
    """The service's grid: the processing thread adds looks, the reporter thread reads
    deltas for the HQ (companion/reporting/coverage_sender.py); a lock keeps a delta from
    reading an array that a look is growing. Everything else stays on the processing
    thread."""

    def __init__(self, cell_m: float = 0.25, max_side_cells: int = 1600) -> None:
        super().__init__(cell_m, max_side_cells)
        self._lock = threading.Lock()

    def add_look(self, cells: CellIndex, p: NDArray[np.float64]) -> int:
        with self._lock:
            return super().add_look(cells, p)

    def delta_since(self, version: int) -> CoverageDelta:
        with self._lock:
            return super().delta_since(version)


@dataclass
class _Viewpoint:
    north_m: float
    east_m: float
    yaw_rad: float


@dataclass
class CoverageMapper:
    """The mission's coverage: each camera's frames added to one grid as looks."""

    grid: CoverageGrid
    geo: GeolocationParams
    colour_camera: CameraModel
    thermal_camera: CameraModel | None = None
    colour: DetectionCurve = COLOUR_LIT
    colour_dark: DetectionCurve = COLOUR_DARK
    thermal: DetectionCurve = THERMAL
    min_move_m: float = 0.2
    min_turn_deg: float = 10.0
    _last: dict[Sensor, _Viewpoint] = field(default_factory=dict)

    def add(
        self, pose: PoseSample | None, sensor: Sensor, image: NDArray[np.uint8] | None = None
    ) -> int:
        """Add one processed frame (its pose, None when it had none; the colour
        frame's image for its light). Returns the cells it added (0 for a frame from
        the same viewpoint as the camera's last counted look)."""
        if pose is None or not self.new_viewpoint(pose, sensor):
            return 0
        if sensor == Sensor.THERMAL:
            if self.thermal_camera is None:
                return 0
            look = footprint(self.thermal_camera, pose, self.geo, self.grid, self.thermal)
        else:
            luma = block_luma(image) if image is not None else None
            look = footprint(
                self.colour_camera, pose, self.geo, self.grid, self.colour, luma, self.colour_dark
            )
        self._last[sensor] = _Viewpoint(pose.north_m, pose.east_m, pose.yaw_rad)
        return self.grid.add_look(look.cells, look.p)

    def new_viewpoint(self, pose: PoseSample, sensor: Sensor) -> bool:
        """Whether a look from ``pose`` counts: the first of this camera, or moved or
        turned enough since its last counted look."""
        last = self._last.get(sensor)
        if last is None:
            return True
        moved = math.hypot(pose.north_m - last.north_m, pose.east_m - last.east_m)
        turn = abs((pose.yaw_rad - last.yaw_rad + math.pi) % (2.0 * math.pi) - math.pi)
        return moved >= self.min_move_m or math.degrees(turn) >= self.min_turn_deg


def coverage_document(grid: CoverageGrid) -> dict[str, Any]:
    """The grid for a JSON document (``rescue-companion replay``, docs/REPLAY.md):
    its cells' quantised probabilities (0..255, p = p_q / 255) as one zlib-compressed
    base64 array, rows north from ``origin_index``, and its summary figures."""
    summary = grid.summary()
    return {
        "cell_m": grid.cell_m,
        "origin_index": list(grid.origin_index),
        "shape": list(grid.shape),
        "p_q": base64.b64encode(zlib.compress(grid.quantised().tobytes(), 9)).decode("ascii"),
        "looks": grid.looks,
        "looked_at_m2": round(summary.looked_at_m2, 3),
        "glanced_at_m2": round(summary.glanced_at_m2, 3),
        "searched_well_m2": round(summary.searched_well_m2, 3),
    }


def p_of_document(doc: dict[str, Any]) -> NDArray[np.float64]:
    """The probabilities per cell of a ``coverage_document`` (rows north)."""
    rows, cols = doc["shape"]
    raw = zlib.decompress(base64.b64decode(doc["p_q"]))
    return np.frombuffer(raw, np.uint8).reshape(rows, cols).astype(float) / 255.0
