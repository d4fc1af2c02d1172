"""Frames at the size the camera is configured (and calibrated) for.

The camera model (its intrinsics or calibration file) describes frames of
``camera.width_px`` x ``camera.height_px``; a detection's pixel in a frame of another
size lands somewhere else on the floor. A camera can deliver another size: a USB
camera without the mode asked for, a stream, a video file or a frames folder
recorded at another resolution. Measured on 2026-11-28: the demo's mission replayed
from its frames at 1280x960 with the 640x480 camera found 1 of 3 victims, placed
0.66 m off, and reported 2 false victims, without a word.

A frame of the configured aspect (within 1 %) is resized to the configured size, as
a binned sensor mode is (said once per size). A frame of another aspect cannot be
mapped onto the camera model: CameraError naming both sizes (live, the camera is
then reopened with backoff and its status says why; a replay stops with exit 2).
"""

from __future__ import annotations

import dataclasses
import logging
import math

import cv2

from companion.sources.base import CameraError, Frame, FrameSource

log = logging.getLogger(__name__)

ASPECT_TOLERANCE = 0.01


class SizedSource:
    """``inner``'s frames at ``width_px`` x ``height_px`` (see the module)."""

    def __init__(self, inner: FrameSource, width_px: int, height_px: int) -> None:
        self.name = inner.name
        self.inner = inner
        self._size = (width_px, height_px)
        self._said: set[tuple[int, int]] = set()

    def read(self, timeout_s: float) -> Frame:
        return self.conform(self.inner.read(timeout_s))

    def conform(self, frame: Frame) -> Frame:
        w, h = self._size
        fh, fw = frame.image.shape[:2]
        if (fw, fh) == (w, h):
            return frame
        if not math.isclose(fw / fh, w / h, rel_tol=ASPECT_TOLERANCE):
            raise CameraError(
                f"{self.name}: frames are {fw}x{fh}, the camera is configured for {w}x{h} "
                "(another aspect ratio): set camera.width_px and camera.height_px, and its "
                "calibration, to the camera's frames"
            )
        if (fw, fh) not in self._said:
            self._said.add((fw, fh))
            log.warning(
                "%s: frames are %dx%d, the camera is configured for %dx%d: resized to it",
                self.name,
                fw,
                fh,
                w,
                h,
            )
        shrink = fw > w
        image = cv2.resize(
            frame.image, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
        )
        return dataclasses.replace(frame, image=image)

    def close(self) -> None:
        self.inner.close()
