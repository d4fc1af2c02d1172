"""Synthetic top-down test scenes for the vision self-checks, tests and bench.

A scene is a textured floor seen at a constant scale (``metres_per_px``) with lying
figures drawn from their own polygons in a palette picked from wide ranges of
skin tones and clothing colours, grey slabs over them, debris, overlay text, shading
and sensor noise. The ground truth (each figure's full and visible masks) comes
from the same polygons. These are not the scenarios renderer's pictures: their
colours and shapes are drawn independently, so tuning on one checks the other.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from companion.vision.base import DEFAULT_SILHOUETTE_FILL, FrameGeometry

SKIN_BGR = [  # pale .. dark, under warm and cool light
    (190, 205, 240),
    (150, 175, 225),
    (120, 150, 205),
    (95, 125, 180),
    (70, 95, 140),
    (50, 70, 105),
    (40, 55, 80),
]
CLOTH_BGR = [
    (40, 40, 190),  # red
    (170, 90, 30),  # blue
    (40, 140, 40),  # green
    (30, 190, 220),  # yellow
    (150, 60, 120),  # purple
    (20, 110, 230),  # orange
    (110, 70, 35),  # navy
]


@dataclass
class Figure:
    centre_px: tuple[float, float]
    heading_rad: float
    height_m: float
    skin_bgr: tuple[int, int, int]
    top_bgr: tuple[int, int, int]
    trousers_bgr: tuple[int, int, int]
    full_mask: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    visible_mask: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))

    @property
    def visibility_pct(self) -> float:
        return 100.0 * np.count_nonzero(self.visible_mask) / np.count_nonzero(self.full_mask)

    @property
    def visible_centroid_px(self) -> tuple[float, float]:
        ys, xs = np.nonzero(self.visible_mask)
        return float(xs.mean()), float(ys.mean())


@dataclass
class Scene:
    image: np.ndarray
    metres_per_px: float
    figures: list[Figure]

    @property
    def geometry(self) -> FrameGeometry:
        return FrameGeometry.constant(self.metres_per_px)


def _to_px(points_m: np.ndarray, fig: Figure, mpp: float) -> np.ndarray:
    c, s = math.cos(fig.heading_rad), math.sin(fig.heading_rad)
    rot = np.array([[c, -s], [s, c]])
    xy = points_m @ rot.T / mpp + np.array(fig.centre_px)
    fixed: np.ndarray = np.round(xy * 16).astype(np.int32)  # 4 fractional bits
    return fixed


def _ellipse_m(cx: float, cy: float, ax: float, ay: float, n: int = 20) -> np.ndarray:
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.column_stack([cx + ax * np.cos(t), cy + ay * np.sin(t)])


def _limb_m(x0: float, y0: float, x1: float, y1: float, w0: float, w1: float) -> np.ndarray:
    d = np.array([x1 - x0, y1 - y0])
    n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    a, b = np.array([x0, y0]), np.array([x1, y1])
    return np.array([a + n * w0 / 2, b + n * w1 / 2, b - n * w1 / 2, a - n * w0 / 2])


def figure_parts(h: float) -> list[tuple[str, np.ndarray]]:
    """(role, polygon in metres); x along the body (head at +x), y across it.

    Proportions give a silhouette of ~0.57 m^2 for a 1.7 m adult (arms by the side).
    """
    parts: list[tuple[str, np.ndarray]] = []
    for sy in (1.0, -1.0):
        parts.append(
            (
                "trousers",
                _limb_m(-0.02 * h, sy * 0.05 * h, -0.47 * h, sy * 0.07 * h, 0.095 * h, 0.06 * h),
            )
        )
        parts.append(("shoes", _ellipse_m(-0.49 * h, sy * 0.077 * h, 0.04 * h, 0.03 * h)))
        parts.append(
            ("top", _limb_m(0.30 * h, sy * 0.14 * h, 0.02 * h, sy * 0.18 * h, 0.055 * h, 0.045 * h))
        )
        parts.append(("skin", _ellipse_m(-0.03 * h, sy * 0.185 * h, 0.05 * h, 0.028 * h)))
    torso = (
        np.array(
            [
                [0.32, 0.12],
                [0.35, 0.05],
                [0.35, -0.05],
                [0.32, -0.12],
                [0.0, -0.1],
                [-0.05, -0.1],
                [-0.05, 0.1],
                [0.0, 0.1],
            ]
        )
        * h
    )
    parts.append(("top", torso))
    parts.append(("skin", _ellipse_m(0.43 * h, 0.0, 0.065 * h, 0.05 * h)))
    parts.append(("skin", _limb_m(0.33 * h, 0.0, 0.38 * h, 0.0, 0.05 * h, 0.05 * h)))
    return parts


def floor(
    rng: np.random.Generator, size: tuple[int, int], base_bgr: tuple[int, int, int]
) -> np.ndarray:
    """Concrete-like floor: base colour, blotches and fine grain."""
    w, h = size
    img = np.empty((h, w, 3), np.float32)
    img[:] = base_bgr
    blotch = cv2.resize(rng.normal(0, 12, (h // 16, w // 16)).astype(np.float32), (w, h))
    img += blotch[:, :, None]
    img += rng.normal(0, 5, (h, w, 1)).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


def draw_figure(image: np.ndarray, fig: Figure, mpp: float, rng: np.random.Generator) -> None:
    colours = {
        "skin": fig.skin_bgr,
        "top": fig.top_bgr,
        "trousers": fig.trousers_bgr,
        "shoes": (35, 35, 40),
    }
    full = np.zeros(image.shape[:2], np.uint8)
    for role, poly in figure_parts(fig.height_m):
        pts = _to_px(poly, fig, mpp)
        # Shading: each part a little lighter or darker than its nominal colour.
        tone = np.clip(np.array(colours[role], float) * rng.uniform(0.85, 1.1), 0, 255)
        cv2.fillPoly(image, [pts], tone.tolist(), cv2.LINE_AA, 4)
        cv2.fillPoly(full, [pts], 255, cv2.LINE_8, 4)
    fig.full_mask = full
    fig.visible_mask = full.copy()


def cover(
    image: np.ndarray, figures: list[Figure], poly_px: np.ndarray, bgr: tuple[int, int, int]
) -> None:
    """Lay a slab over everything (figures lose the covered pixels)."""
    pts = np.round(poly_px * 16).astype(np.int32)
    cv2.fillPoly(image, [pts], bgr, cv2.LINE_AA, 4)
    m = np.zeros(image.shape[:2], np.uint8)
    cv2.fillPoly(m, [pts], 255, cv2.LINE_8, 4)
    for f in figures:
        f.visible_mask[m > 0] = 0


def rect_px(cx: float, cy: float, w: float, h: float, angle_deg: float = 0.0) -> np.ndarray:
    return cv2.boxPoints(((cx, cy), (w, h), angle_deg)).astype(np.float64)


def darken(
    image: np.ndarray, factor: float, noise_sigma: float, rng: np.random.Generator
) -> np.ndarray:
    out = image.astype(np.float32) * factor + rng.normal(0, noise_sigma, image.shape).astype(
        np.float32
    )
    dark: np.ndarray = np.clip(out, 0, 255).astype(np.uint8)
    return dark


def make_scene(
    kind: str, seed: int, size: tuple[int, int] = (640, 480), mpp: float = 0.006
) -> Scene:
    """Scenes: full, half, hand, two, debris, text, dark, dark_empty, empty."""
    rng = np.random.default_rng(seed)
    w, h = size
    level = int(rng.integers(90, 150))  # grey to beige or bluish concrete
    tint = rng.integers(-12, 13, 3)
    img = floor(rng, size, (level + int(tint[0]), level + int(tint[1]), level + int(tint[2])))
    figures: list[Figure] = []

    def person(cx: float, cy: float) -> Figure:
        skin = SKIN_BGR[int(rng.integers(len(SKIN_BGR)))]
        top, trousers = (CLOTH_BGR[int(i)] for i in rng.choice(len(CLOTH_BGR), 2, replace=False))
        fig = Figure(
            (cx, cy),
            float(rng.uniform(0, math.pi)),
            float(rng.uniform(1.55, 1.85)),
            skin,
            top,
            trousers,
        )
        draw_figure(img, fig, mpp, rng)
        figures.append(fig)
        return fig

    grey = (int(rng.integers(95, 125)),) * 3
    if kind in ("full", "dark"):
        person(w / 2 + rng.uniform(-40, 40), h / 2 + rng.uniform(-30, 30))
    elif kind == "two":
        person(w * 0.28, h / 2)
        person(w * 0.75, h / 2)
    elif kind == "half":
        fig = person(w / 2, h / 2)
        # A slab over the legs, hips and hands: from the feet to above the navel.
        c, s = math.cos(fig.heading_rad), math.sin(fig.heading_rad)
        L = fig.height_m / mpp
        cx, cy = fig.centre_px[0] - c * 0.25 * L, fig.centre_px[1] - s * 0.25 * L
        cover(img, figures, rect_px(cx, cy, 0.75 * L, 0.5 * L, math.degrees(fig.heading_rad)), grey)
    elif kind == "hand":
        fig = person(w / 2, h / 2)
        c, s = math.cos(fig.heading_rad), math.sin(fig.heading_rad)
        L = fig.height_m / mpp
        # Everything under slabs except one hand (at body x = -0.03 h, y = +0.195 h).
        hx = fig.centre_px[0] + c * (-0.03 * L) - s * (0.185 * L)
        hy = fig.centre_px[1] + s * (-0.03 * L) + c * (0.185 * L)
        ang = math.degrees(fig.heading_rad)
        cover(
            img,
            figures,
            rect_px(
                fig.centre_px[0] + s * 0.05 * L,
                fig.centre_px[1] - c * 0.05 * L,
                1.15 * L,
                0.4 * L,
                ang,
            ),
            grey,
        )
        cover(
            img, figures, rect_px(hx + c * 0.3 * L, hy + s * 0.3 * L, 0.45 * L, 0.12 * L, ang), grey
        )
        cover(
            img,
            figures,
            rect_px(hx - c * 0.35 * L, hy - s * 0.35 * L, 0.5 * L, 0.12 * L, ang),
            grey,
        )
    elif kind == "debris":
        cover(img, figures, rect_px(w * 0.3, h * 0.4, 140, 70, 20), (20, 110, 230))  # orange
        cover(
            img, figures, rect_px(w * 0.7, h * 0.6, 90, 60, -35), (120, 160, 215)
        )  # skin-toned box
        tri = np.array([[w * 0.55, h * 0.15], [w * 0.7, h * 0.3], [w * 0.5, h * 0.33]])
        cover(img, figures, tri, (95, 130, 185))  # skin-toned triangle
        cover(img, figures, rect_px(w * 0.2, h * 0.8, 40, 160, 5), (60, 60, 170))  # red plank
    if kind == "text" or kind in ("debris", "full"):
        cv2.putText(
            img, "CAM1 12:04:33", (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (120, 170, 230), 2
        )
        cv2.putText(img, "REC", (w - 80, h - 15), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (40, 40, 220), 2)
    if kind in ("dark", "dark_empty"):
        img = darken(img, 0.18, 6.0, rng)
    else:
        img = np.clip(img.astype(np.float32) + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)
    return Scene(img, mpp, figures)


EXPECTED_BODY_AREA_M2 = 1.7 * 0.45 * DEFAULT_SILHOUETTE_FILL
