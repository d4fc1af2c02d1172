"""The USB thermal cameras, read through OpenCV's V4L2 backend on a background thread.

- FLIR Lepton 3.5 on a PureThermal 2 or 3 board (UVC): the format is set to Y16 and
  then CONVERT_RGB off, in that order (setting the format turns OpenCV's conversion to
  RGB back on). ``find_purethermal`` finds the board by its V4L2 card name.
- InfiRay P2 Pro / Topdon TC001: YUYV at W x 2H with CONVERT_RGB off; the bottom half
  is the temperature.

Frames are grabbed as ``ThreadedSource`` grabs colour ones (the newest kept); ``read``
turns the newest into temperatures (``thermal_raw``). A device that sends what is not
temperatures (an 8-bit or false-colour picture, another size) fails with CameraError
saying so in one line; frames that are not evidence (frozen by the flat-field
correction, absurd values) are skipped, said once per run and held in ``status``, and
fail the camera when they last longer than ``thermal_raw.GIVE_UP_AFTER_S``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, Protocol

import cv2
import numpy as np

from companion.sources.base import CameraError, ThreadedSource, _Grabbed
from companion.sources.thermal import ThermalFrame
from companion.sources.thermal_raw import (
    GIVE_UP_AFTER_S,
    ThermalJudge,
    infiray_kelvin,
    lepton_kelvin,
)

VIDEO4LINUX = Path("/sys/class/video4linux")
PURETHERMAL_CARD = "purethermal"  # the board's V4L2 card name: "PureThermal (fw:v1.3.0)"


class VideoCaptureLike(Protocol):
    """The part of cv2.VideoCapture the thermal cameras use."""

    def open(self, filename: str, apiPreference: int, /) -> bool: ...

    def set(self, propId: int, value: float, /) -> bool: ...

    def get(self, propId: int, /) -> float: ...

    def read(self) -> tuple[bool, Any]: ...

    def release(self) -> None: ...


def find_purethermal(video4linux: Path = VIDEO4LINUX) -> str:
    """The /dev/videoN of the first PureThermal board (its capture node, index 0);
    CameraError when there is none."""
    found: list[tuple[int, int, str]] = []
    try:
        nodes = list(video4linux.glob("video*"))
    except OSError:
        nodes = []
    for node in nodes:
        number = node.name[5:]
        try:
            card = (node / "name").read_text(encoding="utf-8", errors="replace")
            index_file = node / "index"
            index_text = (
                index_file.read_text(errors="replace").strip() if index_file.exists() else "0"
            )
        except OSError:
            continue
        if number.isdecimal() and PURETHERMAL_CARD in card.lower():
            index = int(index_text) if index_text.isdecimal() else 0
            found.append((index, int(number), f"/dev/video{number}"))
    if not found:
        raise CameraError(
            f"lepton: no PureThermal board found (no V4L2 device named PureThermal in "
            f"{video4linux}); plug it in, or name it: lepton:/dev/videoN"
        )
    return min(found)[2]


def _fourcc(code: str) -> float:
    return float(cv2.VideoWriter.fourcc(*code))


def _fourcc_text(value: float) -> str:
    number = int(value) if value == value and 0 <= value < 2**32 else 0
    return "".join(chr((number >> (8 * i)) & 0xFF) for i in range(4))


class ThermalCaptureSource(ThreadedSource[np.ndarray, ThermalFrame]):
    """A Lepton (``kind = "lepton"``) or InfiRay (``"infiray"``) on a V4L2 device.

    ``capture`` makes the VideoCapture (a pseudo-device in tests). Its ``_decode``
    turns a grabbed frame into apparent kelvin, raising CameraError for a device that
    does not send temperatures; ``read`` returns ThermalFrames, not colour Frames."""

    def __init__(
        self,
        device: str,
        kind: Literal["lepton", "infiray"],
        width_px: int,
        height_px: int,
        fps: float,
        emissivity: float,
        capture: Callable[[], VideoCaptureLike] = cv2.VideoCapture,
    ) -> None:
        super().__init__(f"{kind}:{device}")
        self._kind = kind
        self._size = (width_px, height_px)
        self._judge = ThermalJudge(self.name, emissivity, GIVE_UP_AFTER_S)
        try:
            self._cap = capture()
            opened = self._cap.open(device, cv2.CAP_V4L2)
        except cv2.error as exc:
            raise CameraError(f"{self.name}: cannot open: {exc}") from None
        if not opened:
            self._cap.release()
            raise CameraError(f"{self.name}: cannot open (no such device, or it is busy)")
        try:
            self._configure(width_px, height_px, fps)
        except CameraError:
            self._cap.release()
            raise
        except cv2.error as exc:
            self._cap.release()
            raise CameraError(f"{self.name}: cannot set the camera up: {exc}") from None
        self._start()

    def _configure(self, width_px: int, height_px: int, fps: float) -> None:
        cap = self._cap
        rows = height_px if self._kind == "lepton" else 2 * height_px
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width_px)  # a request: the frames are checked
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, rows)
        cap.set(cv2.CAP_PROP_FPS, fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # keep the driver queue short
        wanted = "Y16 " if self._kind == "lepton" else "YUYV"
        if not cap.set(cv2.CAP_PROP_FOURCC, _fourcc(wanted)):
            raise CameraError(f"{self.name}: the device refuses the {wanted.strip()} format")
        got = _fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        if got != wanted:
            raise CameraError(
                f"{self.name}: the device sends {got!r}, not {wanted!r}"
                + (": not a Lepton on a PureThermal board?" if self._kind == "lepton" else "")
            )
        # Last: setting the format turned OpenCV's conversion to RGB back on.
        if not cap.set(cv2.CAP_PROP_CONVERT_RGB, 0):
            raise CameraError(f"{self.name}: the device refuses CONVERT_RGB off (raw words)")

    @property
    def status(self) -> str:
        """One line: what is wrong with the frames now ("ok" when nothing)."""
        return self._judge.status or "ok"

    @property
    def frames_skipped(self) -> int:
        return self._judge.frames_skipped

    def _grab(self) -> tuple[np.ndarray, float, float]:
        ok, image = self._cap.read()
        t_mono_s, t_unix_s = time.monotonic(), time.time()
        if not ok or image is None:
            raise CameraError(f"{self.name}: the device stopped delivering frames")
        return image, t_mono_s, t_unix_s

    def _decode(self, payload: np.ndarray) -> np.ndarray:
        to_kelvin = lepton_kelvin if self._kind == "lepton" else infiray_kelvin
        kelvin = to_kelvin(payload, self.name, *self._size)
        if isinstance(kelvin, str):
            raise CameraError(f"{self.name}: {kelvin}")
        return kelvin

    def _release(self) -> None:
        self._cap.release()

    def _frame(self, decoded: np.ndarray, grabbed: _Grabbed[np.ndarray]) -> ThermalFrame | None:
        temps_c = self._judge.judge(decoded, grabbed.t_mono_s)
        if temps_c is None:
            return None  # not evidence (the judge said why, once)
        return ThermalFrame(temps_c, grabbed.t_mono_s, grabbed.t_unix_s, grabbed.index)
