"""The camera threads: frames into the processing thread's mailbox (one slot per
camera; a newer frame replaces an unprocessed one and the drop is counted), each
also recorded for replay with ``[paths] record_frames``, and each camera's health:
``camera_ok`` (set while frames come or the source says it is healthy; the vehicle
link's HEARTBEAT and RESCUE_STATUS read it) and "camera lost" / "camera back",
announced once each. The thermal camera, when there is one, has its own thread,
slot, health ("thermal camera lost" / "back") and recording folder; nothing it does
stops the colour camera's.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Generic, Protocol, TypeVar

from companion.config import Config
from companion.reporting.announcements import Announcer
from companion.sources.base import CameraError, CameraTimeout, EndOfStream, Frame
from companion.sources.thermal import ThermalFrame

log = logging.getLogger(__name__)


class FrameMailbox:
    """The slots between the camera threads and the processing thread: one for the
    colour camera, one for the thermal camera."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._thermal: ThermalFrame | None = None
        self.received = 0
        self.dropped = 0
        self.thermal_received = 0
        self.thermal_dropped = 0

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self.received += 1
            self._cond.notify()

    def put_thermal(self, frame: ThermalFrame) -> None:
        with self._cond:
            if self._thermal is not None:
                self.thermal_dropped += 1
            self._thermal = frame
            self.thermal_received += 1
            self._cond.notify()

    def get(self, timeout_s: float) -> Frame | ThermalFrame:
        """The waiting frame captured first (colour or thermal); CameraTimeout when
        none arrives in time."""
        with self._cond:
            if not self._cond.wait_for(
                lambda: self._frame is not None or self._thermal is not None, timeout_s
            ):
                raise CameraTimeout(f"no frame within {timeout_s} s")
            colour, thermal = self._frame, self._thermal
            if thermal is None or (colour is not None and colour.t_mono_s <= thermal.t_mono_s):
                self._frame = None
                assert colour is not None  # wait_for guarantees one of them
                return colour
            self._thermal = None
            return thermal


def recording_dir(config: Config, kind: str) -> Path | None:
    """Where this run's frames of one camera are recorded (``kind``: "frames" for the
    colour camera, "thermal" for the thermal one, as ``rescue-sim record`` lays out a
    mission), created; None when not recording."""
    if not config.paths.record_frames:
        return None
    frames_dir = config.paths.state_dir / kind / time.strftime("%Y%m%d-%H%M%S")
    try:
        frames_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        log.warning("not recording frames: cannot create %s: %s", frames_dir, exc.strerror)
        return None
    return frames_dir


F = TypeVar("F", bound=Frame | ThermalFrame)
F_co = TypeVar("F_co", bound=Frame | ThermalFrame, covariant=True)


class Camera(Protocol[F_co]):
    """A camera behind reopening (companion.sources.reopen): read, health, close."""

    name: str

    @property
    def healthy(self) -> bool: ...

    def read(self, timeout_s: float) -> F_co: ...

    def close(self) -> None: ...


class Capture(Generic[F]):
    """One camera's thread: read, hand over, record, say how the camera is."""

    def __init__(
        self,
        *,
        camera: Camera[F],
        put: Callable[[F], None],
        record: Callable[[Path, F], object],
        frames_dir: Path | None,
        camera_ok: threading.Event,
        announcer: Announcer,
        stop: threading.Event,
        condition: str = "camera",
    ) -> None:
        self.camera: Camera[F] = camera
        self._put: Callable[[F], None] = put
        self._write: Callable[[Path, F], object] = record
        self.frames_dir = frames_dir
        self._camera_ok = camera_ok
        self._announcer = announcer
        self._stop = stop
        self._condition = condition

    def run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.camera.read(timeout_s=0.5)
            except CameraTimeout:
                frame = None
            except EndOfStream as exc:
                log.info("%s: %s", self._condition, exc)
                self._camera_ok.clear()
                self._announcer.announce(f"{self._condition} stream ended", 4)
                self._stop.wait()
                return
            except CameraError as exc:
                log.debug("%s: %s", self._condition, exc)
                frame = None
            ok = frame is not None or self.camera.healthy
            self._announcer.condition(self._condition, ok, time.monotonic())
            if ok:
                self._camera_ok.set()
            else:
                self._camera_ok.clear()
            if frame is not None:
                self._put(frame)
                self._record(frame)

    def _record(self, frame: F) -> None:
        """Save the frame for replay; a full disk stops the recording, not the camera."""
        if self.frames_dir is None:
            return
        try:
            self._write(self.frames_dir, frame)
        except CameraError as exc:
            log.warning("%s recording stopped: %s", self._condition, exc)
            self.frames_dir = None
