"""The ``classic`` backend: skin and clothing cues, shape tests and a metric size prior.

Per frame:

1. A working grid (grid.py): columns reduced to ``work_width_px``, rows sampled by
   the floor they span (full resolution where the floor is far and rows are
   precious, merged near the camera), rows above the usable floor dropped.
2. Optional dark-scene enhancement (enhance.py) of the working image.
3. Colour cues (cues.py): skin, and clothing (saturated, or much darker or brighter
   than the local floor).
4. Skin seeds: skin regions on the floor within range, with a body part's floor area
   (a hand's ~0.01 m^2 to a bare torso's 0.3 m^2), extent and thickness, not in a row
   of glyphs (overlay text) and not man-made (rectangle, plank, straight-edged
   polygon), judged on the floor (FrameGeometry.floor_ne_m). Every victim starts
   from a skin seed: coloured debris alone never makes a victim.
5. Body parts: clothing regions on the floor, no larger than ``part_area_max_m2``
   and not man-made.
6. One body, one detection: parts within ``part_gap_m`` of a seed's cluster join it;
   then clusters whose gap on the floor is at most ``seed_gap_m`` merge (a head and
   a hand with grey clothes in between). Every join must keep the cluster a body:
   at most ``body_extent_max_m`` across and ``body_area_max_m2`` on the floor.

The visible area is the frame pixels of the cluster's union mask; its centroid is
the floor-contact pixel. Without a FrameGeometry (photos) the frame is taken to
span ``photo_width_m`` of floor at one scale, so the same metric tests apply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from companion.vision.base import FrameGeometry
from companion.vision.cues import (
    MIN_OUTLINE_PX,
    ColourParams,
    FloorShape,
    Masks,
    colour_masks,
    equivalent_size_m,
    floor_looks_man_made,
    floor_shape,
    region_is_skin,
    skin_pixels,
    text_like_labels,
)
from companion.vision.enhance import Enhancer
from companion.vision.grid import GridParams, WorkGrid, floor_grid, uniform_grid
from fusion.types import Detection

_MIN_REGION_WORK_PX = 4  # smaller regions at working resolution are noise
_MAX_OUTLINE_POINTS = 64  # outlines are subsampled to this many floor points
MIN_RESOLVED_PX = 4.0  # a seed thinner than this (in the pixels it was traced in): no shape


@dataclass(frozen=True)
class ClassicParams:
    work_width_px: int = 320
    row_step_m: float = 0.012  # floor a working row spans near the camera (grid.py)
    max_row_step: int = 4
    colour: ColourParams = field(default_factory=ColourParams)
    skin_area_m2: tuple[float, float] = (0.004, 0.30)  # fingertips+ .. bare torso
    skin_extent_m: tuple[float, float] = (0.06, 0.7)  # longest side: a hand .. a bare arm
    max_row_m: float = 0.1  # a seed where one working row spans more floor is too far
    skin_half_width_m: float = 0.012  # thickest point: a palm is ~0.08 m wide; text strokes
    min_skin_solidity: float = 0.6  # hands, faces, cut limbs are compact; glyphs are not
    part_area_max_m2: float = 0.8  # a clothing region larger than this is not one garment
    body_area_max_m2: float = 1.0  # a whole lying adult is ~0.6 m^2
    body_extent_max_m: float = 2.2  # ... and at most ~2 m long
    part_gap_m: float = 0.12  # clothing this close to a body's parts belongs to it
    seed_gap_m: float = 1.0  # parts of one body are closer than this on the floor
    photo_width_m: float = 4.0  # without geometry: floor the frame is taken to span
    # A body cut by the left, right or bottom frame edge, or so near the bottom edge
    # that its unseen rest could lie below it, has an unknown visible share (and a
    # centroid pulled to the edge): drop it, the views before were whole.
    drop_cut_bodies: bool = True
    body_reach_m: float = 0.85  # half a body: how far the unseen rest could lie


@dataclass
class _Node:
    """A skin seed or a clothing part (or a cluster of them)."""

    labels: list[tuple[int, int]]  # (mask kind 0 skin / 1 cloth, label)
    frame_px: float
    su: float  # sums of frame u and v, weighted by frame pixels
    sv: float
    floor: np.ndarray  # outline points on the floor (M, 2)
    area_m2: float
    seeds: int
    x0: int
    y0: int
    x1: int
    y1: int

    def join(self, other: _Node) -> _Node:
        return _Node(
            self.labels + other.labels,
            self.frame_px + other.frame_px,
            self.su + other.su,
            self.sv + other.sv,
            np.vstack([self.floor, other.floor]),
            self.area_m2 + other.area_m2,
            self.seeds + other.seeds,
            min(self.x0, other.x0),
            min(self.y0, other.y0),
            max(self.x1, other.x1),
            max(self.y1, other.y1),
        )


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
        if self.enhancer is not None:
            small = self.enhancer(small)
            if self.enhancer.last is not None and self.enhancer.last.denoised:
                raw_luma = cv2.GaussianBlur(cv2.medianBlur(raw_luma, 3), (3, 3), 0)
        masks = colour_masks(small, self.params.colour, grid.far_rows, raw_luma)
        ctx = _Frame(self, geometry, grid, masks, image_bgr)
        seeds = ctx.skin_seeds()
        if not seeds:
            return []
        parts = ctx.clothing_parts(seeds)
        victims = ctx.bodies(seeds, parts)
        if self.params.drop_cut_bodies:
            kept = [v for v in victims if not ctx.cut_by_frame(v)]
            if len(kept) < len(victims):
                self._reject("body cut by the frame edge")
            victims = kept
        dets = [ctx.detection(v, t_mono_s) for v in victims]
        return [d for d in dets if d.score >= self.min_score]

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1


class _Frame:
    """The per-frame working state of ClassicDetector."""

    def __init__(
        self,
        det: ClassicDetector,
        geometry: FrameGeometry,
        grid: WorkGrid,
        masks: Masks,
        image_bgr: np.ndarray,
    ) -> None:
        self.det = det
        self.image = image_bgr
        self.p = det.params
        self.geometry = geometry
        self.grid = grid
        self.masks = masks
        self.luma = masks.luma
        self.w_row = grid.px_area_row  # frame pixels per working pixel, per row
        self.u_col, _ = grid.frame_uv(np.arange(grid.work_w), np.zeros(grid.work_w))
        self.area_row, self.row_m = self._floor_per_row()
        self._weights = self._pixel_weights()
        self._edge: np.ndarray | None = None

    # -- per-frame tables ------------------------------------------------------------

    def _floor_per_row(self) -> tuple[np.ndarray, np.ndarray]:
        """Floor m^2 of one working pixel and floor metres one working row spans, per
        working row (at the centre column; NaN where the row is off the floor)."""
        g = self.grid
        ys = np.arange(g.work_h, dtype=np.float64)
        u = np.full(len(ys), (g.frame_w - 1) / 2.0)
        _, v = g.frame_uv(np.zeros(len(ys)), ys)
        half_u, half_v = g.sx / 2.0, g.row_k / 2.0
        pts = np.column_stack([u, v])
        step_u = np.column_stack([half_u + 0 * u, 0 * v])
        step_v = np.column_stack([0 * u, half_v])
        n = len(ys)
        f = self.geometry.floor_ne_m(
            np.vstack([pts + step_u, pts - step_u, pts + step_v, pts - step_v])
        )
        du = f[:n] - f[n : 2 * n]
        dv = f[2 * n : 3 * n] - f[3 * n :]
        area: np.ndarray = np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0])
        return area, np.linalg.norm(dv, axis=1)

    def _pixel_weights(self) -> tuple[np.ndarray, ...]:
        """Per working pixel (raveled): frame pixels, frame u and v times frame pixels,
        floor m^2 (inf off the floor), for bincount sums over components."""
        g = self.grid
        shape = (g.work_h, g.work_w)
        _, v_row = g.frame_uv(np.zeros(1), np.arange(g.work_h))
        w = np.broadcast_to(self.w_row[:, None], shape)
        wu = (self.w_row[:, None] * self.u_col[None, :]).ravel()
        wv = np.broadcast_to((self.w_row * v_row)[:, None], shape).ravel()
        m2 = np.broadcast_to(np.nan_to_num(self.area_row, nan=np.inf)[:, None], shape).ravel()
        return w.ravel(), wu, wv, m2

    # -- regions ---------------------------------------------------------------------

    def _components(
        self, mask: np.ndarray, with_colour: bool = False
    ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        on = np.flatnonzero(mask)  # the masks are sparse: sum over their pixels only
        flat = labels.ravel()[on]
        w_px, wu, wv, m2 = (w[on] for w in self._weights)
        sums = {
            "px": np.bincount(flat, weights=w_px, minlength=n),
            "u": np.bincount(flat, weights=wu, minlength=n),
            "v": np.bincount(flat, weights=wv, minlength=n),
            "m2": np.bincount(flat, weights=m2, minlength=n),
            "n": stats[:, 4].astype(np.float64),
        }
        if with_colour:
            sums["r"] = np.bincount(flat, weights=self.masks.r.ravel()[on], minlength=n)
            sums["g"] = np.bincount(flat, weights=self.masks.g.ravel()[on], minlength=n)
        return labels, stats, sums

    def _node(
        self, kind: int, labels: np.ndarray, stats: np.ndarray, sums: dict[str, np.ndarray], i: int
    ) -> tuple[_Node, np.ndarray, np.ndarray, np.ndarray] | None:
        """Component i's node, its outline's floor points, border flags and pixels."""
        x, y, w, h = (int(v) for v in stats[i][:4])
        roi = (labels[y : y + h, x : x + w] == i).astype(np.uint8)
        contours, _ = cv2.findContours(roi, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not contours:
            return None
        c = max(contours, key=len).reshape(-1, 2)
        if len(c) > _MAX_OUTLINE_POINTS:
            c = c[np.linspace(0, len(c) - 1, _MAX_OUTLINE_POINTS).astype(int)]
        xs, ys = c[:, 0] + x, c[:, 1] + y
        border = (xs == 0) | (ys == 0) | (xs == self.grid.work_w - 1) | (ys == self.grid.work_h - 1)
        u, v = self.grid.frame_uv(xs, ys)
        floor = self.geometry.floor_ne_m(np.column_stack([u, v]))
        node = _Node(
            [(kind, i)],
            float(sums["px"][i]),
            float(sums["u"][i]),
            float(sums["v"][i]),
            floor[np.isfinite(floor).all(axis=1)],
            float(sums["m2"][i]),
            1 if kind == 0 else 0,
            x,
            y,
            x + w,
            y + h,
        )
        return node, floor, border, np.column_stack([xs, ys])

    def _luma_std(self, labels: np.ndarray, n: _Node, i: int) -> float:
        sl = np.s_[n.y0 : n.y1, n.x0 : n.x1]
        return float(self.luma[sl][labels[sl] == i].std())

    # -- skin seeds ------------------------------------------------------------------

    def skin_seeds(self) -> list[_Node]:
        labels, stats, sums = self._components(self.masks.skin, with_colour=True)
        self.skin_labels = labels
        text = self._text_like(labels, stats)
        seeds = []
        lo, hi = self.p.skin_area_m2
        for i in range(1, len(stats)):
            if stats[i][4] < _MIN_REGION_WORK_PX:
                continue
            area = float(sums["m2"][i])
            if not math.isfinite(area):
                self.det._reject("skin off the floor")
                continue
            if not lo <= area <= hi:
                self.det._reject("skin size")
                continue
            if i in text:
                self.det._reject("skin in a line of text")
                continue
            if not self.row_m[int(stats[i][1] + stats[i][3] // 2)] <= self.p.max_row_m:
                self.det._reject("skin too far to judge")
                continue
            n_px = float(sums["n"][i])
            mean_r, mean_g = float(sums["r"][i]) / n_px, float(sums["g"][i]) / n_px
            if not region_is_skin(mean_r, mean_g, self.p.colour, self.masks.background):
                self.det._reject("skin colour only by noise")
                continue
            made = self._node(0, labels, stats, sums, i)
            if made is None:
                continue
            node, floor, border, outline = made
            fine = None
            if max(node.x1 - node.x0, node.y1 - node.y0) < MIN_OUTLINE_PX:
                # Few working pixels: trace it in the frame.
                fine = self._full_res_outline(labels, node, i)
            if fine is not None:
                floor, border, outline = fine
            if self._seed_ok(labels, node, floor_shape(floor, border, outline), i):
                seeds.append(node)
        return seeds

    def _full_res_outline(
        self, labels: np.ndarray, n: _Node, i: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The seed's outline traced in the frame itself (floor points, border flags,
        pixels): at working resolution a small hand is a few pixels, where ellipses
        and rectangles look alike. None when the frame's own pixels do not hold it
        (a dark zone, where only the enhanced working image shows the colour)."""
        g = self.grid
        v0, _ = g.frame_rows(n.y0, n.y1)
        u0, u1 = math.floor(n.x0 * g.sx), min(g.frame_w, math.ceil(n.x1 * g.sx))
        roi = (labels[n.y0 : n.y1, n.x0 : n.x1] == i).astype(np.uint8)
        # The footprint in frame pixels: rows repeated by their step, columns scaled.
        own = np.repeat(roi, g.row_k[n.y0 : n.y1].astype(int), axis=0)
        own = cv2.resize(own, (u1 - u0, own.shape[0]), interpolation=cv2.INTER_NEAREST)
        own = cv2.dilate(own, np.ones((3, 3), np.uint8))
        crop = self.image[v0 : v0 + own.shape[0], u0:u1]
        enh = self.det.enhancer
        if enh is not None and enh.last is not None and enh.last.denoised:
            crop = cv2.GaussianBlur(cv2.medianBlur(crop, 3), (3, 3), 0)  # as enhance does
        skin, *_ = skin_pixels(crop, self.p.colour, self.masks.background)
        raw: np.ndarray = (skin & (own[: crop.shape[0]] > 0)).astype(np.uint8)
        opened: np.ndarray = cv2.morphologyEx(raw, cv2.MORPH_OPEN, np.ones((1, 3), np.uint8))
        mask: np.ndarray = cv2.morphologyEx(opened, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
        if np.count_nonzero(mask) < 0.5 * n.frame_px:
            return None
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        c = max(contours, key=cv2.contourArea).reshape(-1, 2)
        if len(c) > 2 * _MAX_OUTLINE_POINTS:
            c = c[np.linspace(0, len(c) - 1, 2 * _MAX_OUTLINE_POINTS).astype(int)]
        u, v = c[:, 0] + u0, c[:, 1] + v0
        border = (u == 0) | (v == 0) | (u == g.frame_w - 1) | (v == g.frame_h - 1)
        pixels = np.column_stack([u, v]).astype(np.float64)
        return self.geometry.floor_ne_m(pixels), border, pixels

    def _seed_ok(self, labels: np.ndarray, node: _Node, shape: FloorShape | None, i: int) -> bool:
        if shape is None:
            self.det._reject("skin off the floor")
            return False
        lo, hi = self.p.skin_extent_m
        if not lo <= shape.long_m <= hi:
            self.det._reject("skin extent")
            return False
        if shape.short_px < MIN_RESOLVED_PX:
            # A hand at 2-3 m is 2-3 rows tall: every blob that thin is "solid" and
            # "rectangular". Colour, floor size and extent are all that can be judged;
            # the shape is judged when the rover comes nearer.
            return True
        if shape.solidity < self.p.min_skin_solidity:
            self.det._reject("skin fragmented")
            return False
        if self._half_width_m(labels, node, i) < self.p.skin_half_width_m:
            self.det._reject("skin too thin")
            return False
        if floor_looks_man_made(shape, self._luma_std(labels, node, i)):
            self.det._reject("skin looks man-made")
            return False
        return True

    def _text_like(self, labels: np.ndarray, stats: np.ndarray) -> set[int]:
        """Skin components that belong to a line of glyphs. Glyphs of overlay text can
        fall partly in the skin and partly in the clothing colours (anti-aliasing,
        JPEG), so the line is looked for among the components of both together."""
        both = cv2.bitwise_or(self.masks.skin, self.masks.cloth)
        _, u_labels, u_stats, _ = cv2.connectedComponentsWithStats(both, connectivity=8)
        lines = text_like_labels(u_stats)
        if not lines:
            return set()
        out = set()
        for i in range(1, len(stats)):
            x, y = int(stats[i][0]), int(stats[i][1])
            ys, xs = np.nonzero(labels[y : y + int(stats[i][3]), x : x + int(stats[i][2])] == i)
            if len(xs) and int(u_labels[y + ys[0], x + xs[0]]) in lines:
                out.add(i)
        return out

    def _half_width_m(self, labels: np.ndarray, n: _Node, i: int) -> float:
        """Radius of the largest disc inside the region, in floor metres (the working
        pixel's smaller floor side at the region's centre)."""
        roi = (labels[n.y0 : n.y1, n.x0 : n.x1] == i).astype(np.uint8)
        padded = cv2.copyMakeBorder(roi, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        half_px = float(cv2.distanceTransform(padded, cv2.DIST_L2, 3).max())
        u, v = n.su / n.frame_px, n.sv / n.frame_px
        k = float(self.grid.row_k[min(self.grid.work_h - 1, (n.y0 + n.y1) // 2)])
        pts = np.array([[u, v], [u + self.grid.sx, v], [u, v + k]])
        f = self.geometry.floor_ne_m(pts)
        side = min(float(np.linalg.norm(f[1] - f[0])), float(np.linalg.norm(f[2] - f[0])))
        return half_px * side if math.isfinite(side) else 0.0

    # -- clothing --------------------------------------------------------------------

    def _reach(self, seeds: list[_Node]) -> list[tuple[int, int, int, int]]:
        """Working-pixel boxes around each seed that a body through it could cover
        (``body_extent_max_m`` on the floor each way): clothing outside them cannot
        join a victim and is not examined."""
        g = self.grid
        reach = self.p.body_extent_max_m
        cum = np.cumsum(np.nan_to_num(self.row_m, nan=1e3))
        with np.errstate(invalid="ignore", divide="ignore"):
            col_m = self.area_row / self.row_m
        boxes = []
        for n in seeds:
            y = min(g.work_h - 1, (n.y0 + n.y1) // 2)
            rows = np.flatnonzero(np.abs(cum - cum[y]) <= reach)
            cm = float(col_m[y]) if math.isfinite(col_m[y]) and col_m[y] > 0 else 0.0
            dx = g.work_w if cm == 0.0 else math.ceil(reach / cm)
            y0 = int(rows[0]) if len(rows) else n.y0
            y1 = int(rows[-1]) + 1 if len(rows) else n.y1
            boxes.append((n.x0 - dx, min(y0, n.y0), n.x1 + dx, max(y1, n.y1)))
        return boxes

    def clothing_parts(self, seeds: list[_Node]) -> list[_Node]:
        labels, stats, sums = self._components(self.masks.cloth)
        self.cloth_labels = labels
        boxes = self._reach(seeds)
        parts = []
        for i in range(1, len(stats)):
            if stats[i][4] < _MIN_REGION_WORK_PX:
                continue
            x, y, w, h = (int(v) for v in stats[i][:4])
            if not any(
                x < bx1 and x + w > bx0 and y < by1 and y + h > by0 for bx0, by0, bx1, by1 in boxes
            ):
                continue
            area = float(sums["m2"][i])
            if not math.isfinite(area) or area > self.p.part_area_max_m2:
                continue
            made = self._node(1, labels, stats, sums, i)
            if made is None:
                continue
            node, floor, border, outline = made
            if max(w, h) < MIN_OUTLINE_PX / 3:  # a few pixels: no shape to judge
                parts.append(node)
                continue
            shape = floor_shape(floor, border, outline)
            if shape is None:
                continue
            if floor_looks_man_made(shape, self._luma_std(labels, node, i), strict=False):
                self.det._reject("cloth looks man-made")
                continue
            parts.append(node)
        return parts

    # -- one body, one detection -------------------------------------------------------

    @staticmethod
    def _gap_m(a: _Node, b: _Node) -> float:
        if len(a.floor) == 0 or len(b.floor) == 0:
            return math.inf
        d = a.floor[:, None, :] - b.floor[None, :, :]
        return float(np.sqrt((d * d).sum(axis=2).min()))

    def _body_sized(self, n: _Node) -> bool:
        if n.area_m2 > self.p.body_area_max_m2:
            return False
        pts = n.floor
        if len(pts) > 2:
            pts = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
        d = pts[:, None, :] - pts[None, :, :]
        extent = float(np.sqrt((d * d).sum(axis=2).max())) if len(pts) else 0.0
        return extent <= self.p.body_extent_max_m

    def bodies(self, seeds: list[_Node], parts: list[_Node]) -> list[_Node]:
        clusters = list(seeds)
        free = list(parts)
        changed = True
        while changed and free:  # clothing joins the body it touches, transitively
            changed = False
            for part in list(free):
                gaps = [self._gap_m(c, part) for c in clusters]
                j = int(np.argmin(gaps))
                if gaps[j] <= self.p.part_gap_m:
                    joined = clusters[j].join(part)
                    if self._body_sized(joined):
                        clusters[j] = joined
                        free.remove(part)
                        changed = True
        return self._merge(clusters)

    def _merge(self, clusters: list[_Node]) -> list[_Node]:
        """Closest pairs first, while the union is still one body."""
        while len(clusters) > 1:
            best: tuple[float, int, int] | None = None
            for i in range(len(clusters)):
                for j in range(i + 1, len(clusters)):
                    gap = self._gap_m(clusters[i], clusters[j])
                    if gap <= self.p.seed_gap_m and (best is None or gap < best[0]):
                        joined = clusters[i].join(clusters[j])
                        if self._body_sized(joined):
                            best = (gap, i, j)
            if best is None:
                break
            _, i, j = best
            clusters[i] = clusters[i].join(clusters[j])
            del clusters[j]
        return clusters

    def cut_by_frame(self, n: _Node) -> bool:
        """The node touches the left, right or bottom edge of the frame, or a whole body
        lying around it could reach under the bottom edge (within ``body_reach_m`` on
        the floor of its centroid): the rover is about to pass it, and the close view
        shows a head or a hand of a body whose rest is out of the frame. (Beside the
        left and right edges a hand may be all the route ever shows: kept.)"""
        g = self.grid
        if n.x0 <= 0 or n.x1 >= g.work_w or (n.y1 >= g.work_h and g.row_v[-1] >= g.frame_h - 4):
            return True
        centre = self.geometry.floor_ne_m(np.array([[n.su / n.frame_px, n.sv / n.frame_px]]))
        edge = self._edge_floor()
        if not np.isfinite(centre).all() or len(edge) == 0:
            return False
        d = np.sqrt(((edge - centre) ** 2).sum(axis=1)).min()
        return bool(d < self.p.body_reach_m)

    def _edge_floor(self) -> np.ndarray:
        """Floor points of the frame's bottom edge (cached)."""
        if self._edge is None:
            g = self.grid
            u = np.linspace(0, g.frame_w - 1, 32)
            px = np.column_stack([u, np.full_like(u, g.frame_h - 1)])
            f = self.geometry.floor_ne_m(px)
            self._edge = f[np.isfinite(f).all(axis=1)]
        return self._edge

    def detection(self, n: _Node, t_mono_s: float) -> Detection:
        u, v = n.su / n.frame_px, n.sv / n.frame_px
        g = self.grid
        v0, _ = g.frame_rows(n.y0, n.y0 + 1)
        _, v1 = g.frame_rows(n.y1 - 1, n.y1)
        x0 = math.floor(n.x0 * g.sx)
        x1 = min(g.frame_w, math.ceil(n.x1 * g.sx))
        v1 = min(g.frame_h, v1)
        cloth_share = 1.0 - sum(1 for k, _ in n.labels if k == 0) / len(n.labels)
        score = 0.6 + (0.2 if cloth_share > 0.2 else 0.0) + (0.1 if n.seeds >= 2 else 0.0)
        return Detection(
            t_mono_s=t_mono_s,
            u_px=u,
            v_px=v,
            bbox_xywh_px=(x0, v0, max(1, x1 - x0), max(1, v1 - v0)),
            visible_area_px=n.frame_px,
            score=min(0.95, score),
            source="classic",
        )


def equivalent_size(area_px: float, mpp: float) -> float:  # re-export for tools
    return equivalent_size_m(area_px, mpp)
