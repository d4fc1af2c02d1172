"""The Raspberry Pi camera through Picamera2 (Raspberry Pi OS's python3-picamera2).

Picamera2 is not on PyPI for the venv; on the Pi create the venv with
``--system-site-packages`` so that ``import picamera2`` finds the system package.
Format "RGB888" is BGR in memory order, which is what OpenCV wants.

The capture time comes from libcamera's SensorTimestamp (nanoseconds on
CLOCK_BOOTTIME): its age is subtracted from the arrival time on both clocks. When
the metadata has no timestamp, the arrival time is used.
"""

from __future__ import annotations

import importlib
import logging
import time
from typing import Any

import numpy as np

from companion.sources.base import CameraError, ColourSource

log = logging.getLogger(__name__)

_NEEDS = (
    "source = 'picamera2' needs Picamera2, which comes with Raspberry Pi OS "
    "(sudo apt install python3-picamera2; make the venv with --system-site-packages)"
)


class Picamera2Source(ColourSource[np.ndarray]):
    def __init__(self, width_px: int, height_px: int, fps: float) -> None:
        super().__init__("picamera2")
        try:
            module: Any = importlib.import_module("picamera2")
        except ImportError:
            raise CameraError(_NEEDS) from None
        try:
            self._cam = module.Picamera2()
            config = self._cam.create_video_configuration(
                main={"size": (width_px, height_px), "format": "RGB888"},
                controls={"FrameRate": fps},
                buffer_count=4,
            )
            self._cam.configure(config)
            self._cam.start()
        except Exception as exc:  # libcamera raises RuntimeError/IndexError/OSError variously
            raise CameraError(f"picamera2: cannot start the camera: {exc}") from None
        self._boottime = hasattr(time, "CLOCK_BOOTTIME")  # Linux only; else arrival time
        self._start()

    def _grab(self) -> tuple[np.ndarray, float, float]:
        try:
            request = self._cam.capture_request()
        except Exception as exc:
            raise CameraError(f"picamera2: capture failed: {exc}") from None
        t_mono_s, t_unix_s = time.monotonic(), time.time()
        try:
            image = request.make_array("main")
            sensor_ns = request.get_metadata().get("SensorTimestamp")
        finally:
            request.release()
        if sensor_ns is not None and self._boottime:
            age_s = _age_s(int(sensor_ns))
            t_mono_s -= age_s
            t_unix_s -= age_s
        return image, t_mono_s, t_unix_s

    def _decode(self, payload: np.ndarray) -> np.ndarray | None:
        return np.ascontiguousarray(payload[:, :, :3])

    def _release(self) -> None:
        try:
            self._cam.stop()
            self._cam.close()
        except Exception as exc:  # closing a failed camera must not raise from close()
            log.warning("picamera2: close failed: %s", exc)


def _age_s(stamp_ns: int) -> float:
    """How long ago a CLOCK_BOOTTIME nanosecond stamp was, clamped to [0, 1] s."""
    now_ns = time.clock_gettime_ns(time.CLOCK_BOOTTIME)
    return min(1.0, max(0.0, (now_ns - stamp_ns) / 1e9))
