"""The ``classic`` backend: skin and clothing colour, shape tests and a metric size prior.

Per frame, at a reduced working resolution (``work_width_px``, default 320;
``work_height_px`` can keep more rows for grazing views):

1. Optional dark-scene enhancement (enhance.py).
2. Colour cues in rg chromaticity (cues.py): a skin mask and a clothing mask.
3. Skin seeds: each skin region must lie on the floor within range (FrameGeometry),
   have the floor size of a body part (a hand's ~0.01 m^2 to a bare torso's ~0.3 m^2)
   and thickness (a palm, not a text stroke), and not look man-made (rectangular,
   straight-edged convex, or flat few-cornered).
   Every detection starts from at least one skin seed: coloured debris alone never
   makes a victim.
4. Clothing regions that look man-made are dropped; the rest join the seeds they
   touch (one body = skin + clothes), unless the joined region is larger than a
   body, in which case the clothing leaked into the background and only the skin
   is kept.
5. Regions closer than ``merge_gap_m`` on the floor merge into one victim (a head
   and two hands with dark clothes in between), so one person gives one detection.

The visible area is the pixel count of skin and clothing of that victim, scaled back
to the frame's resolution; its centroid is the floor-contact pixel.

Without a FrameGeometry (photos, tools) the metric tests become pixel tests:
seeds between ``min_skin_px`` and ``max_region_share`` of the frame, merged within
``merge_gap_rel`` times the larger seed's size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from companion.vision.base import FrameGeometry
from companion.vision.cues import (
    ColourParams,
    Masks,
    Shape,
    colour_masks,
    equivalent_size_m,
    looks_man_made,
    shape_of,
    skin_pixels,
    text_like_labels,
)
from companion.vision.enhance import Enhancer
from fusion.types import Detection

_MIN_REGION_WORK_PX = 6  # smaller regions at working resolution are noise


@dataclass(frozen=True)
class ClassicParams:
    work_width_px: int = 320
    # None: the same reduction as the width. A number (e.g. the frame's height) keeps
    # more rows: a rover's camera sees bodies at a grazing angle, a few rows tall;
    # on the scenario suite full height raised medium recall 0.67 -> 0.78 for 2x cost.
    work_height_px: int | None = None
    colour: ColourParams = field(default_factory=ColourParams)
    skin_area_m2: tuple[float, float] = (0.004, 0.30)  # fingertips+ .. bare torso
    skin_extent_m: tuple[float, float] = (0.06, 1.0)  # longest side of a skin part
    skin_half_width_m: float = 0.012  # thickest point: a palm is ~0.08 m wide; text strokes
    min_half_width_px: float = 3.0  # without geometry: the same in frame pixels
    min_skin_solidity: float = 0.6  # hands, faces, cut limbs are compact; glyphs are not
    body_area_max_m2: float = 1.0  # a whole lying adult is ~0.6 m^2
    body_extent_max_m: float = 2.4
    merge_gap_m: float = 0.5  # parts of one body are closer than this on the floor
    min_skin_px: float = 60.0  # without geometry: smallest skin seed (frame pixels)
    max_region_share: float = 0.3  # without geometry: largest region share of the frame
    merge_gap_rel: float = 2.0  # without geometry: gap, times the larger seed's size


@dataclass
class _Region:
    label: int
    x0: int
    y0: int
    x1: int  # exclusive
    y1: int
    pixels: int
    cx: float
    cy: float


def _regions(mask: np.ndarray) -> tuple[np.ndarray, list[_Region]]:
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    out = []
    for i in range(1, n):
        x, y, w, h, a = (int(v) for v in stats[i])
        if a >= _MIN_REGION_WORK_PX:
            out.append(_Region(i, x, y, x + w, y + h, a, float(cents[i][0]), float(cents[i][1])))
    return labels, out


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

    # -- public ------------------------------------------------------------------

    def detect(
        self, image_bgr: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]:
        h, w = image_bgr.shape[:2]
        work_w = min(w, self.params.work_width_px)
        work_h = self.params.work_height_px or round(h * work_w / w)
        size = (work_w, min(h, work_h))
        small = image_bgr
        if size != (w, h):
            small = cv2.resize(image_bgr, size, interpolation=cv2.INTER_AREA)
        scale = (w / size[0], h / size[1])
        if self.enhancer is not None:
            small = self.enhancer(small)
        masks = colour_masks(small, self.params.colour)
        ctx = _Frame(self, geometry, scale, (w, h), masks, image_bgr)
        seeds_mask, seeds = ctx.skin_seeds(masks.skin)
        if not seeds:
            return []
        cloth = ctx.clean_cloth(masks.cloth)
        groups = ctx.groups(seeds_mask, cloth, seeds)
        victims = ctx.cluster(groups)
        dets = [ctx.detection(v, t_mono_s) for v in victims]
        return [d for d in dets if d.score >= self.min_score]

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1


@dataclass
class _Group:
    pixels: int  # skin + clothing pixels (working resolution)
    skin_pixels: int
    sx: float  # sums of x and y over the pixels
    sy: float
    x0: int
    y0: int
    x1: int
    y1: int
    seeds: int


class _Frame:
    """The per-frame working state of ClassicDetector (kept out of the detector)."""

    def __init__(
        self,
        det: ClassicDetector,
        geometry: FrameGeometry | None,
        scale: tuple[float, float],
        frame_size: tuple[int, int],
        masks: Masks,
        image_bgr: np.ndarray,
    ) -> None:
        self.det = det
        self.p = det.params
        self.geometry = geometry
        self.sx, self.sy = scale
        self.px_area = self.sx * self.sy  # frame pixels per working pixel
        self.frame_w, self.frame_h = frame_size
        self.luma = masks.luma
        self.masks = masks
        self.image = image_bgr
        self.text: set[int] = set()

    def full(self, x: float, y: float) -> tuple[float, float]:
        """Working-resolution pixel centre -> frame pixel."""
        return (x + 0.5) * self.sx - 0.5, (y + 0.5) * self.sy - 0.5

    def mpp(self, x: float, y: float) -> float | None:
        if self.geometry is None:
            return None
        u, v = self.full(x, y)
        return self.geometry.metres_per_px(u, v)

    # -- skin seeds ----------------------------------------------------------------

    def skin_seeds(self, skin: np.ndarray) -> tuple[np.ndarray, list[_Region]]:
        n, labels, stats, cents = cv2.connectedComponentsWithStats(skin, connectivity=8)
        self.text = text_like_labels(stats)
        regions = [
            _Region(i, x, y, x + w, y + h, a, float(cents[i][0]), float(cents[i][1]))
            for i in range(1, n)
            for x, y, w, h, a in [(int(v) for v in stats[i])]
            if a >= _MIN_REGION_WORK_PX
        ]
        keep = np.zeros(labels.max() + 1, np.uint8)
        seeds = []
        for r in regions:
            if self._seed_ok(labels, r):
                keep[r.label] = 255
                seeds.append(r)
        return keep[labels], seeds

    def _seed_ok(self, labels: np.ndarray, r: _Region) -> bool:
        frame_px = r.pixels * self.px_area
        if self.geometry is not None:
            mpp = self.mpp(r.cx, r.cy)
            if mpp is None:
                self.det._reject("skin off the floor")
                return False
            lo, hi = self.p.skin_area_m2
            if not lo <= frame_px * mpp**2 <= hi:
                self.det._reject("skin size")
                return False
        elif not (
            self.p.min_skin_px <= frame_px <= self.p.max_region_share * self.frame_w * self.frame_h
        ):
            self.det._reject("skin size")
            return False
        if r.label in self.text:
            self.det._reject("skin in a line of text")
            return False
        roi = (labels[r.y0 : r.y1, r.x0 : r.x1] == r.label).astype(np.uint8)
        shape = self._full_res_shape(r, roi)
        if shape is None:
            return False
        if shape.solidity < self.p.min_skin_solidity:
            self.det._reject("skin fragmented")
            return False
        if self.geometry is not None:
            mpp = self.mpp(r.cx, r.cy) or 0.0
            extent_m = shape.long_side_px * mpp
            lo, hi = self.p.skin_extent_m
            if not lo <= extent_m <= hi:
                self.det._reject("skin extent")
                return False
        # Thickness: the largest inscribed disc. Overlay text and thin lines have none.
        padded = cv2.copyMakeBorder(roi, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        half_width_work = float(cv2.distanceTransform(padded, cv2.DIST_L2, 3).max())
        half_width_px = half_width_work * min(self.sx, self.sy)
        if self.geometry is not None:
            thick_enough = half_width_px * (self.mpp(r.cx, r.cy) or 0.0) >= self.p.skin_half_width_m
        else:
            thick_enough = half_width_px >= self.p.min_half_width_px
        if not thick_enough:
            self.det._reject("skin too thin")
            return False
        luma_std = float(self.luma[r.y0 : r.y1, r.x0 : r.x1][roi > 0].std())
        if looks_man_made(shape, luma_std):
            self.det._reject("skin looks man-made")
            return False
        return True

    def _full_res_shape(self, r: _Region, roi: np.ndarray) -> Shape | None:
        """The seed's outline measured on the frame itself (small seeds are few pixels
        at working resolution, where rectangles and ellipses look alike)."""
        if self.px_area <= 1.0:
            return shape_of(roi)
        sx, sy = self.sx, self.sy
        x0, y0 = max(0, math.floor(r.x0 * sx) - 2), max(0, math.floor(r.y0 * sy) - 2)
        x1 = min(self.frame_w, math.ceil(r.x1 * sx) + 2)
        y1 = min(self.frame_h, math.ceil(r.y1 * sy) + 2)
        crop = self.image[y0:y1, x0:x1]
        enh = self.det.enhancer
        if enh is not None and enh.last is not None and enh.last.denoised:
            crop = cv2.GaussianBlur(cv2.medianBlur(crop, 3), (3, 3), 0)  # as enhance does
        skin, *_ = skin_pixels(crop, self.p.colour, self.masks.background)
        # Only the part that belongs to this seed (a scaled-up copy of its region).
        own: np.ndarray = cv2.resize(roi, (round((r.x1 - r.x0) * sx), round((r.y1 - r.y0) * sy)))
        own_full: np.ndarray = np.zeros(skin.shape, np.uint8)
        ox, oy = math.floor(r.x0 * sx) - x0, math.floor(r.y0 * sy) - y0
        hh, ww = (
            min(own.shape[0], own_full.shape[0] - oy),
            min(own.shape[1], own_full.shape[1] - ox),
        )
        own_full[oy : oy + hh, ox : ox + ww] = own[:hh, :ww]
        own_full = cv2.dilate(own_full, np.ones((3, 3), np.uint8))
        mask: np.ndarray = (skin & (own_full > 0)).astype(np.uint8)
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        return shape_of(mask)

    # -- clothing ------------------------------------------------------------------

    def clean_cloth(self, cloth: np.ndarray) -> np.ndarray:
        labels, regions = _regions(cloth)
        keep = np.zeros(labels.max() + 1, np.uint8)
        for r in regions:
            roi = (labels[r.y0 : r.y1, r.x0 : r.x1] == r.label).astype(np.uint8)
            shape = shape_of(roi)
            if shape is None:
                continue
            luma_std = float(self.luma[r.y0 : r.y1, r.x0 : r.x1][roi > 0].std())
            if looks_man_made(shape, luma_std):
                self.det._reject("cloth looks man-made")
                continue
            keep[r.label] = 255
        cleaned: np.ndarray = keep[labels]
        return cleaned

    # -- grouping ------------------------------------------------------------------

    def groups(
        self, seeds_mask: np.ndarray, cloth: np.ndarray, seeds: list[_Region]
    ) -> list[_Group]:
        union = cv2.bitwise_or(seeds_mask, cloth)
        bridged = cv2.morphologyEx(
            union, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        )
        labels, regions = _regions(bridged)
        by_label = {r.label: r for r in regions}
        seeds_of: dict[int, list[_Region]] = {}
        for s in seeds:
            ys, xs = np.nonzero(seeds_mask[s.y0 : s.y1, s.x0 : s.x1])
            lab = int(labels[s.y0 + ys[0], s.x0 + xs[0]])
            seeds_of.setdefault(lab, []).append(s)
        out = []
        for lab, members in seeds_of.items():
            region = by_label.get(lab)
            group = self._group(labels, union, seeds_mask, lab, region) if region else None
            if group is None or not self._body_sized(group):
                # Clothing leaked into the background: keep the skin alone.
                for s in members:
                    out.append(self._seed_group(s))
                continue
            group.seeds = len(members)
            out.append(group)
        return out

    def _group(
        self,
        labels: np.ndarray,
        union: np.ndarray,
        skin: np.ndarray,
        lab: int,
        r: _Region,
    ) -> _Group | None:
        sl = np.s_[r.y0 : r.y1, r.x0 : r.x1]
        inside = (labels[sl] == lab) & (union[sl] > 0)
        ys, xs = np.nonzero(inside)
        if len(xs) == 0:
            return None
        skin_px = int(np.count_nonzero(skin[sl][inside]))
        return _Group(
            len(xs),
            skin_px,
            float(xs.sum() + r.x0 * len(xs)),
            float(ys.sum() + r.y0 * len(ys)),
            r.x0,
            r.y0,
            r.x1,
            r.y1,
            0,
        )

    def _seed_group(self, s: _Region) -> _Group:
        return _Group(
            s.pixels, s.pixels, s.cx * s.pixels, s.cy * s.pixels, s.x0, s.y0, s.x1, s.y1, 1
        )

    def _body_sized(self, g: _Group) -> bool:
        frame_px = g.pixels * self.px_area
        if self.geometry is None:
            return frame_px <= self.p.max_region_share * self.frame_w * self.frame_h
        mpp = self.mpp(g.sx / g.pixels, g.sy / g.pixels)
        if mpp is None:
            return False
        extent_m = max((g.x1 - g.x0) * self.sx, (g.y1 - g.y0) * self.sy) * mpp
        return frame_px * mpp**2 <= self.p.body_area_max_m2 and extent_m <= self.p.body_extent_max_m

    # -- one victim, one detection ---------------------------------------------------

    def _gap_ok(self, a: _Group, b: _Group) -> bool:
        dx = max(0, max(a.x0, b.x0) - min(a.x1, b.x1))
        dy = max(0, max(a.y0, b.y0) - min(a.y1, b.y1))
        gap_px = math.hypot(dx * self.sx, dy * self.sy)
        if self.geometry is not None:
            mx = (a.sx / a.pixels + b.sx / b.pixels) / 2.0
            my = (a.sy / a.pixels + b.sy / b.pixels) / 2.0
            mpp = self.mpp(mx, my)
            return mpp is not None and gap_px * mpp <= self.p.merge_gap_m
        size_px = math.sqrt(max(a.pixels, b.pixels) * self.px_area)
        return gap_px <= self.p.merge_gap_rel * size_px

    def cluster(self, groups: list[_Group]) -> list[_Group]:
        """Single-linkage merge of groups that are parts of one body."""
        merged = list(groups)
        changed = True
        while changed and len(merged) > 1:
            changed = False
            for i in range(len(merged)):
                for j in range(i + 1, len(merged)):
                    a, b = merged[i], merged[j]
                    if self._gap_ok(a, b):
                        combined = _Group(
                            a.pixels + b.pixels,
                            a.skin_pixels + b.skin_pixels,
                            a.sx + b.sx,
                            a.sy + b.sy,
                            min(a.x0, b.x0),
                            min(a.y0, b.y0),
                            max(a.x1, b.x1),
                            max(a.y1, b.y1),
                            a.seeds + b.seeds,
                        )
                        if self._body_sized(combined):
                            merged[i] = combined
                            del merged[j]
                            changed = True
                            break
                if changed:
                    break
        return merged

    def detection(self, g: _Group, t_mono_s: float) -> Detection:
        u, v = self.full(g.sx / g.pixels, g.sy / g.pixels)
        sx, sy = self.sx, self.sy
        x0, y0 = math.floor(g.x0 * sx), math.floor(g.y0 * sy)
        x1 = min(self.frame_w, math.ceil(g.x1 * sx))
        y1 = min(self.frame_h, math.ceil(g.y1 * sy))
        cloth_share = 1.0 - g.skin_pixels / g.pixels
        score = 0.6 + (0.2 if cloth_share > 0.2 else 0.0) + (0.1 if g.seeds >= 2 else 0.0)
        return Detection(
            t_mono_s=t_mono_s,
            u_px=u,
            v_px=v,
            bbox_xywh_px=(x0, y0, max(1, x1 - x0), max(1, y1 - y0)),
            visible_area_px=g.pixels * self.px_area,
            score=min(0.95, score),
            source="classic",
        )


def equivalent_size(area_px: float, mpp: float) -> float:  # re-export for tools
    return equivalent_size_m(area_px, mpp)
