"""A mission map PNG: the route, and victims coloured by urgency with their
uncertainty ellipses (2 sigma), north up, east right."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from fusion.registry import Victim
from fusion.types import TrackState, Urgency

URGENCY_BGR = {
    Urgency.LIGHT: (60, 170, 40),  # green
    Urgency.MEDIUM: (0, 140, 255),  # orange
    Urgency.CRITICAL: (40, 40, 220),  # red
}
_CANVAS_PX = 900
_MARGIN_PX = 50
_MIN_SPAN_M = 4.0


def draw_mission_map(
    path: Path,
    route_ne_m: Sequence[tuple[float, float]],
    victims: Sequence[Victim],
    truth_ne_m: Sequence[tuple[float, float]] = (),
) -> None:
    """Route, victims and, for simulated missions, the true victims (black crosses)."""
    points = list(route_ne_m) + [(v.north_m, v.east_m) for v in victims] + list(truth_ne_m)
    if points:
        n = np.array([p[0] for p in points])
        e = np.array([p[1] for p in points])
        n0, n1, e0, e1 = n.min() - 1, n.max() + 1, e.min() - 1, e.max() + 1
    else:
        n0, n1, e0, e1 = -2.0, 2.0, -2.0, 2.0
    span_m = max(n1 - n0, e1 - e0, _MIN_SPAN_M)
    scale = (_CANVAS_PX - 2 * _MARGIN_PX) / span_m  # px per metre
    h = int((n1 - n0) * scale) + 2 * _MARGIN_PX
    w = int((e1 - e0) * scale) + 2 * _MARGIN_PX
    img = np.full((max(h, 200), max(w, 300), 3), 250, np.uint8)

    def px(north_m: float, east_m: float) -> tuple[int, int]:
        return (
            int(_MARGIN_PX + (east_m - e0) * scale),
            int(img.shape[0] - _MARGIN_PX - (north_m - n0) * scale),
        )

    # 1 m grid
    for k in range(math.floor(e0), math.ceil(e1) + 1):
        cv2.line(img, px(n0, k), px(n1, k), (225, 225, 225), 1)
    for k in range(math.floor(n0), math.ceil(n1) + 1):
        cv2.line(img, px(k, e0), px(k, e1), (225, 225, 225), 1)
    if len(route_ne_m) > 1:
        pts = np.array([px(n, e) for n, e in route_ne_m], np.int32)
        cv2.polylines(img, [pts], False, (150, 110, 60), 2, cv2.LINE_AA)
        cv2.circle(img, px(*route_ne_m[0]), 6, (150, 110, 60), -1)
    for v in victims:
        colour = URGENCY_BGR[v.urgency]
        (a, b), (_, d) = v.cov_ne_m2
        vals, vecs = np.linalg.eigh(np.array([[a, b], [b, d]]))
        # Axes in pixels (2 sigma); the angle is of the major axis on screen (x east, y south).
        major = vecs[:, 1]
        angle = math.degrees(math.atan2(-major[0], major[1]))
        axes = (
            max(2, int(2 * math.sqrt(vals[1]) * scale)),
            max(2, int(2 * math.sqrt(vals[0]) * scale)),
        )
        centre = px(v.north_m, v.east_m)
        cv2.ellipse(img, centre, axes, angle, 0, 360, colour, 2, cv2.LINE_AA)
        filled = -1 if v.state in (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY) else 2
        cv2.circle(img, centre, 7, colour, filled, cv2.LINE_AA)
        label = f"#{v.victim_id} {v.urgency.name} {v.visibility_pct:.0f}%"
        cv2.putText(
            img,
            label,
            (centre[0] + 10, centre[1] - 8),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5,
            (30, 30, 30),
            1,
            cv2.LINE_AA,
        )
    for true_n, true_e in truth_ne_m:
        cv2.drawMarker(
            img, px(true_n, true_e), (0, 0, 0), cv2.MARKER_TILTED_CROSS, 16, 2, cv2.LINE_AA
        )
    bar_px = int(scale)
    cv2.line(img, (20, img.shape[0] - 20), (20 + bar_px, img.shape[0] - 20), (0, 0, 0), 2)
    cv2.putText(img, "1 m", (20, img.shape[0] - 28), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    x = img.shape[1] - 30
    cv2.arrowedLine(img, (x, 50), (x, 15), (0, 0, 0), 2, tipLength=0.35)
    cv2.putText(img, "N", (x - 6, 68), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 2)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"cannot write {path}")
