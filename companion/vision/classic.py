"""The ``classic`` backend: skin and clothing cues, shape tests and a metric size prior.

Per frame:

1. A working grid (grid.py): columns reduced to ``work_width_px``, rows sampled by
   the floor they span (full resolution where the floor is far and rows are
   precious, merged near the camera), rows above the usable floor dropped.
2. Optional dark-scene enhancement (enhance.py) of the working image.
3. Colour cues (cues.py): skin, and clothing (saturated, or much darker or brighter
   than the local floor).
4. Skin seeds (classic_frame.py, as step 5): skin regions on the floor within range,
   with a body part's floor area
   (a hand's ~0.01 m^2 to a bare torso's 0.3 m^2), extent and thickness, not in a row
   of glyphs (overlay text) and not man-made (rectangle, plank, straight-edged
   polygon), judged on the floor (FrameGeometry.floor_ne_m). Every victim starts
   from a skin seed: coloured debris alone never makes a victim.
5. Body parts: clothing regions on the floor, no larger than ``part_area_max_m2``
   and not man-made.
6. One body, one detection (classic_bodies.py): parts within ``part_gap_m`` of a
   seed's cluster join it; then clusters whose gap on the floor is at most ``seed_gap_m`` merge (a head and
   a hand with grey clothes in between). Every join must keep the cluster a body:
   at most ``body_extent_max_m`` across and ``body_area_max_m2`` on the floor.

A body cut by the frame edge is dropped (``drop_cut_bodies``). The visible area is
the frame pixels of the cluster's union mask; its centroid is the floor-contact
pixel (classic_frame.py). Without a FrameGeometry (photos) the frame is taken to
span ``photo_width_m`` of floor at one scale, so the same metric tests apply.
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.vision.base import FrameGeometry
from companion.vision.classic_bodies import bodies
from companion.vision.classic_frame import ClassicFrame
from companion.vision.classic_params import ClassicParams
from companion.vision.cues import colour_masks
from companion.vision.enhance import Enhancer
from companion.vision.grid import GridParams, WorkGrid, floor_grid, uniform_grid
from fusion.types import Detection


class ClassicDetector:
    name = "classic"

    def __init__(
        self,
        params: ClassicParams | None = None,
        enhancer: Enhancer | None = None,
        min_score: float = 0.5,
    ) -> None:
        self.params = params or ClassicParams()
        self.enhancer = enhancer
        self.min_score = min_score
        self.rejected: dict[str, int] = {}  # reason -> count, for diagnostics

    def grid_for(self, frame_w: int, frame_h: int, geometry: FrameGeometry | None) -> WorkGrid:
        p = self.params
        if geometry is None:
            return uniform_grid(frame_w, frame_h, p.work_width_px)
        return floor_grid(
            frame_w, frame_h, geometry, GridParams(p.work_width_px, p.row_step_m, p.max_row_step)
        )

    def detect(
        self, image_bgr: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]:
        h, w = image_bgr.shape[:2]
        grid = self.grid_for(w, h, geometry)
        if geometry is None:
            geometry = FrameGeometry.constant(self.params.photo_width_m / w)
        small = grid.sample(image_bgr)
        raw_luma = cv2.cvtColor(small, cv2.COLOR_BGR2GRAY)
        denoised = False  # the enhancer denoised the working image
        if self.enhancer is not None:
            small = self.enhancer(small)
            denoised = self.enhancer.last is not None and self.enhancer.last.denoised
            if denoised:
                raw_luma = cv2.GaussianBlur(cv2.medianBlur(raw_luma, 3), (3, 3), 0)
        masks = colour_masks(small, self.params.colour, grid.far_rows, raw_luma)
        ctx = ClassicFrame(
            self.params, geometry, grid, masks, image_bgr, denoised=denoised, reject=self._reject
        )
        seeds = ctx.skin_seeds()
        if not seeds:
            return []
        parts = ctx.clothing_parts(seeds)
        victims = bodies(seeds, parts, self.params)
        if self.params.drop_cut_bodies:
            kept = [v for v in victims if not ctx.cut_by_frame(v)]
            if len(kept) < len(victims):
                self._reject("body cut by the frame edge")
            victims = kept
        dets = [ctx.detection(v, t_mono_s) for v in victims]
        return [d for d in dets if d.score >= self.min_score]

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
