"""Frames, the camera interface, its errors, and a background grabber for live cameras.

Exceptions::

    CameraError                 the camera failed (device gone, stream broken, bad config)
    +-- CameraTimeout           nothing arrived within read()'s timeout
    +-- EndOfStream             a file or a frames folder is finished

Live sources (V4L2, GStreamer, RTSP, Picamera2, the simulated camera) grab on a
background thread and keep only the newest frame: a slow consumer gets the latest
picture instead of a growing backlog, and ``frames_dropped`` counts what it missed.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import cv2
import numpy as np

from companion.errors import CompanionError

log = logging.getLogger(__name__)

_JOIN_TIMEOUT_S = 3.0  # how long close() waits for a grabber blocked in the driver


def decode_image(data: bytes) -> np.ndarray | None:
    """The BGR image an encoded JPEG or PNG (any format OpenCV reads) holds, or None.

    None also where OpenCV raises instead of returning nothing: an empty buffer, or a
    header claiming more pixels than it will allocate (CV_IO_MAX_IMAGE_PIXELS)."""
    if not data:
        return None
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    except cv2.error:
        return None
    return image if image is not None and image.size else None


def truncation(data: bytes) -> str | None:
    """Why an encoded image is cut short, judged by its content (a JPEG without its
    end-of-image marker, a PNG without its IEND chunk), or None. OpenCV decodes such
    a file without complaint, grey or black below the cut."""
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00\r\n").endswith(b"\xff\xd9"):
        return "truncated JPEG (no end-of-image marker)"
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in data[-16:]:
        return "truncated PNG (no IEND chunk)"
    return None


class CameraError(CompanionError):
    """The camera failed; the message says which camera and why."""


class CameraTimeout(CameraError):
    """No frame arrived within the timeout."""


class EndOfStream(CameraError):
    """A recorded source (file, frames folder) has no more frames."""


@dataclass(frozen=True)
class Frame:
    """One camera picture with its capture time on both clocks."""

    image: np.ndarray = field(repr=False)  # BGR uint8, H x W x 3
    t_mono_s: float  # capture time on the companion's time.monotonic()
    t_unix_s: float  # capture time on the wall clock
    index: int  # frame number from the source (gaps mean dropped frames)

    def __post_init__(self) -> None:
        img = self.image
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(
                f"Frame.image must be BGR uint8 HxWx3, got {img.dtype} {tuple(img.shape)}"
            )


class FrameSource(Protocol):
    """A camera. ``read`` raises CameraTimeout, CameraError or EndOfStream."""

    name: str

    def read(self, timeout_s: float) -> Frame: ...

    def close(self) -> None: ...


def mono_minus_unix_s() -> float:
    """The offset that turns wall time into monotonic time, sampled now."""
    return time.monotonic() - time.time()


P = TypeVar("P")  # what the grabber hands over (bytes, an array)
F = TypeVar("F")  # what read() returns (a Frame, a ThermalFrame)


@dataclass
class _Grabbed(Generic[P]):
    payload: P
    t_mono_s: float
    t_unix_s: float
    index: int


class ThreadedSource(ABC, Generic[P, F]):
    """A live camera: a thread grabs, read() waits for the newest frame.

    Subclasses open the device in their constructor (raising CameraError), then call
    ``_start()``; they implement ``_grab`` (blocking, raises CameraError when the
    device fails), ``_decode`` (payload -> an array, or None for a corrupt frame),
    ``_frame`` (that array -> what read() returns, or None for a frame that is no
    evidence) and ``_release``. ``_interrupt`` may unblock a pending ``_grab`` on
    close. ``ColourSource`` is the colour cameras' (BGR images, ``Frame``s).
    """

    name: str

    def __init__(self, name: str) -> None:
        self.name = name
        self._cond = threading.Condition()
        self._latest: _Grabbed[P] | None = None
        self._error: CameraError | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        self.frames_grabbed = 0
        self.frames_dropped = 0  # grabbed but replaced before anyone read them
        self.frames_corrupt = 0

    def _start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"camera {self.name}", daemon=True)
        self._thread.start()

    @abstractmethod
    def _grab(self) -> tuple[P, float, float]:
        """Block until the next frame: (payload, t_mono_s, t_unix_s)."""

    @abstractmethod
    def _decode(self, payload: P) -> np.ndarray | None: ...

    @abstractmethod
    def _frame(self, decoded: np.ndarray, grabbed: _Grabbed[P]) -> F | None: ...

    @abstractmethod
    def _release(self) -> None: ...

    def _interrupt(self) -> None:
        """Unblock a pending _grab (e.g. shut a socket down); default: nothing."""

    def _run(self) -> None:
        index = 0
        try:
            while not self._stop.is_set():
                payload, t_mono_s, t_unix_s = self._grab()
                with self._cond:
                    if self._latest is not None:
                        self.frames_dropped += 1
                    self._latest = _Grabbed(payload, t_mono_s, t_unix_s, index)
                    self.frames_grabbed += 1
                    self._cond.notify_all()
                index += 1
        except CameraError as exc:
            if not self._stop.is_set():
                log.warning("%s: %s", self.name, exc)
                with self._cond:
                    self._error = exc
                    self._cond.notify_all()
        except Exception as exc:  # a driver bug must become status, not a dead thread
            log.exception("%s: grabber failed", self.name)
            with self._cond:
                self._error = CameraError(f"{self.name}: grabber failed: {exc!r}")
                self._cond.notify_all()
        finally:
            self._release()

    def _take(self, deadline: float, timeout_s: float) -> _Grabbed[P]:
        """The newest grabbed payload, waiting until ``deadline`` (monotonic; the read's
        ``timeout_s`` names it in the message): CameraTimeout when none comes,
        CameraError once closed, the grabber's error when it failed."""
        with self._cond:
            while self._latest is None and self._error is None and not self._closed:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    raise CameraTimeout(f"{self.name}: no frame within {timeout_s:.3g} s")
                self._cond.wait(remaining)
            if self._closed:
                raise CameraError(f"{self.name}: closed")
            grabbed = self._latest
            if grabbed is None:
                assert self._error is not None  # loop exit condition
                raise self._error
            self._latest = None
            return grabbed

    def read(self, timeout_s: float) -> F:
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            grabbed = self._take(deadline, timeout_s)
            decoded = self._decode(grabbed.payload)
            if decoded is None:
                self.frames_corrupt += 1
                log.warning("%s: frame %d could not be decoded; skipped", self.name, grabbed.index)
                continue
            frame = self._frame(decoded, grabbed)
            if frame is not None:
                return frame

    def close(self) -> None:
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        self._stop.set()
        self._interrupt()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(_JOIN_TIMEOUT_S)
            if thread.is_alive():
                log.warning("%s: grabber still blocked in the driver after close", self.name)
        elif thread is None:
            self._release()

    def __enter__(self) -> ThreadedSource[P, F]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ColourSource(ThreadedSource[P, Frame]):
    """A live colour camera: ``_decode`` gives a BGR image, read() a ``Frame``."""

    def _frame(self, decoded: np.ndarray, grabbed: _Grabbed[P]) -> Frame:
        return Frame(decoded, grabbed.t_mono_s, grabbed.t_unix_s, grabbed.index)
