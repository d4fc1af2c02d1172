"""A thermal frame as a picture: false colour (inferno), boxes, a temperature scale.

Used by ``rescue-companion detect --annotate``; the same picture serves as a warm
victim's evidence beside its colour one. Small frames (a Lepton's 160x120) are
enlarged (nearest neighbour: each sensor pixel stays a visible square) so the
labels can be read.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

SCALE_BAR_PX = 70  # the strip on the right with the colour scale and its labels
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def colour_range_c(temps_c: np.ndarray) -> tuple[float, float]:
    """The temperatures mapped to the colour scale's ends: the 1st percentile (a few
    cold pixels do not wash the picture out) to the hottest pixel, at least 2 K apart."""
    lo = float(np.percentile(temps_c, 1.0))
    hi = max(float(temps_c.max()), lo + 2.0)
    return lo, hi


def false_colour(temps_c: np.ndarray, lo_c: float, hi_c: float) -> np.ndarray:
    """BGR uint8, inferno: lo_c and colder black, hi_c and hotter pale yellow."""
    grey = np.clip((temps_c - lo_c) * (255.0 / (hi_c - lo_c)), 0.0, 255.0).astype(np.uint8)
    return cv2.applyColorMap(grey, cv2.COLORMAP_INFERNO)


def _text(img: np.ndarray, text: str, at: tuple[int, int], colour: tuple[int, int, int]) -> None:
    cv2.putText(img, text, at, _FONT, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, at, _FONT, 0.45, colour, 1, cv2.LINE_AA)


def thermal_picture(
    temps_c: np.ndarray,
    boxes: Sequence[tuple[tuple[int, int, int, int], str, tuple[int, int, int]]] = (),
    min_width_px: int = 480,
) -> np.ndarray:
    """The frame in false colour, enlarged to at least ``min_width_px``, with each
    ``(box_xywh_px, label, bgr)`` drawn and a scale bar (°C) on the right."""
    lo, hi = colour_range_c(temps_c)
    picture = false_colour(temps_c, lo, hi)
    h, w = temps_c.shape
    k = max(1, -(-min_width_px // w))  # ceil: whole sensor pixels
    if k > 1:
        picture = cv2.resize(picture, (w * k, h * k), interpolation=cv2.INTER_NEAREST)
    for (x, y, bw, bh), label, colour in boxes:
        p0, p1 = (x * k, y * k), ((x + bw) * k - 1, (y + bh) * k - 1)
        cv2.rectangle(picture, p0, p1, colour, 2)
        ty = p0[1] - 6 if p0[1] > 18 else p1[1] + 16
        _text(picture, label, (p0[0] + 2, ty), colour)
    return np.hstack([picture, _scale_bar(h * k, lo, hi)])


def _scale_bar(height_px: int, lo_c: float, hi_c: float) -> np.ndarray:
    bar = np.zeros((height_px, SCALE_BAR_PX, 3), np.uint8)
    top, bottom = 24, height_px - 12
    ramp = np.linspace(hi_c, lo_c, max(2, bottom - top), dtype=np.float32)[:, None]
    bar[top:bottom, 6:22] = false_colour(np.repeat(ramp, 16, axis=1), lo_c, hi_c)
    for frac in (0.0, 0.5, 1.0):
        y = round(top + frac * (bottom - top - 1))
        _text(
            bar,
            f"{hi_c - frac * (hi_c - lo_c):.1f}",
            (28, min(max(y + 4, 10), height_px - 2)),
            (255, 255, 255),
        )
    _text(bar, "deg C", (6, 14), (255, 255, 255))
    return bar
