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
- Dark and bright: grey-ish pixels much darker (black, navy, dark trousers, shoes)
  or much brighter (white, dusty clothing) than the floor around them, as a ratio
  to the local floor luma (a block median), so a light zone's level cancels out.
  These only ever extend a body that skin has found; alone they are never a victim.

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
    dark_ratio: float = 0.7  # luma below this share of the local floor's: dark clothing
    bright_ratio: float = 1.5  # luma above this multiple of the local floor's: white clothing
    min_floor_luma: float = 20.0  # local floor darker than this (after enhancement): no cue
    floor_block_px: int = 32  # block of the local floor luma median


@dataclass(frozen=True)
class Background:
    r: float  # the frame's median rg chromaticity
    g: float
    sigma: float  # robust spread of rg around it (1.4826 MAD, larger of r and g)


@dataclass(frozen=True)
class Masks:
    skin: np.ndarray  # uint8 0/255
    cloth: np.ndarray  # uint8 0/255: saturated clothing, dark or bright clothing
    luma: np.ndarray  # uint8
    background: Background
    r: np.ndarray  # rg chromaticity planes (float32)
    g: np.ndarray


def chromaticity(image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(r, g, intensity R+G+B) as float32 planes."""
    f = image_bgr.astype(np.float32)
    b, g, r = cv2.split(f)
    s = b + g + r
    inv = 1.0 / np.maximum(s, 1.0)
    return r * inv, g * inv, s


SKIN_HUE_DEG = (-30.0, 10.0)  # direction from grey in the (r, g) plane
SKIN_SATURATION = (0.035, 0.225)  # distance from grey in the (r, g) plane


def skin_locus(r: np.ndarray, g: np.ndarray, grey_radius: float) -> np.ndarray:
    """Skin chromaticities: a sector around grey in the rg plane.

    With dr = r - 1/3, dg = g - 1/3, skin lies at hue atan2(dg, dr) in [-30, +10] deg
    (reddish-orange, slightly magenta to slightly yellow) and saturation
    hypot(dr, dg) in [0.035, 0.225]: pale skin under white light (~0.05), tan and
    dark skin (~0.1-0.13), saturated brown/sienna skin (~0.17-0.21). Hi-vis orange
    (240, 150, 30) has the hue of skin at 0.24: the upper bound keeps it clothing
    (at 0.26 an orange shirt and the face above it were one skin region). Red paint
    and fabric are more saturated (> 0.3). Wood and cardboard fall inside: shape
    tests have to reject them.
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


def region_is_skin(mean_r: float, mean_g: float, params: ColourParams, bg: Background) -> bool:
    """A region's mean chromaticity is skin and clearly off the floor's (twice the
    per-pixel margin). Sensor noise in a dark zone makes specks whose pixels are
    skin-coloured by chance; their mean falls back towards the floor's colour."""
    r, g = np.array([mean_r]), np.array([mean_g])
    margin = 2.0 * max(params.skin_from_background, params.background_spread_k * bg.sigma)
    off_bg = (mean_r - bg.r) ** 2 + (mean_g - bg.g) ** 2 > margin**2
    return bool(skin_locus(r, g, params.grey_radius)[0]) and off_bg


def skin_pixels(
    image_bgr: np.ndarray,
    params: ColourParams,
    bg: Background,
    planes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(skin bool mask, r, g, lit) for an image or a crop, given the background
    (``planes``: its chromaticity() when already computed)."""
    r, g, s = chromaticity(image_bgr) if planes is None else planes
    lit = s >= params.min_intensity
    margin = max(params.skin_from_background, params.background_spread_k * bg.sigma)
    off_bg = (r - bg.r) ** 2 + (g - bg.g) ** 2 > margin**2
    return skin_locus(r, g, params.grey_radius) & lit & off_bg, r, g, lit


def colour_masks(
    image_bgr: np.ndarray,
    params: ColourParams,
    far_rows: np.ndarray | None = None,
    contrast_luma: np.ndarray | None = None,
) -> Masks:
    """Skin and clothing masks of a (working, enhanced) image.

    ``contrast_luma`` is the luma the dark/bright cue compares with the local floor:
    the image before enhancement (gamma and CLAHE change luma ratios, and the ratio
    is what holds from full light to a dark zone); by default the image's own.
    ``far_rows`` flags rows where a hand is one or two rows tall (grid.py).
    """
    planes = chromaticity(image_bgr)
    r, g, _ = planes
    # The background's chromaticity: the median of a subsample (the floor dominates).
    r_sub, g_sub = r[::4, ::4], g[::4, ::4]
    bg_r, bg_g = float(np.median(r_sub)), float(np.median(g_sub))
    sigma = 1.4826 * max(
        float(np.median(np.abs(r_sub - bg_r))), float(np.median(np.abs(g_sub - bg_g)))
    )
    bg = Background(bg_r, bg_g, sigma)
    skin, r, g, lit = skin_pixels(image_bgr, params, bg, planes)
    sat = np.sqrt((r - GREY_R) ** 2 + (g - GREY_G) ** 2)
    bg_sat = math.hypot(bg_r - GREY_R, bg_g - GREY_G)
    cloth = (
        lit
        & ~skin
        & (sat > max(params.cloth_min_saturation, bg_sat + params.cloth_above_background))
    )
    # The blended rim of saturated clothing on a grey floor (red + grey = a muted
    # orange) has skin's colour: skin right next to clothing counts as clothing rim.
    rim = cv2.dilate(cloth.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    skin &= ~rim
    n = skin.size
    skin_u8: np.ndarray = skin.astype(np.uint8) * 255
    cloth_u8: np.ndarray = cloth.astype(np.uint8) * 255
    # A cue that covers a large share of the frame is the floor or a wall, not a body.
    if np.count_nonzero(cloth) > params.background_share_max * n:
        cloth_u8[:] = 0
    if np.count_nonzero(skin) > params.background_share_max * n:
        skin_u8[:] = 0
    luma = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY)
    raw = luma if contrast_luma is None else contrast_luma
    floor = local_floor_luma(raw, params.floor_block_px)
    lit_floor = floor >= params.min_floor_luma
    lf = raw.astype(np.float32)
    contrast = lit_floor & ((lf < params.dark_ratio * floor) | (lf > params.bright_ratio * floor))
    contrast &= ~skin
    if np.count_nonzero(contrast) <= params.background_share_max * n:
        cloth_u8[contrast] = 255
    skin_u8 = _clean(skin_u8, far_rows)  # noise, thin text strokes
    cloth_u8 = _clean(cloth_u8, far_rows)
    return Masks(skin_u8, cloth_u8, luma, bg, r, g)


def _clean(mask: np.ndarray, far_rows: np.ndarray | None) -> np.ndarray:
    """Opening (specks, thin strokes) then closing, 3x3. In far floor rows a hand or
    a leg is one or two rows tall: there the opening runs along the row only."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    opened = cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)
    if far_rows is not None and far_rows.any():
        wide = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((1, 3), np.uint8))
        opened[far_rows] = wide[far_rows]
    closed: np.ndarray = cv2.morphologyEx(opened, cv2.MORPH_CLOSE, kernel)
    return closed


def local_floor_luma(luma: np.ndarray, block_px: int) -> np.ndarray:
    """The floor's luma around each pixel (float32): medians of block_px blocks,
    a 3x3 median over blocks (a body filling a block does not count), upsampled."""
    h, w = luma.shape
    bh, bw = max(1, h // block_px), max(1, w // block_px)
    crop = luma[: bh * block_px, : bw * block_px] if h >= block_px and w >= block_px else luma
    if crop.shape != (bh * block_px, bw * block_px):
        return np.full((h, w), float(np.median(luma)), np.float32)
    blocks = crop.reshape(bh, block_px, bw, block_px).transpose(0, 2, 1, 3).reshape(bh, bw, -1)
    med = np.median(blocks, axis=2).astype(np.uint8)
    if bh >= 3 and bw >= 3:
        med = cv2.medianBlur(med, 3)
    up: np.ndarray = cv2.resize(med, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    return up


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


@dataclass(frozen=True)
class FloorShape:
    """An outline measured on the floor (metres), parts on the frame border left out."""

    area_m2: float
    long_m: float  # sides of the minimum-area rectangle
    short_m: float
    rect_fill: float  # area / that rectangle's area
    solidity: float  # area / convex hull area
    straight_share: float  # share of the (non-border) outline on long straight runs
    corners: int  # vertices of the polygon approximation
    border_share: float  # share of the outline on the frame border
    long_px: float  # the outline's longest side in the image it was traced in
    short_px: float  # ... and its shortest


def floor_shape(
    floor_pts: np.ndarray, on_border: np.ndarray, outline_px: np.ndarray
) -> FloorShape | None:
    """Shape features of a closed outline given as floor points (N, 2), metres.

    ``on_border`` flags points on the frame's edge: a plank cut by the frame edge is
    still a plank, so edges along the border count neither as straight nor as curved.
    ``outline_px`` is the same outline in the pixels it was traced in (its size says
    whether straight edges can be told from curves at all).
    """
    ok = np.isfinite(floor_pts).all(axis=1)
    pts = floor_pts[ok].astype(np.float32)
    border = on_border[ok]
    if len(pts) < 3:
        return None
    area = float(abs(cv2.contourArea(pts)))
    if area <= 0.0:
        return None
    hull_area = float(cv2.contourArea(cv2.convexHull(pts)))
    (_, _), (w, h), _ = cv2.minAreaRect(pts)
    steps = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    perimeter = float(steps.sum())
    straight_share, corners = _straightness(outline_px[ok].astype(np.float32), border)
    border_len = float(steps[border].sum())
    side_px = cv2.minAreaRect(outline_px.astype(np.float32))[1]
    return FloorShape(
        area_m2=area,
        long_m=float(max(w, h)),
        short_m=float(min(w, h)),
        rect_fill=area / (w * h) if w * h > 0 else 0.0,
        solidity=area / hull_area if hull_area > 0 else 0.0,
        straight_share=straight_share,
        corners=corners,
        border_share=border_len / perimeter if perimeter > 0 else 0.0,
        long_px=float(max(side_px)),
        short_px=float(min(side_px)),
    )


def _straightness(px: np.ndarray, border: np.ndarray) -> tuple[float, int]:
    """(share of the non-border outline on long straight runs, polygon corners),
    measured in the image: a straight edge on the floor is straight in the image
    (perspective keeps lines), and pixel steps are even there, while far floor rows
    are tens of millimetres apart."""
    steps = np.linalg.norm(np.roll(px, -1, axis=0) - px, axis=1)
    perimeter = float(steps.sum())
    idx_approx = _approx_indices(px, max(0.015 * perimeter, 1.0))
    straight = free = 0.0
    n = len(px)
    for a, b in zip(idx_approx, idx_approx[1:] + idx_approx[:1], strict=True):
        idx = np.arange(a, b if b > a else b + n) % n
        length = float(np.linalg.norm(px[b] - px[a]))
        if border[idx].mean() > 0.5:
            continue
        free += length
        if length >= max(perimeter / 6.0, 4.0):
            straight += length
    return (straight / free if free > 0 else 0.0), len(idx_approx)


def _approx_indices(pts: np.ndarray, epsilon: float) -> list[int]:
    """Indices of the polygon approximation's vertices, in outline order."""
    approx = cv2.approxPolyDP(pts.reshape(-1, 1, 2), epsilon, True).reshape(-1, 2)
    # approxPolyDP returns a subset of the points: find their indices.
    d = np.abs(pts[None, :, :] - approx[:, None, :]).sum(axis=2)
    idx = sorted({int(i) for i in d.argmin(axis=1)})
    return idx


def floor_looks_man_made(
    s: FloorShape, luma_std: float, flat_luma_std: float = 6.0, strict: bool = True
) -> bool:
    """Rectangles, planks, straight-edged convex polygons, flat few-cornered shapes,
    judged on the floor (perspective removed; straightness in the image).

    ``strict=False`` (clothing next to skin): only whole rectangles and planks. The
    visible part of a buried torso is cut by the slab's straight edge and is still
    clothing; a board or a sheet lying beside the body is a rectangle of its own.
    """
    if s.rect_fill > 0.88 and s.corners <= 6 and s.border_share < 0.2:
        return True  # a rectangle, at any angle
    if s.long_px < MIN_OUTLINE_PX:
        return False  # too few pixels to tell straight edges from curves
    if s.long_m >= 3.0 * s.short_m and s.straight_share > 0.6 and s.rect_fill > 0.7:
        return True  # a plank or beam: long, thin, straight parallel sides
    if not strict or s.short_px < MIN_OUTLINE_PX / 3:
        # A flat ellipse a few rows tall has nearly straight long sides in pixels.
        return False
    if s.straight_share > 0.8 and s.solidity > 0.9:
        return True  # a convex polygon with long straight edges (slab, piece, triangle)
    if s.straight_share > 0.6 and s.solidity > 0.9 and s.corners <= 6:
        return True  # few corners, mostly straight: a slab's corner, a broken piece
    return s.corners <= 5 and s.solidity > 0.9 and luma_std < flat_luma_std
