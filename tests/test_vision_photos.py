"""Every backend on the real photos of ../shared/data/images (skips without them).

Photos have no pose, so detectors run without a FrameGeometry (pixel-size tests).
The negatives are the false-positive check: grey textures (gravel, brick), thermal
images without people, and an empty room. The classic backend finds victims by skin
and clothing colour, so grey and false-colour thermal pictures must give nothing.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.config import DetectorConfig
from companion.vision.backends import make_detector

GREY_OR_THERMAL_NEGATIVES = [
    "skimage_gravel_gray.png",
    "skimage_brick_gray.png",
    "wm_termografia_building_ir.jpg",
]


def _load(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert image is not None, f"{path} is not readable"
    if image.shape[1] > 960:
        f = 960 / image.shape[1]
        image = cv2.resize(image, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
    return image


@pytest.mark.parametrize("name", GREY_OR_THERMAL_NEGATIVES)
def test_classic_finds_nothing_in_grey_and_thermal_negatives(shared_data: Path, name: str) -> None:
    detector = make_detector(DetectorConfig(backend="classic"))
    assert detector.detect(_load(shared_data / "images" / "negatives" / name), None, 0.0) == []


def test_every_backend_runs_on_every_photo(shared_data: Path) -> None:
    backends = [make_detector(DetectorConfig(backend="classic"))]
    if hasattr(cv2, "HOGDescriptor"):
        backends.append(make_detector(DetectorConfig(backend="hog")))
    paths = sorted(p for p in (shared_data / "images").rglob("*.*") if p.suffix in {".png", ".jpg"})
    assert len(paths) >= 15
    for path in paths[::3]:  # a third of them keeps the default run fast (hog is slow)
        image = _load(path)
        for det in backends:
            for d in det.detect(image, None, 0.0):
                x, y, w, h = d.bbox_xywh_px
                assert x >= 0 and y >= 0 and x + w <= image.shape[1] and y + h <= image.shape[0]
                assert d.visible_area_px <= w * h


def test_hog_finds_the_standing_worker(shared_data: Path) -> None:
    if not hasattr(cv2, "HOGDescriptor"):
        pytest.skip("this OpenCV has no HOGDescriptor")
    image = _load(
        shared_data / "images" / "people_rgb" / "intel_worker_zone_frame030_warehouse.png"
    )
    dets = make_detector(DetectorConfig(backend="hog")).detect(image, None, 0.0)
    assert len(dets) >= 1
