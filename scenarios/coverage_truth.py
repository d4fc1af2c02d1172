"""Which floor cells a simulated camera really saw: the truth the coverage map is scored by.

For a true pose, the renderer's own ray casting (``Solids.trace``: bodies, debris
prisms, warm objects, every pixel of the camera) gives the distance at which each
pixel's ray first meets something. Each floor cell within ``reach_m`` of the camera
is sampled at four points (the centres of its quarters); a point is visible when it
projects into the image and its pixel's ray meets nothing before it (within 5 % +
5 cm: a pixel's floor footprint is longer than that only beyond 7 m). A cell is seen
in a frame when at least ``min_visible_share`` of its points are. Flat debris (under
2 cm, painted on the floor) hides nothing: a person lying on it would show. Cells
off the world's floor are never seen.

``CoverageTruth.frame`` gives those cells and their ranges; the bench
(bench/coverage.py) accumulates them with the same detection curve as the claim,
so the claim and the truth differ by what the camera could not see (what lies
behind tall debris, piles and people, and off the world's floor) and by the cells
the claim counts by their centre alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.camera import CameraModel
from scenarios.render import PoseLike, camera_rays, floor_rays
from scenarios.solids import Solids
from scenarios.world import World


@dataclass(frozen=True)
class SeenCells:
    """The cells (K, 2: floor(north / cell_m), floor(east / cell_m)) a frame really
    saw, and the range (m) from the camera to each cell's nearest seen floor point."""

    cells: NDArray[np.int64]
    range_m: NDArray[np.float64]


class CoverageTruth:
    """The seen floor cells of one world through one camera. Not thread-safe."""

    def __init__(
        self,
        world: World,
        camera: CameraModel,
        cell_m: float = 0.25,
        reach_m: float = 7.5,
        min_visible_share: float = 0.5,
    ) -> None:
        self.camera = camera
        self.world = world
        self.cell_m = cell_m
        self.reach_m = reach_m
        self.min_visible_share = min_visible_share
        self._rays_cam = camera_rays(camera)
        # The largest |x/z| and |y/z| of the image's pixels (undistorted), with 5 %.
        self._bound_xy = 1.05 * np.array(
            [
                np.abs(self._rays_cam[0] / self._rays_cam[2]).max(),
                np.abs(self._rays_cam[1] / self._rays_cam[2]).max(),
            ]
        )
        self._solids = Solids(world, None, camera)

    def frame(self, pose: PoseLike) -> SeenCells:
        _n, _e, t, _sin, rays, centre, r_nc = floor_rays(self.camera, self._rays_cam, pose)
        depth = self._solids.trace(t, centre, r_nc, rays).depth_m
        height = -float(centre[2])
        empty = SeenCells(np.zeros((0, 2), np.int64), np.zeros(0))
        if not 0.0 < height < self.reach_m:
            return empty
        s, (size_n, size_e) = self.cell_m, self.world.size_m
        radius = np.sqrt(self.reach_m**2 - height**2)
        lo = np.maximum(np.floor((centre[:2] - radius) / s), 0).astype(np.int64)
        hi = np.minimum(
            np.floor((centre[:2] + radius) / s), np.array([size_n / s - 1, size_e / s - 1])
        ).astype(np.int64)
        if (hi < lo).any():
            return empty
        nn, ee = np.meshgrid(
            np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij"
        )
        cells = np.column_stack([nn.ravel(), ee.ravel()])
        quarters = np.array([[0.25, 0.25], [0.25, 0.75], [0.75, 0.25], [0.75, 0.75]])
        points = ((cells[:, None, :] + quarters[None, :, :]) * s).reshape(-1, 2)
        d = points - centre[:2]
        dist = np.sqrt((d * d).sum(axis=1) + height**2)
        ned = np.column_stack([points, np.zeros(len(points))])
        rel = (ned - centre) @ r_nc  # the camera frame, z forward
        k = self.camera.intrinsics
        visible = (rel[:, 2] > 1e-3) & (dist <= self.reach_m)
        # Within the view's undistorted bounds: a strong lens's polynomial folds points
        # far outside the view back into the image.
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = np.abs(rel[:, :2] / rel[:, 2:3])
        visible &= (xy[:, 0] <= self._bound_xy[0]) & (xy[:, 1] <= self._bound_xy[1])
        safe = rel.copy()
        safe[~visible, 2] = 1.0
        uv = np.rint(self.camera.project_camera(safe)).astype(np.int64)
        visible &= (uv[:, 0] >= 0) & (uv[:, 0] < k.width_px) & (uv[:, 1] >= 0)
        visible &= uv[:, 1] < k.height_px
        u, v = np.clip(uv[:, 0], 0, k.width_px - 1), np.clip(uv[:, 1], 0, k.height_px - 1)
        visible &= depth[v, u] >= dist * 0.95 - 0.05
        share = visible.reshape(-1, 4).mean(axis=1)
        seen = share >= self.min_visible_share
        near = np.where(visible, dist, np.inf).reshape(-1, 4).min(axis=1)
        return SeenCells(cells[seen], near[seen])
