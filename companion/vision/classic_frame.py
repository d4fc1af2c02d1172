"""The per-frame work of the classic backend (companion.vision.classic, steps 4 and
5): the skin seeds and clothing parts in the colour masks, measured on the floor;
and, once they are clustered into bodies (classic_bodies.py), whether a body is cut
by the frame edge and its detection."""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np

from companion.vision.base import FrameGeometry
from companion.vision.classic_bodies import Node
from companion.vision.classic_params import ClassicParams
from companion.vision.cues import (
    MIN_OUTLINE_PX,
    FloorShape,
    Masks,
    floor_looks_man_made,
    floor_shape,
    region_is_skin,
    skin_pixels,
    text_like_labels,
)
from companion.vision.grid import WorkGrid
from fusion.types import Detection

_MIN_REGION_WORK_PX = 4  # smaller regions at working resolution are noise
_MAX_OUTLINE_POINTS = 64  # outlines are subsampled to this many floor points
MIN_RESOLVED_PX = 4.0  # a seed thinner than this (in the pixels it was traced in): no shape


class ClassicFrame:
    """The per-frame working state of ClassicDetector: per-row floor tables, the skin
    seeds and clothing parts found in the colour masks, and what becomes of a body
    (cut by the frame edge, or a detection)."""

    def __init__(
        self,
        params: ClassicParams,
        geometry: FrameGeometry,
        grid: WorkGrid,
        masks: Masks,
        image_bgr: np.ndarray,
        *,
        denoised: bool,
        reject: Callable[[str], None],
    ) -> None:
        self.image = image_bgr
        self.p = params
        self.denoised = denoised  # the enhancer denoised the working image
        self.reject = reject  # counts a rejected region by its reason
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
    ) -> tuple[Node, np.ndarray, np.ndarray, np.ndarray] | None:
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
        node = Node(
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

    def _luma_std(self, labels: np.ndarray, n: Node, i: int) -> float:
        sl = np.s_[n.y0 : n.y1, n.x0 : n.x1]
        return float(self.luma[sl][labels[sl] == i].std())

    # -- skin seeds ------------------------------------------------------------------

    def skin_seeds(self) -> list[Node]:
        labels, stats, sums = self._components(self.masks.skin, with_colour=True)
        text = self._text_like(labels, stats)
        seeds = []
        lo, hi = self.p.skin_area_m2
        for i in range(1, len(stats)):
            if stats[i][4] < _MIN_REGION_WORK_PX:
                continue
            area = float(sums["m2"][i])
            if not math.isfinite(area):
                self.reject("skin off the floor")
                continue
            if not lo <= area <= hi:
                self.reject("skin size")
                continue
            if i in text:
                self.reject("skin in a line of text")
                continue
            if not self.row_m[int(stats[i][1] + stats[i][3] // 2)] <= self.p.max_row_m:
                self.reject("skin too far to judge")
                continue
            n_px = float(sums["n"][i])
            mean_r, mean_g = float(sums["r"][i]) / n_px, float(sums["g"][i]) / n_px
            if not region_is_skin(mean_r, mean_g, self.p.colour, self.masks.background):
                self.reject("skin colour only by noise")
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
        self, labels: np.ndarray, n: Node, i: int
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
        if self.denoised:
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

    def _seed_ok(self, labels: np.ndarray, node: Node, shape: FloorShape | None, i: int) -> bool:
        if shape is None:
            self.reject("skin off the floor")
            return False
        lo, hi = self.p.skin_extent_m
        if not lo <= shape.long_m <= hi:
            self.reject("skin extent")
            return False
        if shape.short_px < MIN_RESOLVED_PX:
            # A hand at 2-3 m is 2-3 rows tall: every blob that thin is "solid" and
            # "rectangular". Colour, floor size and extent are all that can be judged;
            # the shape is judged when the rover comes nearer.
            return True
        if shape.solidity < self.p.min_skin_solidity:
            self.reject("skin fragmented")
            return False
        if self._half_width_m(labels, node, i) < self.p.skin_half_width_m:
            self.reject("skin too thin")
            return False
        if floor_looks_man_made(shape, self._luma_std(labels, node, i)):
            self.reject("skin looks man-made")
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

    def _half_width_m(self, labels: np.ndarray, n: Node, i: int) -> float:
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

    def _reach(self, seeds: list[Node]) -> list[tuple[int, int, int, int]]:
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

    def clothing_parts(self, seeds: list[Node]) -> list[Node]:
        labels, stats, sums = self._components(self.masks.cloth)
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
                self.reject("cloth looks man-made")
                continue
            parts.append(node)
        return parts

    # -- a body in the frame -----------------------------------------------------------

    def cut_by_frame(self, n: Node) -> bool:
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

    def detection(self, n: Node, t_mono_s: float) -> Detection:
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
