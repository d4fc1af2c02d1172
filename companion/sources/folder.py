"""A folder of recorded frames named ``<unix_time_microseconds>.jpg|png`` (replay).

Frames are read in time order, as fast as asked. ``t_unix_s`` comes from the name;
``t_mono_s`` maps it onto this process's monotonic clock with the offset between
the two clocks sampled when the folder is opened, so a recording replays on the
same time axis as the pose log recorded with it. Files with other names are
ignored (counted and logged once); an unreadable or truncated image (a JPEG without
its end marker, a PNG without IEND: a recording cut short by a full disk or a
power loss) is skipped with a warning and counted in ``frames_skipped``; OpenCV
would decode the part that is there and grey out the rest, a frame that lies.
``write_frame`` saves a frame under the same naming scheme.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import cv2
import numpy as np

from companion.sources.base import (
    CameraError,
    EndOfStream,
    Frame,
    decode_image,
    mono_minus_unix_s,
    truncation,
)

log = logging.getLogger(__name__)

_NAME = re.compile(r"^(\d{1,20})\.(jpe?g|png)$", re.IGNORECASE)


def read_frame_file(path: Path) -> tuple[np.ndarray | None, str]:
    """The BGR image in a .jpg/.png file, or (None, why it cannot be used)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return None, f"cannot be read: {exc.strerror or exc}"
    if (why := truncation(data)) is not None:
        return None, f"is a {why}"
    image = decode_image(data)
    if image is None:
        return None, "is not a readable image"
    return image, ""


def frame_filename(t_unix_s: float, ext: str = "jpg") -> str:
    """The file name a frame captured at ``t_unix_s`` is stored under."""
    return f"{round(t_unix_s * 1e6):d}.{ext}"


def write_frame(folder: Path, frame: Frame, ext: str = "jpg", jpeg_quality: int = 90) -> Path:
    """Save a frame for replay; returns the path. Raises CameraError if it cannot."""
    path = folder / frame_filename(frame.t_unix_s, ext)
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if ext.lower() in ("jpg", "jpeg") else []
    try:
        ok = cv2.imwrite(str(path), frame.image, params)
    except cv2.error as exc:
        raise CameraError(f"cannot write {path}: {exc}") from None
    if not ok:
        raise CameraError(f"cannot write {path}")
    return path


def timed_files(
    name: str, folder: Path, pattern: re.Pattern[str], kind: str, suffixes: str
) -> list[tuple[int, Path]]:
    """The files of a frames folder named ``<unix_time_us>.<suffix>`` (``pattern``'s
    first group is the time), oldest first, with their times in microseconds. Raises
    CameraError naming ``name`` when the folder is missing, unreadable or holds none;
    other files are ignored and counted in the log."""
    if not folder.is_dir():
        raise CameraError(f"{name}: no such folder")
    try:
        paths = list(folder.iterdir())
    except OSError as exc:
        raise CameraError(f"{name}: cannot be listed: {exc.strerror or exc}") from None
    entries: list[tuple[int, Path]] = []
    for path in paths:
        match = pattern.match(path.name)
        if match and path.is_file():
            entries.append((int(match.group(1)), path))
    if len(entries) < len(paths):
        ignored = len(paths) - len(entries)
        log.info("%s: ignored %d files not named <unix_us>.%s", name, ignored, suffixes)
    if not entries:
        raise CameraError(f"{name}: holds no {kind} named <unix_time_us>.{suffixes}")
    return sorted(entries)


class FramesDirSource:
    """Replays a folder of time-stamped frames; EndOfStream after the last."""

    def __init__(self, folder: Path) -> None:
        self.name = f"frames:{folder}"
        self._entries = timed_files(self.name, folder, _NAME, "frames", "jpg|png")
        self._offset_s = mono_minus_unix_s()
        self._pos = 0
        self.frames_skipped = 0
        self._closed = False

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def mono_minus_unix_s(self) -> float:
        """The offset that maps the frames' wall times onto t_mono_s."""
        return self._offset_s

    def read(self, timeout_s: float) -> Frame:
        if self._closed:
            raise CameraError(f"{self.name}: closed")
        while self._pos < len(self._entries):
            t_us, path = self._entries[self._pos]
            index = self._pos
            self._pos += 1
            image, why = read_frame_file(path)
            if image is None:
                self.frames_skipped += 1
                log.warning("%s: %s %s; skipped", self.name, path.name, why)
                continue
            t_unix_s = t_us / 1e6
            return Frame(image, t_unix_s + self._offset_s, t_unix_s, index)
        raise EndOfStream(f"{self.name}: end after {len(self._entries)} frames")

    def close(self) -> None:
        self._closed = True
