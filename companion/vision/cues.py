"""Colour and shape cues of the classic detector (pure functions on small images).

Colour works in normalised rg chromaticity, r = R/(R+G+B), g = G/(R+G+B): it does
not change when the light gets dimmer or the enhancement brightens a pixel, so the
same thresholds hold in a dark zone as in full light. Where R+G+B is small the
ratios are mostly noise, so pixels below ``min_intensity`` carry no colour.

- Skin: a sector of the rg plane around grey (see skin_locus): pale to dark skin
  under white and warm light. (The Soriano et al. skin locus was tried first: it
  cuts off saturated brown skin tones such as (141, 85, 36).)
- Both must differ from the background's chromaticity (the frame's median rg: the
  floor fills most of a rover's view): a beige floor inside the skin locus is not
  skin. Pale skin on a beige floor is then missed: a limit of colour cues.
- Clothing: pixels clearly more saturated (further from grey in rg) than the
  frame's background, and not skin. Grey slabs, concrete and dust never count.

Shape features tell man-made debris (straight-edged, convex, rectangular) from body
parts (rounded, irregular).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

GREY_R = GREY_G = 1.0 / 3.0


@dataclass(frozen=True)
class ColourParams:
    min_intensity: int = 60  # R+G+B below this carries no usable colour
    grey_radius: float = 0.02  # rg distance from grey excluded from skin
    cloth_min_saturation: float = 0.07  # rg distance from grey for clothing
    cloth_above_background: float = 0.04  # ... and this much above the background's
    skin_from_background: float = 0.015  # skin differs at least this much from the floor's rg
    background_spread_k: float = 3.0  # ... and by this many robust sigmas of the floor's rg
    background_share_max: float = 0.35  # a cue covering more of the frame is background


@dataclass(frozen=True)
class Background:
    r: float  # the frame's median rg chromaticity
    g: float
    sigma: float  # robust spread of rg around it (1.4826 MAD, larger of r and g)


@dataclass(frozen=True)
class Masks:
    skin: np.ndarray  # uint8 0/255
    cloth: np.ndarray  # uint8 0/255
    luma: np.ndarray  # uint8
    background: Background


def chromaticity(image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(r, g, intensity R+G+B) as float32 planes."""
    f = image_bgr.astype(np.float32)
    b, g, r = cv2.split(f)
    s = b + g + r
    inv = 1.0 / np.maximum(s, 1.0)
    return r * inv, g * inv, s


SKIN_HUE_DEG = (-30.0, 10.0)  # direction from grey in the (r, g) plane
SKIN_SATURATION = (0.035, 0.26)  # distance from grey in the (r, g) plane


def skin_locus(r: np.ndarray, g: np.ndarray, grey_radius: float) -> np.ndarray:
    """Skin chromaticities: a sector around grey in the rg plane.

    With dr = r - 1/3, dg = g - 1/3, skin lies at hue atan2(dg, dr) in [-30, +10] deg
    (reddish-orange, slightly magenta to slightly yellow) and saturation
    hypot(dr, dg) in [0.035, 0.26]: pale skin under white light (~0.05), tan and
    dark skin (~0.1-0.13), saturated brown/sienna skin in warm light (~0.2). Orange
    and red paint and fabric are more saturated (> 0.3). Wood and cardboard fall
    inside: shape tests have to reject them.
    """
    dr = r - GREY_R
    dg = g - GREY_G
    sat = np.sqrt(dr * dr + dg * dg)
    lo, hi = (math.tan(math.radians(a)) for a in SKIN_HUE_DEG)
    # Hue window for dr > 0: lo * dr <= dg <= hi * dr.
    locus: np.ndarray = (
        (dr > 0.0)
        & (dg >= lo * dr)
        & (dg <= hi * dr)
        & (sat >= max(grey_radius, SKIN_SATURATION[0]))
        & (sat <= SKIN_SATURATION[1])
    )
    return locus


def skin_pixels(
    image_bgr: np.ndarray, params: ColourParams, bg: Background
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(skin bool mask, r, g, lit) for an image or a crop, given the background."""
    r, g, s = chromaticity(image_bgr)
    lit = s >= params.min_intensity
    margin = max(params.skin_from_background, params.background_spread_k * bg.sigma)
    off_bg = (r - bg.r) ** 2 + (g - bg.g) ** 2 > margin**2
    return skin_locus(r, g, params.grey_radius) & lit & off_bg, r, g, lit


def colour_masks(image_bgr: np.ndarray, params: ColourParams) -> Masks:
    r, g, _ = chromaticity(image_bgr)
    # The background's chromaticity: the median of a subsample (the floor dominates).
    r_sub, g_sub = r[::4, ::4], g[::4, ::4]
    bg_r, bg_g = float(np.median(r_sub)), float(np.median(g_sub))
    sigma = 1.4826 * max(
        float(np.median(np.abs(r_sub - bg_r))), float(np.median(np.abs(g_sub - bg_g)))
    )
    bg = Background(bg_r, bg_g, sigma)
    skin, r, g, lit = skin_pixels(image_bgr, params, bg)
    sat = np.sqrt((r - GREY_R) ** 2 + (g - GREY_G) ** 2)
    bg_sat = math.hypot(bg_r - GREY_R, bg_g - GREY_G)
    cloth = (
        lit
        & ~skin
        & (sat > max(params.cloth_min_saturation, bg_sat + params.cloth_above_background))
    )
    n = skin.size
    skin_u8: np.ndarray = skin.astype(np.uint8) * 255
    cloth_u8: np.ndarray = cloth.astype(np.uint8) * 255
    # A cue that covers a large share of the frame is the floor or a wall, not a body.
    if np.count_nonzero(cloth) > params.background_share_max * n:
        cloth_u8[:] = 0
    if np.count_nonzero(skin) > params.background_share_max * n:
        skin_u8[:] = 0
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    skin_u8 = cv2.morphologyEx(skin_u8, cv2.MORPH_OPEN, kernel)  # noise, thin text strokes
    skin_u8 = cv2.morphologyEx(skin_u8, cv2.MORPH_CLOSE, kernel)
    cloth_u8 = cv2.morphologyEx(cloth_u8, cv2.MORPH_OPEN, kernel)
    cloth_u8 = cv2.morphologyEx(cloth_u8, cv2.MORPH_CLOSE, kernel)
    luma = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
    return Masks(skin_u8, cloth_u8, luma, bg)


@dataclass(frozen=True)
class Shape:
    area_px: int
    solidity: float  # area / convex hull area
    rect_fill: float  # area / minimum-area rectangle
    straight_share: float  # share of the outline on straight runs
    corners: int  # vertices of the polygon approximation
    long_side_px: float
    short_side_px: float


def shape_of(mask: np.ndarray) -> Shape | None:
    """Features of the largest outline in a (cropped) binary mask."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    area = float(cv2.contourArea(c))
    if area < 4.0:
        return None
    hull_area = float(cv2.contourArea(cv2.convexHull(c)))
    (_, _), (w, h), _ = cv2.minAreaRect(c)
    perimeter = cv2.arcLength(c, True)
    approx = cv2.approxPolyDP(c, max(1.0, 0.02 * perimeter), True)
    pts = approx.reshape(-1, 2).astype(np.float64)
    seg = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    # A run counts as straight when it is at least 1/8 of the outline and 4 px.
    straight = float(seg[seg >= max(4.0, perimeter / 8.0)].sum())
    return Shape(
        area_px=int(np.count_nonzero(mask)),
        solidity=area / hull_area if hull_area > 0 else 0.0,
        rect_fill=area / (w * h) if w * h > 0 else 0.0,
        straight_share=straight / perimeter if perimeter > 0 else 0.0,
        corners=len(approx),
        long_side_px=max(w, h),
        short_side_px=min(w, h),
    )


MIN_OUTLINE_PX = 24.0  # below this long side, straight runs are pixel artefacts


def looks_man_made(shape: Shape, luma_std: float, flat_luma_std: float = 6.0) -> bool:
    """Rectangles, straight-edged convex polygons and flat few-cornered shapes.

    Measure on the frame's resolution: at a few pixels an ellipse and a rectangle
    look alike, so the straight-run tests need an outline of MIN_OUTLINE_PX.
    """
    if shape.rect_fill > 0.9 and shape.corners <= 6:
        return True  # a rectangle, at any angle
    if shape.long_side_px < MIN_OUTLINE_PX:
        return False
    if shape.solidity > 0.93 and shape.straight_share > 0.85:
        return True  # a convex polygon with long straight edges (slab, plank, triangle)
    return shape.corners <= 5 and shape.solidity > 0.9 and luma_std < flat_luma_std


def text_like_labels(stats: np.ndarray, min_neighbours: int = 2) -> set[int]:
    """Components that sit in a row of similar-height components: a line of text.

    Overlay text breaks into glyphs of one height side by side on one baseline; body
    parts do not line up like that. ``stats`` is connectedComponentsWithStats'.
    """
    boxes = [(i, *(int(v) for v in stats[i][:5])) for i in range(1, len(stats)) if stats[i][4] >= 3]
    text: set[int] = set()
    for i, x, y, w, h, a in boxes:
        row = 0
        for j, xj, yj, wj, hj, aj in boxes:
            # Glyphs of one line: comparable heights and ink (noise specks are not).
            if j == i or not (h / 3.0 <= hj <= 3.0 * h and a / 12.0 <= aj <= 12.0 * a):
                continue
            gap = max(xj - (x + w), x - (xj + wj))
            overlap = min(y + h, yj + hj) - max(y, yj)
            # Side by side, sharing most of the shorter one's rows (one text line).
            if gap <= 1.5 * max(h, hj) and overlap >= 0.6 * min(h, hj):
                row += 1
        if row >= min_neighbours:
            text.add(i)
    return text


def equivalent_size_m(area_px: float, metres_per_px: float) -> float:
    """The side of a square with the same floor area (m)."""
    return math.sqrt(max(area_px, 0.0)) * metres_per_px
