"""The ``hog`` backend: OpenCV's HOG + linear SVM people detector (Dalal-Triggs).

Available in OpenCV 4.x (``cv2.HOGDescriptor``); OpenCV 5 removed it, and building
this backend there raises DetectorUnavailable saying so. It finds upright people
(its window is 64 x 128 px: people smaller than ~100 px tall are missed, lying
people mostly too), so on a rescue rover it is a baseline, not the main detector.

The SVM margin ``w`` becomes a score with a logistic, 1 / (1 + exp(-2 w)): margin 0
(the SVM's own boundary) is 0.5.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from companion.vision.base import DetectorUnavailable, FrameGeometry
from companion.vision.boxes import nms_detections
from companion.vision.enhance import Enhancer
from fusion.types import Detection


class HogDetector:
    name = "hog"

    def __init__(
        self,
        min_score: float = 0.5,
        nms_iou: float = 0.45,
        fill_ratio: float = 0.5,
        enhancer: Enhancer | None = None,
        scale_step: float = 1.05,
    ) -> None:
        if not hasattr(cv2, "HOGDescriptor"):
            raise DetectorUnavailable(
                f"detector.backend = 'hog' needs cv2.HOGDescriptor, which OpenCV "
                f"{cv2.__version__} does not have (removed in OpenCV 5); use 'classic' or "
                "'dnn', or install opencv-python-headless<5"
            )
        self.hog = cv2.HOGDescriptor()
        self.hog.setSVMDetector(np.asarray(cv2.HOGDescriptor.getDefaultPeopleDetector()))
        self.min_score = min_score
        self.nms_iou = nms_iou
        self.fill_ratio = fill_ratio
        self.enhancer = enhancer
        self.scale_step = scale_step

    def detect(
        self, image_bgr: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]:
        h, w = image_bgr.shape[:2]
        image = self.enhancer(image_bgr) if self.enhancer is not None else image_bgr
        rects, weights = self.hog.detectMultiScale(
            image, winStride=(8, 8), padding=(8, 8), scale=self.scale_step
        )
        if len(rects) == 0:
            return []
        scores = [1.0 / (1.0 + math.exp(-2.0 * float(wt))) for wt in np.ravel(weights)]
        boxes = [tuple(int(v) for v in r) for r in rects]
        return nms_detections(
            boxes,
            scores,
            self.min_score,
            self.nms_iou,
            (w, h),
            t_mono_s,
            self.name,
            self.fill_ratio,
            geometry,
        )
