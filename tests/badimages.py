"""Encoded images that OpenCV refuses by raising rather than by returning None."""

from __future__ import annotations

import cv2
import numpy as np


def huge_jpeg() -> bytes:
    """A whole JPEG (end marker and all) whose header claims 65000 x 65000 pixels:
    cv2.imdecode raises (CV_IO_MAX_IMAGE_PIXELS) instead of returning None."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")  # baseline start-of-frame: length, precision, height, width
    data[sof + 5 : sof + 9] = (65000).to_bytes(2, "big") * 2
    return bytes(data)
