"""Cameras and files read through OpenCV's VideoCapture.

- ``LiveCaptureSource``: a V4L2 device (index or /dev/videoN), a GStreamer pipeline
  (needs an OpenCV built with GStreamer; the pip wheels are not) or a network URL
  (RTSP/HTTP through FFmpeg). Frames are stamped when the driver hands them over.
- ``VideoFileSource``: a video file, read as fast as asked. Its capture times are
  synthetic: the time of opening plus ``index / fps`` (the file's frame rate, or the
  configured one when the file has none), on both clocks. A damaged frame is
  skipped and counted (``frames_corrupt``); the frames after it are read
  (``video_frames``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from companion.sources.base import CameraError, ColourSource, EndOfStream, Frame

log = logging.getLogger(__name__)


# Reads that fail in a row before a video counts as ended: a damaged frame fails
# alone and the next ones decode again; at the end of the file every read fails.
_GIVE_UP_AFTER_FAILED_READS = 10


def video_frames(cap: cv2.VideoCapture) -> Iterator[tuple[int, np.ndarray | None]]:
    """(index in the file, image) for each frame of an open video file; None for a
    frame that did not decode where a later one did."""
    index = failed = 0
    while failed < _GIVE_UP_AFTER_FAILED_READS:
        ok, image = cap.read()
        if not ok or image is None:
            failed += 1
            continue
        for _ in range(failed):
            yield index, None
            index += 1
        failed = 0
        yield index, image
        index += 1


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


class LiveCaptureSource(ColourSource[np.ndarray]):
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
        # The frame count the file's header gives (0: none; some containers estimate it).
        self.frames_in_header = max(0, int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0))
        self._t0_mono_s = time.monotonic()
        self._t0_unix_s = time.time()
        self._frames = video_frames(self._cap)
        self.frames_read = 0  # frames of the file read so far, damaged ones included
        self.frames_corrupt = 0
        self._closed = False

    def read(self, timeout_s: float) -> Frame:
        if self._closed:
            raise CameraError(f"{self.name}: closed")
        for index, image in self._frames:
            self.frames_read = index + 1
            if image is None:
                self.frames_corrupt += 1
                log.warning("%s: frame %d could not be decoded; skipped", self.name, index)
                continue
            dt_s = index / self.fps
            return Frame(_as_bgr(image), self._t0_mono_s + dt_s, self._t0_unix_s + dt_s, index)
        raise EndOfStream(f"{self.name}: end of file after {self.frames_read} frames")

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._cap.release()
