"""The thermal detector: people found by their warmth against the scene.

One frame of temperatures (°C) becomes detections, each a person or a person's
exposed parts:

1. The ambient level is the frame's median temperature (most of a frame is floor,
   walls, debris or water; a person rarely covers half of it). In a stream of frames
   (the rover's camera) it may rise at most ``ambient_rise_k_per_s`` from one frame
   to the next: a person the rover drives up to fills most of the view and lifts the
   median to body temperature, a room does not warm that fast. A pixel is warm when
   it is ``min_contrast_k`` above it: a man in 7 °C water shows at most 27 °C; in a
   heat event a 45 °C background is warmer than the animals in it, which then show
   no warm pixel at all.
2. Warm pixels form clusters (8-connected, at least ``min_blob_px``). A cluster is
   the seed of a person when its warmest pixel is skin: at least ``min_body_c``,
   ``min_peak_contrast_k`` above ambient and not over ``max_skin_c``. Warm clusters
   within ``merge_gap_m`` of a seed (on the floor, ``thermal_group``) join it (a head and two hands out of water are one
   person; the hands in cold water read 14-19 °C). A cluster with a pixel hotter than
   skin is machinery, hot water or a lamp: never a seed, never joined.
3. Each group's size on the floor (from the geometry: the share of a whole lying
   adult's pixels at its floor point, times that adult's 0.57 m²) tells a hand, a
   face, a forearm (``part_max_area_m2``: cue ``warm_part``) from a torso or a
   body; smaller than ``min_area_m2`` or larger than ``max_area_m2`` it is no person.
   Large and flat (over ``flat_min_area_m2`` with a spread under ``flat_std_k``) is a
   heated surface. Less than ``min_floor_share`` of it on the floor (rays above the
   horizon or out of range) is above the floor, where a lying person cannot be.
4. Over frames (``thermal_track``): a find whose excess over ambient keeps falling,
   seen at the same scale, is a warm imprint where a person lay, and is dropped.
   With a geometry, a find larger than a part whose top row meets the floor at a
   point that stays put as the rover moves along the line of sight is warmth flat on
   the floor (floor heating, an imprint), and is dropped, and so are the part-sized
   pieces of it seen after; until the motion has shown its height such a find
   carries the cue ``UNSETTLED`` (no support for a victim in the tracker).

With a geometry a find's floor point is where the warm region meets the floor, not
its centroid: from a camera 0.3 m up, warm skin and clothing 0.2 m above the floor
project far beyond the body (companion/vision/floorpoint.py, ``blob_floor_pixel``:
the near edge and half a body's width; for a lone part, where it meets the floor).

Without a geometry (a photo) sizes are in pixels: a whole lying adult is taken to
cover ``photo_body_share`` of the frame (``expected_area_px``) and the merge gap is
``photo_merge_gap_share`` of its width; a find's pixels count as the share of that
body's floor area (a lying adult's silhouette, 0.57 m²) for the part and flatness
tests. Its largest size is not tested: a photo can be a close-up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from companion.vision.base import DEFAULT_SILHOUETTE_FILL, FrameGeometry, VisionError
from companion.vision.floorpoint import FloorParams, blob_floor_pixel
from companion.vision.thermal_group import group_in_pixels, group_on_floor
from companion.vision.thermal_params import ThermalDetectorParams
from companion.vision.thermal_track import Shape, ThermalMemory, View
from fusion.types import Detection

SOURCE = "thermal"
# The cue of a find larger than a part whose height is not known yet (thermal_track):
# it may be warmth flat on the floor; it gives a tentative victim no support.
UNSETTLED = "warm_unsettled"
# The most of a body a lone warm part (a hand, a face, a forearm) shows.
PART_SHARE_MAX = 0.05
# A whole lying adult's silhouette on the floor (1.7 m x 0.45 m, 3/4 of it filled),
# what a photo's pixel prior stands for.
BODY_AREA_M2 = 1.7 * 0.45 * DEFAULT_SILHOUETTE_FILL


@dataclass(frozen=True)
class ThermalFind:
    """One detection with the temperatures behind it."""

    detection: Detection
    peak_c: float  # the warmest pixel
    mean_c: float  # over its warm pixels
    area_m2: float | None  # on the floor; None without a geometry


@dataclass(frozen=True)
class Rejected:
    """A warm group that is not a person, and why (for benchmarks and --json)."""

    bbox_xywh_px: tuple[int, int, int, int]
    peak_c: float
    reason: str


@dataclass(frozen=True)
class ThermalResult:
    """A frame's ambient level, its finds and the warm groups turned down."""

    ambient_c: float
    min_c: float
    max_c: float
    finds: list[ThermalFind] = field(default_factory=list)
    rejected: list[Rejected] = field(default_factory=list)


def ambient_c(temps_c: np.ndarray) -> float:
    """The frame's background level: the median (of every second pixel and row)."""
    sample = temps_c if temps_c.size <= 5_000 else temps_c[::2, ::2]
    return float(np.median(sample))


class ThermalDetector:
    """Warm regions judged against the scene and the floor; see the module doc."""

    name = SOURCE

    def __init__(self, params: ThermalDetectorParams | None = None, min_score: float = 0.0):
        self.params = params or ThermalDetectorParams()
        self.min_score = min_score
        self.memory = ThermalMemory(self.params)
        self._floor = FloorParams()
        self._ambient: tuple[float, float] | None = None  # (t_mono_s, level °C) of a stream

    def _ambient_c(self, t: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float) -> float:
        """The frame's ambient level; in a stream (frames with a geometry), its rise is
        limited (see the module doc)."""
        median = ambient_c(t)
        if geometry is None:
            return median
        p = self.params
        level = median
        if self._ambient is not None:
            t0, before = self._ambient
            dt = t_mono_s - t0
            if 0.0 <= dt <= p.ambient_reset_s:
                level = min(median, before + p.ambient_rise_k_per_s * dt)
        self._ambient = (t_mono_s, level)
        return level

    def detect(
        self, temps_c: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]:
        return [f.detection for f in self.analyse(temps_c, geometry, t_mono_s).finds]

    def analyse(
        self, temps_c: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> ThermalResult:
        """The frame's finds with their temperatures, and what was turned down."""
        t = np.asarray(temps_c)
        if t.ndim != 2 or t.size == 0 or t.dtype.kind != "f":
            raise VisionError(f"thermal frame must be a 2-D float array, got {t.dtype} {t.shape}")
        p = self.params
        amb = self._ambient_c(t, geometry, t_mono_s)
        result = ThermalResult(amb, float(t.min()), float(t.max()))
        warm = (t >= amb + p.min_contrast_k).astype(np.uint8)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(warm, connectivity=8)
        if n <= 1:
            self.memory.forget(t_mono_s)
            return result
        big = stats[:, cv2.CC_STAT_AREA] >= p.min_blob_px
        # clusters holding a pixel hotter than skin, and clusters holding skin
        hot = np.bincount(labels[t > p.max_skin_c], minlength=n) > 0
        skin_c = max(p.min_body_c, amb + p.min_peak_contrast_k)
        seeds = big & ~hot & (np.bincount(labels[t >= skin_c], minlength=n) > 0)
        seeds[0] = hot[0] = False
        for i in np.flatnonzero(big & hot)[:8].tolist():
            x, y, w, h = _box(stats[i])
            peak = float(t[y : y + h, x : x + w][labels[y : y + h, x : x + w] == i].max())
            result.rejected.append(Rejected((x, y, w, h), peak, "hotter than skin"))
        if not seeds.any():
            self.memory.forget(t_mono_s)
            return result
        groups = self._group(labels, seeds, big & ~hot, geometry)
        for members in groups:
            self._judge(t, labels, stats, members, amb, geometry, t_mono_s, result)
        self.memory.forget(t_mono_s)
        result.finds.sort(key=lambda f: -f.detection.score)
        return result

    def _group(
        self,
        labels: np.ndarray,
        seeds: np.ndarray,
        joinable: np.ndarray,
        geometry: FrameGeometry | None,
    ) -> list[np.ndarray]:
        """Cluster labels per person: each seed with the joinable clusters near it."""
        if geometry is not None:
            gap_m = self.params.merge_gap_m
            return group_on_floor(labels, seeds, joinable, geometry, gap_m)
        gap_px = max(1.0, round(self.params.photo_merge_gap_share * labels.shape[1]))
        return group_in_pixels(labels, seeds, joinable, gap_px)

    def _judge(
        self,
        t: np.ndarray,
        labels: np.ndarray,
        stats: np.ndarray,
        members: np.ndarray,
        amb: float,
        geometry: FrameGeometry | None,
        t_mono_s: float,
        result: ThermalResult,
    ) -> None:
        p = self.params
        x0 = int(stats[members, cv2.CC_STAT_LEFT].min())
        y0 = int(stats[members, cv2.CC_STAT_TOP].min())
        x1 = int((stats[members, cv2.CC_STAT_LEFT] + stats[members, cv2.CC_STAT_WIDTH]).max())
        y1 = int((stats[members, cv2.CC_STAT_TOP] + stats[members, cv2.CC_STAT_HEIGHT]).max())
        box = (x0, y0, x1 - x0, y1 - y0)
        lut = np.zeros(len(stats), bool)
        lut[members] = True
        roi = lut[labels[y0:y1, x0:x1]]
        vs, us = np.nonzero(roi)
        vals = t[y0:y1, x0:x1][roi]
        area_px = float(vals.size)
        peak, mean, spread = float(vals.max()), float(vals.mean()), float(vals.std())
        u, v = float(us.mean() + x0), float(vs.mean() + y0)

        def reject(reason: str) -> None:
            result.rejected.append(Rejected(box, peak, reason))

        area_m2: float | None = None
        expected: float | None = None
        floor_uv: tuple[float, float] | None = None
        if geometry is not None:
            raised = None
            skin = float(np.median(vals)) >= p.raised_skin_c
            if skin and not _on_floor_as_a_person(
                geometry, t, roi, box, area_px, u, v, vs, p, self._floor
            ):
                raised = _raised_part(geometry, box, p, t.shape)
            if raised is not None:
                height_m, floor_uv = raised
                if height_m > p.max_raised_m:
                    return reject(
                        f"{height_m:.1f} m above the floor: higher than debris a person lies under"
                    )
                if floor_uv is None:
                    return reject("above the floor or out of range")
            else:
                on_floor = _floor_share(geometry, u, vs + y0)
                if on_floor < p.min_floor_share or geometry.metres_per_px(u, v) is None:
                    return reject("above the floor or out of range")
                mask = np.zeros(t.shape, bool)
                mask[y0:y1, x0:x1] = roi
                # Its size as the floor area of the share of a lying adult it shows:
                # the pixels a whole body would cover where it lies (a 3-D body's side,
                # as a low camera sees it), not its pixels' floor metres, which a body's
                # upper surface seen near the horizon stretches to metres beyond it.
                floor_uv = blob_floor_pixel(mask, geometry, False, self._floor)
            fu, fv = floor_uv if floor_uv is not None else (u, float(y1) - 0.5)
            whole_px = geometry.expected_body_area_px(fu, fv)
            if whole_px is None:
                return reject("above the floor or out of range")
            area_m2 = area_px / whole_px * BODY_AREA_M2
            if area_m2 < p.min_area_m2:
                return reject(f"{area_m2:.4f} m² is smaller than a hand")
            if area_m2 > p.max_area_m2:
                return reject(f"{area_m2:.2f} m² is larger than a person")
            if area_m2 >= p.flat_min_area_m2 and spread < p.flat_std_k:
                return reject(f"large and flat ({area_m2:.2f} m², spread {spread:.2f} K)")
            # A raised part was placed by a face's or a hand's size: a part. So is a
            # find no longer than a forearm where it lies, whatever its pixels.
            part = (
                raised is not None
                or area_m2 <= p.part_max_area_m2
                or _longest_m(geometry, box, (fu, fv), t.shape) <= p.part_max_extent_m
            )
            key = _floor_key(geometry, u, v)
            in_metres = key is not None
        else:
            if (inward := _cut_sliver_px(box, t.shape, p.photo_min_cut_share)) is not None:
                return reject(f"cut by the photo's edge, {inward} px in view: a sliver")
            expected = p.photo_body_share * t.size
            like_m2 = area_px / expected * BODY_AREA_M2  # the body prior's floor area
            if like_m2 < p.min_area_m2:
                return reject(f"{area_px:.0f} px is smaller than a hand at this prior")
            if like_m2 >= p.flat_min_area_m2 and spread < p.flat_std_k:
                return reject(f"large and flat ({area_px:.0f} px, spread {spread:.2f} K)")
            part = like_m2 <= p.part_max_area_m2
            key, in_metres = None, False
        scale = (geometry.metres_per_px(u, v) if geometry is not None else None) or 1.0
        view = _view(geometry, roi, box) if geometry is not None and in_metres else None
        fading, track = self.memory.observe(
            key or (u, v), in_metres, peak - amb, t_mono_s, scale, view
        )
        if fading:
            return reject("a warm imprint fading towards ambient")
        if view is not None and part and track.flat_seen:
            return reject("a piece of a warm region found flat on the floor before")
        unsettled = False
        if view is not None and not part:
            height = track.height(p)
            if height.shape == Shape.FLAT:
                track.flat_seen = True
                return reject(
                    f"flat on the floor: its far edge stays put as the rover moves "
                    f"({height.moved_m:.1f} m; {100 * (height.height_m or 0.0):.0f} cm high)"
                )
            # Its top row meets the floor and the rover's motion has not shown yet
            # whether it lies flat: found, but no support for confirming a victim.
            unsettled = height.shape == Shape.UNKNOWN and view.top_ne is not None
        score = _score(peak, amb, p)
        if score < self.min_score:
            return reject(f"score {score:.2f} under min_score {self.min_score:.2f}")
        if geometry is not None:
            if part and raised is None:  # a lone part lies where it meets the floor
                mask = np.zeros(t.shape, bool)
                mask[y0:y1, x0:x1] = roi
                floor_uv = blob_floor_pixel(mask, geometry, True, self._floor)
            if floor_uv is not None:
                u, v = floor_uv
        # Seen: bare warmth; heat through thin cover finds a person, it shows none of it.
        seen_px = area_px
        if geometry is not None:
            seen_px = float(np.count_nonzero(vals >= amb + p.bare_min_contrast_k))
        cues = ("warm", "warm_part") if part else ("warm", UNSETTLED) if unsettled else ("warm",)
        det = Detection(
            t_mono_s=t_mono_s,
            u_px=u,
            v_px=v,
            bbox_xywh_px=box,
            visible_area_px=seen_px,
            score=score,
            source=SOURCE,
            cues=cues,
            expected_area_px=expected,
            # A hand or a face alone is a few percent of a body, whatever the pixels
            # around it that its warmth blurs into: CRITICAL (issue 41).
            seen_share_max=PART_SHARE_MAX if part else None,
        )
        result.finds.append(ThermalFind(det, peak, mean, area_m2))


def _cut_sliver_px(
    box: tuple[int, int, int, int], shape: tuple[int, ...], min_share: float
) -> int | None:
    """How far (px) a region cut by the frame's edge reaches into it, when that is
    under ``min_share`` of the frame across that edge; None otherwise."""
    x, y, w, h = box
    height_px, width_px = shape[:2]
    for cut, inward, across in (
        (y <= 0 or y + h >= height_px, h, height_px),
        (x <= 0 or x + w >= width_px, w, width_px),
    ):
        if cut and inward < min_share * across:
            return inward
    return None


def _box(stat: np.ndarray) -> tuple[int, int, int, int]:
    return (int(stat[0]), int(stat[1]), int(stat[2]), int(stat[3]))


def _on_floor_as_a_person(
    geometry: FrameGeometry,
    t: np.ndarray,
    roi: np.ndarray,
    box: tuple[int, int, int, int],
    area_px: float,
    u: float,
    v: float,
    vs: np.ndarray,
    p: ThermalDetectorParams,
    floor: FloorParams,
) -> bool:
    """Whether the region makes sense lying on the floor: its pixels on the floor and
    its size there no larger than a person. Only one that does not is tried as a part
    raised on debris (a face over a slab's edge reads, placed on the floor behind
    it, as metres of warmth, or lies above the horizon)."""
    x0, y0, w, h = box
    if _floor_share(geometry, u, vs + y0) < p.min_floor_share:
        return False
    # A body lying on the floor is no higher than the camera (0.3 m on a rover): a
    # region reaching above the horizon is raised, or no one lying.
    top = geometry.along_ray(np.array([[u, y0 + 0.5]]), 1.0)
    camera = geometry.along_ray(np.array([[u, y0 + 0.5]]), 0.0)
    if top is not None and camera is not None and top[0, 2] > camera[0, 2]:
        return False
    if geometry.metres_per_px(u, v) is None:
        return False
    mask = np.zeros(t.shape, bool)
    mask[y0 : y0 + h, x0 : x0 + w] = roi
    floor_uv = blob_floor_pixel(mask, geometry, False, floor)
    fu, fv = floor_uv if floor_uv is not None else (u, float(y0 + h) - 0.5)
    whole_px = geometry.expected_body_area_px(fu, fv)
    return whole_px is not None and area_px / whole_px * BODY_AREA_M2 <= p.max_area_m2


def _raised_part(
    geometry: FrameGeometry,
    box: tuple[int, int, int, int],
    p: ThermalDetectorParams,
    shape: tuple[int, ...],
) -> tuple[float, tuple[float, float] | None] | None:
    """For a compact region nearer than its floor contact says (see
    ThermalDetectorParams.part_size_m): its bottom's height above the floor and the
    pixel of the floor point below it; None for a region that is not such a part."""
    x, y, w, h = box
    if max(w, h) > p.raised_aspect_max * min(w, h):
        return None  # elongated: a limb along the floor, a pipe
    if _cut_by_frame(box, shape):
        return None  # its size says nothing of its range
    bottom = np.array([[x + 0.5 * w, y + h - 0.5]], np.float64)
    extent_rad = _extent_rad(geometry, box)
    at_1m = geometry.along_ray(bottom, 1.0)
    at_0 = geometry.along_ray(bottom, 0.0)
    if extent_rad is None or at_1m is None or at_0 is None or extent_rad <= 0.0:
        return None
    range_m = p.part_size_m / extent_rad
    camera_m, drop_per_m = float(at_0[0, 2]), float(at_0[0, 2] - at_1m[0, 2])
    floor_range_m = camera_m / drop_per_m if drop_per_m > 1e-6 else math.inf
    if range_m >= _RAISED_MARGIN * floor_range_m:
        return None  # where its floor contact says, or farther: on the floor
    point = geometry.along_ray(bottom, range_m)
    assert point is not None  # the geometry has rays (checked above)
    pixel = geometry.pixels_of_floor(point[:, :2])
    floor_uv = None
    if pixel is not None and np.isfinite(pixel).all():
        floor_uv = (float(pixel[0, 0]), float(pixel[0, 1]))
        if geometry.metres_per_px(*floor_uv) is None:
            floor_uv = None
    return float(point[0, 2]), floor_uv


def _longest_m(
    geometry: FrameGeometry,
    box: tuple[int, int, int, int],
    floor_uv: tuple[float, float],
    shape: tuple[int, ...],
) -> float:
    """A find's longest extent in metres (across or up its box) at the range of where
    it lies; inf for a find cut by the frame (its size is unknown) or off the floor."""
    if _cut_by_frame(box, shape):
        return math.inf
    extent_rad = _extent_rad(geometry, box)
    camera = geometry.along_ray(np.array([floor_uv], np.float64), 0.0)
    floor = geometry.floor_ne_m(np.array([floor_uv], np.float64))
    if extent_rad is None or camera is None or not np.isfinite(floor).all():
        return math.inf
    north_m, east_m = float(floor[0, 0] - camera[0, 0]), float(floor[0, 1] - camera[0, 1])
    return extent_rad * math.sqrt(north_m**2 + east_m**2 + float(camera[0, 2]) ** 2)


def _cut_by_frame(box: tuple[int, int, int, int], shape: tuple[int, ...]) -> bool:
    x, y, w, h = box
    height_px, width_px = shape[:2]
    return x <= 0 or y <= 0 or x + w >= width_px or y + h >= height_px


def _extent_rad(geometry: FrameGeometry, box: tuple[int, int, int, int]) -> float | None:
    """A box's larger angular extent, across or up through its centre (radians: metres
    at 1 m along the rays); None for a geometry without the camera's rays."""
    x, y, w, h = box
    uc, vc = x + 0.5 * w, y + 0.5 * h
    corners = np.array([[x, vc], [x + w, vc], [uc, y], [uc, y + h]], np.float64)
    at_1m = geometry.along_ray(corners, 1.0)
    if at_1m is None:
        return None
    return max(
        float(np.linalg.norm(at_1m[0] - at_1m[1])), float(np.linalg.norm(at_1m[2] - at_1m[3]))
    )


# A part counts as raised when its size puts it nearer than this share of the range
# its floor contact gives (the size prior's own spread: faces and hands differ).
_RAISED_MARGIN = 0.8


def _floor_share(geometry: FrameGeometry, u: float, vs: np.ndarray) -> float:
    """The share of a find's pixels (rows ``vs``) whose rays meet the usable floor,
    by 8-row bands at the find's centre column (FrameGeometry caches per 8x8 cell)."""
    band0 = int(vs.min()) // 8
    counts = np.bincount(vs // 8 - band0)
    on = 0.0
    for i in np.flatnonzero(counts).tolist():
        if geometry.metres_per_px(u, (band0 + i) * 8 + 4.0) is not None:
            on += float(counts[i])
    return on / float(vs.size)


def _view(geometry: FrameGeometry, roi: np.ndarray, box: tuple[int, int, int, int]) -> View | None:
    """The camera's floor position and where the region's top row meets the floor
    (None there when it meets none in range or the frame cuts the region's top)."""
    x0, y0 = box[0], box[1]
    top_u = float(np.flatnonzero(roi[0]).mean()) + x0
    camera = geometry.along_ray(np.array([[top_u, y0 + 0.5]]), 0.0)
    if camera is None:
        return None
    top_ne = _floor_key(geometry, top_u, y0 + 0.5) if y0 > 0 else None
    return View((float(camera[0, 0]), float(camera[0, 1])), float(camera[0, 2]), top_ne)


def _floor_key(geometry: FrameGeometry, u: float, v: float) -> tuple[float, float] | None:
    ne = geometry.floor_ne_m(np.array([[u, v]]))[0]
    return (float(ne[0]), float(ne[1])) if np.isfinite(ne).all() else None


def _score(peak_c: float, amb_c: float, p: ThermalDetectorParams) -> float:
    """Higher the more the warmest part stands out and the more it reads as skin
    (28-37 °C when resolved; smaller or farther parts read cooler)."""
    contrast = min(1.0, (peak_c - amb_c) / (2.0 * p.min_peak_contrast_k))
    skin = 1.0 if 28.0 <= peak_c <= 37.0 else 0.8
    return round(max(0.05, min(1.0, 0.5 + 0.5 * contrast) * skin), 3)
