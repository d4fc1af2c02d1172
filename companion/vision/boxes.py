"""Shared by the box detectors (dnn, hog): boxes to Detections.

A box detector knows where a person is, not which pixels are body. Its visible
area is the box area times ``fill_ratio`` (a person fills about half of a tight
box: default 0.5), and its floor-contact pixel is the bottom centre for an upright
box (taller than ``upright_aspect`` x its width: a standing or sitting person
touches the floor with the feet) and the box centre otherwise (a lying body).
Boxes whose contact pixel is off the usable floor of the FrameGeometry are dropped.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from companion.vision.base import FrameGeometry
from fusion.types import Detection

UPRIGHT_ASPECT = 1.3


def box_detection(
    box_xywh: tuple[float, float, float, float],
    score: float,
    frame_size: tuple[int, int],
    t_mono_s: float,
    source: str,
    fill_ratio: float,
    geometry: FrameGeometry | None,
) -> Detection | None:
    w_img, h_img = frame_size
    x, y, w, h = box_xywh
    x0, y0 = max(0.0, x), max(0.0, y)
    x1, y1 = min(float(w_img), x + w), min(float(h_img), y + h)
    if x1 - x0 < 1.0 or y1 - y0 < 1.0:
        return None
    u = (x0 + x1) / 2.0
    v = y1 - 0.5 if (y1 - y0) > UPRIGHT_ASPECT * (x1 - x0) else (y0 + y1) / 2.0
    if geometry is not None and geometry.metres_per_px(u, v) is None:
        return None
    bx, by = int(x0), int(y0)
    bw, bh = max(1, round(x1) - bx), max(1, round(y1) - by)
    return Detection(
        t_mono_s=t_mono_s,
        u_px=u,
        v_px=v,
        bbox_xywh_px=(bx, by, bw, bh),
        visible_area_px=(x1 - x0) * (y1 - y0) * fill_ratio,
        score=min(1.0, max(0.0, score)),
        source=source,
    )


def nms_detections(
    boxes_xywh: Sequence[Sequence[float]],
    scores: Sequence[float] | np.ndarray,
    min_score: float,
    nms_iou: float,
    frame_size: tuple[int, int],
    t_mono_s: float,
    source: str,
    fill_ratio: float,
    geometry: FrameGeometry | None,
) -> list[Detection]:
    """Non-maximum suppression (cv2.dnn.NMSBoxes), then one Detection per kept box."""
    boxes = [(float(b[0]), float(b[1]), float(b[2]), float(b[3])) for b in boxes_xywh]
    keep = cv2.dnn.NMSBoxes(boxes, [float(sc) for sc in scores], min_score, nms_iou)
    out = []
    for i in np.asarray(keep, dtype=int).ravel():
        det = box_detection(
            boxes[i], float(scores[i]), frame_size, t_mono_s, source, fill_ratio, geometry
        )
        if det is not None:
            out.append(det)
    return out
