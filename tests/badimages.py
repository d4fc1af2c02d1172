"""Damaged images and videos for the input tests: what OpenCV refuses by raising
rather than returning None, and a video whose one frame does not decode."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def huge_jpeg() -> bytes:
    """A whole JPEG (end marker and all) whose header claims 65000 x 65000 pixels:
    cv2.imdecode raises (CV_IO_MAX_IMAGE_PIXELS) instead of returning None."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")  # baseline start-of-frame: length, precision, height, width
    data[sof + 5 : sof + 9] = (65000).to_bytes(2, "big") * 2
    return bytes(data)


def avi_with_a_damaged_frame(path: Path, frames: list[np.ndarray], damaged: int) -> None:
    """An AVI of JPEG frames (MJPG) whose frame ``damaged`` is zeroed: OpenCV fails to
    read that frame alone and reads the ones after it."""
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (w, h))
    for f in frames:
        writer.write(f)
    writer.release()
    data = bytearray(path.read_bytes())
    starts = [i for i in range(len(data) - 1) if data[i : i + 2] == b"\xff\xd8"]
    assert len(starts) == len(frames)  # one JPEG per frame
    end = starts[damaged + 1] - 8 if damaged + 1 < len(starts) else len(data)
    data[starts[damaged] : end] = bytes(end - starts[damaged])
    path.write_bytes(bytes(data))
