"""The top-down floor raster of a world: what the camera sees, before perspective.

``FloorRaster`` holds, at ``res_m`` per cell (rows = north, columns = east, cell
centres at ``(i + 0.5) * res_m``):
- ``bgrl``: uint8 (rows, cols, 4): the surface colour (BGR) and the static light
  of the light zones (0..255 = 0..100 %) in the fourth channel;
  Victims are solid bodies drawn by the renderer's 3-D pass (scenarios.solids);
  here each leaves only its contact shadow on the floor, darkest under the body;
- ``pyramid``: coarser copies of ``bgrl`` (area-averaged, 2x per level) so that far,
  minified floor does not alias.

Built once per world, deterministic for the world's seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from scenarios.world import World

DEFAULT_RES_M = 0.005
PYRAMID_LEVELS = 5
_SUPERSAMPLE = 4


@dataclass(frozen=True)
class FloorRaster:
    res_m: float
    bgrl: np.ndarray
    pyramid: tuple[np.ndarray, ...]  # level 0 is bgrl itself


def _to_px(poly_ne: np.ndarray, res_m: float) -> np.ndarray:
    """Polygon in metres -> fixed-point pixel vertices (x = east, y = north), 4 bits."""
    pts = np.column_stack([poly_ne[:, 1] / res_m - 0.5, poly_ne[:, 0] / res_m - 0.5])
    return np.round(pts * 16).astype(np.int32)


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: int) -> np.ndarray:
    """Zero-mean noise of about unit std with features of about cell_px pixels."""
    small = rng.standard_normal(
        (max(2, shape[0] // cell_px + 2), max(2, shape[1] // cell_px + 2))
    ).astype(np.float32)
    big = cv2.resize(small, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return big / max(float(big.std()), 1e-6)


def _floor_texture(
    world: World, rng: np.random.Generator, rows: int, cols: int, res_m: float
) -> np.ndarray:
    base = np.array(world.floor.colour_rgb[::-1], np.float32)
    k = world.floor.texture_contrast
    stains = smooth_noise(rng, (rows, cols), max(2, int(0.6 / res_m)))
    mottle = smooth_noise(rng, (rows, cols), max(2, int(0.08 / res_m)))
    grain = rng.standard_normal((rows, cols)).astype(np.float32)
    shade = 1.0 + k * (0.45 * stains + 0.3 * mottle + 0.25 * grain)
    img = base[None, None, :] * shade[:, :, None]
    # Cracks: thin dark random walks.
    n_cracks = int(world.size_m[0] * world.size_m[1] / 6)
    for _ in range(n_cracks):
        p = rng.uniform([0, 0], [cols, rows])
        pts = [p.copy()]
        ang = rng.uniform(0, 2 * math.pi)
        for _ in range(int(rng.integers(4, 12))):
            ang += rng.normal(0, 0.5)
            p = p + (0.12 / res_m) * np.array([math.cos(ang), math.sin(ang)])
            pts.append(p.copy())
        cv2.polylines(
            img,
            [np.round(np.array(pts)).astype(np.int32)],
            False,
            (base * 0.55).tolist(),
            1,
            cv2.LINE_AA,
        )
    return img


def _paint(
    img: np.ndarray,
    poly_ne: np.ndarray,
    rgb: tuple[int, int, int],
    res_m: float,
    rng: np.random.Generator,
    grain: float,
    edge_dark: float,
) -> None:
    """Fill a polygon with a grainy colour and a darker rim, antialiased.

    The polygon is filled at 4x the raster's resolution and area-averaged into a
    coverage fraction: OpenCV's fill includes both end cells of a span, which
    would shift an object's centroid by up to half a cell.
    """
    ss = _SUPERSAMPLE
    pts = np.column_stack([poly_ne[:, 1] / res_m - 0.5, poly_ne[:, 0] / res_m - 0.5])
    x0 = max(int(np.floor(pts[:, 0].min())) - 2, 0)
    y0 = max(int(np.floor(pts[:, 1].min())) - 2, 0)
    x1 = min(int(np.ceil(pts[:, 0].max())) + 3, img.shape[1])
    y1 = min(int(np.ceil(pts[:, 1].max())) + 3, img.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    h, w = y1 - y0, x1 - x0
    # Cell (i, j) of the patch spans fine cells ss*i .. ss*i + ss - 1.
    fine = (pts - np.array([x0, y0]) + 0.5) * ss - 0.5
    mask = np.zeros((h * ss, w * ss), np.uint8)
    cv2.fillPoly(mask, [np.round(fine * 16).astype(np.int32)], 255, cv2.LINE_8, 4)
    cover = cv2.resize(mask, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    colour = np.array(rgb[::-1], np.float32)
    shade = 1.0 + grain * (
        0.6 * smooth_noise(rng, (h, w), max(2, int(0.05 / res_m)))
        + 0.4 * rng.standard_normal((h, w)).astype(np.float32)
    )
    patch = colour[None, None, :] * shade[:, :, None]
    if edge_dark > 0:
        # A darker rim just inside the edge (the mask minus its erosion: symmetric).
        rim = max(1, round(0.012 / res_m * ss))
        inner = cv2.erode(mask, np.ones((2 * rim + 1, 2 * rim + 1), np.uint8))
        inner_cover = cv2.resize(inner, (w, h), interpolation=cv2.INTER_AREA) / 255.0
        patch *= (1.0 - edge_dark * (1.0 - inner_cover.astype(np.float32)))[:, :, None]
    region = img[y0:y1, x0:x1]
    a = cover[:, :, None]
    region[:] = region * (1.0 - a) + patch * a


def build_raster(world: World, res_m: float = DEFAULT_RES_M) -> FloorRaster:
    """Draw the world top-down (deterministic for world.seed)."""
    rng = np.random.default_rng([world.seed, 0x5CE4E])
    rows = math.ceil(world.size_m[0] / res_m)
    cols = math.ceil(world.size_m[1] / res_m)
    img = _floor_texture(world, rng, rows, cols, res_m)
    shadow = np.zeros((rows, cols), np.float32)
    for v in world.victims:
        for part in v.parts():
            cv2.fillPoly(shadow, [_to_px(part.polygon_ne_m, res_m)], 1.0, cv2.LINE_8, 4)
    if world.victims:
        blur = max(1.0, 0.04 / res_m)
        shadow = np.asarray(cv2.GaussianBlur(shadow, (0, 0), blur), np.float32)
        img *= (1.0 - 0.6 * np.clip(shadow, 0.0, 1.0))[:, :, None]
    for d in world.debris:
        grain = 0.08 if d.kind.startswith("lookalike") else 0.16
        _paint(img, d.polygon, d.colour_rgb, res_m, rng, grain, 0.35)
    n = (np.arange(rows, dtype=np.float32) + 0.5) * res_m
    e = (np.arange(cols, dtype=np.float32) + 0.5) * res_m
    light_small_step = max(1, round(0.05 / res_m))
    ln, le = np.meshgrid(n[::light_small_step], e[::light_small_step], indexing="ij")
    light_small = world.light_at(ln, le).astype(np.float32)
    light: np.ndarray = cv2.resize(light_small, (cols, rows), interpolation=cv2.INTER_LINEAR)
    bgrl = np.empty((rows, cols, 4), np.uint8)
    bgrl[:, :, :3] = np.clip(img, 0, 255).astype(np.uint8)
    bgrl[:, :, 3] = np.clip(light * 255.0 + 0.5, 0, 255).astype(np.uint8)
    pyramid: list[np.ndarray] = [bgrl]
    for _ in range(PYRAMID_LEVELS - 1):
        prev = pyramid[-1]
        pyramid.append(
            cv2.resize(
                prev,
                ((prev.shape[1] + 1) // 2, (prev.shape[0] + 1) // 2),
                interpolation=cv2.INTER_AREA,
            )
        )
    return FloorRaster(res_m, bgrl, tuple(pyramid))


def top_down_bgr(raster: FloorRaster, px_per_m: float, lit: bool = True) -> np.ndarray:
    """A north-up map image (rows flipped so north is at the top)."""
    level = 0
    while level + 1 < len(raster.pyramid) and raster.res_m * 2 ** (level + 1) <= 1.0 / px_per_m:
        level += 1
    src = raster.pyramid[level]
    rows = round(raster.bgrl.shape[0] * raster.res_m * px_per_m)
    cols = round(raster.bgrl.shape[1] * raster.res_m * px_per_m)
    small = cv2.resize(src, (cols, rows), interpolation=cv2.INTER_AREA)
    bgr = small[:, :, :3].astype(np.float32)
    if lit:
        bgr *= 0.25 + 0.75 * small[:, :, 3:4].astype(np.float32) / 255.0
    return np.ascontiguousarray(np.clip(bgr, 0, 255).astype(np.uint8)[::-1])
