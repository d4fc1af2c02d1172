"""The ``dnn`` backend: a YOLO-style ONNX person detector through cv2.dnn.

Input: the frame letterboxed into a square of ``input_px`` (aspect kept, padded with
grey 114 as Ultralytics does), RGB, scaled to [0, 1], NCHW.

Outputs understood (``layout``):
- ``yolov8``: [1, 4 + nc, N]: cx, cy, w, h in input pixels, then nc class scores
  (YOLOv8/YOLO11 exports; no objectness);
- ``yolov5``: [1, N, 5 + nc]: cx, cy, w, h, objectness, nc class scores; score =
  objectness x class score (YOLOv5/YOLOv7 exports);
- ``auto``: [1, A, B] with A < B is yolov8, otherwise yolov5 (real models have
  thousands of candidates N and a few dozen channels).

A candidate's score is its best score over ``person_class_ids``; candidates below
``min_score`` are dropped, boxes are mapped back through the letterbox, and
class-agnostic NMS (cv2.dnn.NMSBoxes, ``nms_iou``) keeps one box per person.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from companion.vision.base import DetectorUnavailable, FrameGeometry, VisionError
from companion.vision.boxes import nms_detections
from companion.vision.enhance import Enhancer
from fusion.types import Detection

log = logging.getLogger(__name__)

Layout = Literal["auto", "yolov8", "yolov5"]
PAD_VALUE = 114


@dataclass(frozen=True)
class Letterbox:
    scale: float  # input pixels per frame pixel
    pad_x: float
    pad_y: float

    def to_frame(self, cx: np.ndarray, cy: np.ndarray, w: np.ndarray, h: np.ndarray) -> np.ndarray:
        """(N, 4) x, y, w, h boxes in frame pixels from centre boxes in input pixels."""
        x = (cx - w / 2.0 - self.pad_x) / self.scale
        y = (cy - h / 2.0 - self.pad_y) / self.scale
        boxes: np.ndarray = np.column_stack([x, y, w / self.scale, h / self.scale])
        return boxes


def letterbox(image_bgr: np.ndarray, size_px: int) -> tuple[np.ndarray, Letterbox]:
    h, w = image_bgr.shape[:2]
    scale = min(size_px / w, size_px / h)
    nw, nh = round(w * scale), round(h * scale)
    pad_x, pad_y = (size_px - nw) // 2, (size_px - nh) // 2
    canvas = np.full((size_px, size_px, 3), PAD_VALUE, np.uint8)
    resized = cv2.resize(image_bgr, (nw, nh), interpolation=cv2.INTER_LINEAR)
    canvas[pad_y : pad_y + nh, pad_x : pad_x + nw] = resized
    return canvas, Letterbox(scale, float(pad_x), float(pad_y))


def decode(
    output: np.ndarray,
    layout: Layout,
    person_class_ids: tuple[int, ...],
    min_score: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(centre boxes (N, 4) in input pixels, scores (N,)) above min_score."""
    out = np.asarray(output, dtype=np.float32)
    if out.ndim == 3 and out.shape[0] == 1:
        out = out[0]
    if out.ndim != 2:
        raise VisionError(f"dnn output shape {tuple(output.shape)}: expected [1, A, B]")
    if layout == "auto":
        layout = "yolov8" if out.shape[0] < out.shape[1] else "yolov5"
    if layout == "yolov8":
        rows = out.T  # (N, 4 + nc)
        first_class = 4
        objectness = None
    else:
        rows = out  # (N, 5 + nc)
        first_class = 5
        objectness = rows[:, 4]
    nc = rows.shape[1] - first_class
    bad = [c for c in person_class_ids if not 0 <= c < nc]
    if nc < 1 or bad:
        raise VisionError(
            f"dnn output has {nc} classes ({layout} layout, shape {tuple(output.shape)}); "
            f"person class ids {list(person_class_ids)} do not fit"
        )
    scores = rows[:, [first_class + c for c in person_class_ids]].max(axis=1)
    if objectness is not None:
        scores = scores * objectness
    keep = scores >= min_score
    return rows[keep, :4], scores[keep]


class DnnDetector:
    name = "dnn"

    def __init__(
        self,
        model_path: Path,
        input_px: int = 640,
        person_class_ids: tuple[int, ...] = (0,),
        min_score: float = 0.5,
        nms_iou: float = 0.45,
        layout: Layout = "auto",
        fill_ratio: float = 0.5,
        enhancer: Enhancer | None = None,
    ) -> None:
        if not model_path.is_file():
            raise DetectorUnavailable(f"detector.dnn_model {str(model_path)!r}: no such file")
        try:
            self.net = cv2.dnn.readNetFromONNX(str(model_path))
        except cv2.error as exc:
            first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unreadable"
            raise DetectorUnavailable(
                f"detector.dnn_model {str(model_path)!r}: OpenCV cannot load it as ONNX ({first})"
            ) from None
        self.net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
        self.net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
        self.input_px = input_px
        self.person_class_ids = person_class_ids
        self.min_score = min_score
        self.nms_iou = nms_iou
        self.layout: Layout = layout
        self.fill_ratio = fill_ratio
        self.enhancer = enhancer

    def detect(
        self, image_bgr: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]:
        h, w = image_bgr.shape[:2]
        boxed, lb = letterbox(image_bgr, self.input_px)
        if self.enhancer is not None:
            boxed = self.enhancer(boxed)
        blob = cv2.dnn.blobFromImage(boxed, 1.0 / 255.0, swapRB=True)
        self.net.setInput(blob)
        try:
            output = self.net.forward()
        except cv2.error as exc:
            raise VisionError(f"dnn forward pass failed: {str(exc).strip()}") from None
        centre, scores = decode(output, self.layout, self.person_class_ids, self.min_score)
        if len(scores) == 0:
            return []
        boxes = lb.to_frame(centre[:, 0], centre[:, 1], centre[:, 2], centre[:, 3])
        return nms_detections(
            [tuple(b) for b in boxes],
            scores,
            self.min_score,
            self.nms_iou,
            (w, h),
            t_mono_s,
            self.name,
            self.fill_ratio,
            geometry,
        )
