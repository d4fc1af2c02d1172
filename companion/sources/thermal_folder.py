"""A folder of recorded thermal frames: ``<unix_time_us>.png``, 16-bit, centi-kelvin.

The format other tools produce too (``rescue-sim record``, the service with
``record_frames``): one single-channel 16-bit PNG per frame, each value the
temperature in centi-kelvin (°C = value / 100 - 273.15), named by its capture time on
the tlog's wall clock as the colour frames are (``folder.frame_filename``). The
values are the scene's temperatures as the companion used them (emissivity already
corrected): replay reads them as they are.

``ThermalFramesDir`` reads such a folder as ``FramesDirSource`` reads colour frames:
in time order, ``t_mono_s`` mapped from the name with the clock offset sampled at
opening, files with other names ignored (counted, logged once), an unreadable,
truncated, 8-bit or false-colour file skipped with a warning naming it and counted in
``frames_skipped``, EndOfStream after the last. Frames that are not evidence (frozen
by a flat-field correction, absurd values) are skipped too, said once per run. A
frame of another size than configured is CameraError naming both sizes.
``write_thermal_frame`` records one frame.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import cv2
import numpy as np

from companion.sources.base import CameraError, EndOfStream, mono_minus_unix_s, truncation
from companion.sources.folder import frame_filename, timed_files
from companion.sources.thermal import ThermalFrame
from companion.sources.thermal_raw import ZERO_C_K, ThermalJudge, not_temperatures

log = logging.getLogger(__name__)

_NAME = re.compile(r"^(\d{1,20})\.png$", re.IGNORECASE)
_MAX_CENTI_K = 65535  # 382.2 °C: hotter pixels are written as this


def read_thermal_png(path: Path) -> tuple[np.ndarray | None, str]:
    """The centi-kelvin words (uint16 H x W) of a thermal PNG, or (None, why not)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return None, f"cannot be read: {exc.strerror or exc}"
    if (why := truncation(data)) is not None:
        return None, f"is a {why}"
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None or not image.size:
        return None, "is not a readable image"
    if why := not_temperatures(image):
        return None, f"is {why}"
    return image.reshape(image.shape[:2]), ""


def write_thermal_frame(folder: Path, frame: ThermalFrame) -> Path:
    """Record a frame as ``<unix_time_us>.png`` in centi-kelvin; returns the path.
    Raises CameraError if it cannot (a full disk, NaN temperatures)."""
    path = folder / frame_filename(frame.t_unix_s, "png")
    temps_c = frame.temps_c.astype(np.float64)
    if not np.isfinite(temps_c).all():
        raise CameraError(f"cannot write {path}: the frame holds NaN or infinite temperatures")
    words = np.clip(np.rint((temps_c + ZERO_C_K) * 100.0), 0, _MAX_CENTI_K).astype(np.uint16)
    try:
        ok = cv2.imwrite(str(path), words)
    except cv2.error as exc:
        raise CameraError(f"cannot write {path}: {exc}") from None
    if not ok:
        raise CameraError(f"cannot write {path}")
    return path


class ThermalFramesDir:
    """Replays a folder of thermal frames; EndOfStream after the last."""

    def __init__(self, folder: Path, width_px: int, height_px: int) -> None:
        self.name = f"frames:{folder}"
        self._size = (width_px, height_px)
        self._entries = timed_files(self.name, folder, _NAME, "thermal frames", "png")
        self._offset_s = mono_minus_unix_s()
        self._pos = 0
        self._files_skipped = 0
        # Recorded temperatures are already corrected: emissivity 1 leaves them as they are.
        self._judge = ThermalJudge(self.name, 1.0, None)
        self._closed = False

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def mono_minus_unix_s(self) -> float:
        """The offset that maps the frames' wall times onto t_mono_s."""
        return self._offset_s

    @property
    def frames_skipped(self) -> int:
        """Files that could not be used plus frames that were not evidence."""
        return self._files_skipped + self._judge.frames_skipped

    @property
    def status(self) -> str:
        """One line: what is wrong with the frames now ("ok" when nothing)."""
        return self._judge.status or "ok"

    def read(self, timeout_s: float) -> ThermalFrame:
        if self._closed:
            raise CameraError(f"{self.name}: closed")
        while self._pos < len(self._entries):
            t_us, path = self._entries[self._pos]
            index = self._pos
            self._pos += 1
            words, why = read_thermal_png(path)
            if words is None:
                self._files_skipped += 1
                log.warning("%s: %s %s; skipped", self.name, path.name, why)
                continue
            h, w = words.shape
            if (w, h) != self._size:
                raise CameraError(
                    f"{self.name}: {path.name} is {w}x{h}, [thermal] is configured for "
                    f"{self._size[0]}x{self._size[1]}"
                )
            t_unix_s = t_us / 1e6
            temps_c = self._judge.judge(words.astype(np.float32) / np.float32(100.0), t_unix_s)
            if temps_c is not None:
                return ThermalFrame(temps_c, t_unix_s + self._offset_s, t_unix_s, index)
        raise EndOfStream(f"{self.name}: end after {len(self._entries)} frames")

    def close(self) -> None:
        self._closed = True
