"""Cameras and files read through OpenCV's VideoCapture.

- ``LiveCaptureSource``: a V4L2 device (index or /dev/videoN), a GStreamer pipeline
  (needs an OpenCV built with GStreamer; the pip wheels are not) or a network URL
  (RTSP/HTTP through FFmpeg). Frames are stamped when the driver hands them over.
- ``VideoFileSource``: a video file, read as fast as asked. Its capture times are
  synthetic: the time of opening plus ``index / fps`` (the file's frame rate, or the
  configured one when the file has none), on both clocks.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path

import cv2
import numpy as np

from companion.sources.base import CameraError, EndOfStream, Frame, ThreadedSource

log = logging.getLogger(__name__)


def _has_backend(name: str) -> bool:
    for line in cv2.getBuildInformation().splitlines():
        key, _, value = line.partition(":")
        if key.strip() == name:
            return value.strip().upper().startswith("YES")
    return False


def _as_bgr(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image


class LiveCaptureSource(ThreadedSource[np.ndarray]):
    """A live camera behind cv2.VideoCapture, grabbed on a background thread."""

    def __init__(
        self,
        name: str,
        target: int | str,
        api: int,
        width_px: int = 0,
        height_px: int = 0,
        fps: float = 0.0,
    ) -> None:
        super().__init__(name)
        if api == cv2.CAP_GSTREAMER and not _has_backend("GStreamer"):
            raise CameraError(
                f"{name}: this OpenCV ({cv2.__version__}) is built without GStreamer; "
                "use Raspberry Pi OS's python3-opencv, or source = 'picamera2' for a Pi camera"
            )
        self._cap = cv2.VideoCapture(target, api)
        if not self._cap.isOpened():
            self._cap.release()
            raise CameraError(f"{name}: cannot open (no such device, or it is busy)")
        if api == cv2.CAP_V4L2:
            if width_px and height_px:
                self._cap.set(cv2.CAP_PROP_FRAME_WIDTH, width_px)
                self._cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height_px)
            if fps:
                self._cap.set(cv2.CAP_PROP_FPS, fps)
            self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # keep the driver queue short
        self._start()

    def _grab(self) -> tuple[np.ndarray, float, float]:
        ok, image = self._cap.read()
        t_mono_s, t_unix_s = time.monotonic(), time.time()
        if not ok or image is None:
            raise CameraError(f"{self.name}: the device stopped delivering frames")
        return image, t_mono_s, t_unix_s

    def _decode(self, payload: np.ndarray) -> np.ndarray | None:
        if payload.dtype != np.uint8 or payload.ndim not in (2, 3):
            return None
        return _as_bgr(payload)

    def _release(self) -> None:
        self._cap.release()


class VideoFileSource:
    """A video file; EndOfStream after its last frame."""

    def __init__(self, path: Path, fallback_fps: float) -> None:
        self.name = f"file:{path}"
        if not path.is_file():
            raise CameraError(f"{self.name}: no such file")
        self._cap = cv2.VideoCapture(str(path))
        if not self._cap.isOpened():
            self._cap.release()
            raise CameraError(f"{self.name}: not a video OpenCV can read")
        fps = float(self._cap.get(cv2.CAP_PROP_FPS))
        self.fps = fps if math.isfinite(fps) and fps > 0.0 else fallback_fps
        self._t0_mono_s = time.monotonic()
        self._t0_unix_s = time.time()
        self._index = 0
        self._closed = False

    def read(self, timeout_s: float) -> Frame:
        if self._closed:
            raise CameraError(f"{self.name}: closed")
        ok, image = self._cap.read()
        if not ok or image is None:
            raise EndOfStream(f"{self.name}: end of file after {self._index} frames")
        dt_s = self._index / self.fps
        frame = Frame(_as_bgr(image), self._t0_mono_s + dt_s, self._t0_unix_s + dt_s, self._index)
        self._index += 1
        return frame

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._cap.release()
