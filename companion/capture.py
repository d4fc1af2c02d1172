"""The camera thread: frames into the processing thread's one-slot mailbox (a newer
frame replaces an unprocessed one; the drop is counted), each also recorded for
replay with ``[paths] record_frames``, and the camera's health: ``camera_ok`` (set
while frames come or the source says it is healthy; the vehicle link's HEARTBEAT
and RESCUE_STATUS read it) and "camera lost" / "camera back", announced once each.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

from companion.announcements import Announcer
from companion.config import Config
from companion.sources import (
    CameraError,
    CameraTimeout,
    EndOfStream,
    Frame,
    write_frame,
)
from companion.sources.reopen import ReopeningSource

log = logging.getLogger(__name__)


class FrameMailbox:
    """One frame slot between the camera and processing threads."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self.received = 0
        self.dropped = 0

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self.received += 1
            self._cond.notify()

    def get(self, timeout_s: float) -> Frame:
        """The newest frame; CameraTimeout when none arrives in time."""
        with self._cond:
            if self._frame is None and not self._cond.wait_for(
                lambda: self._frame is not None, timeout_s
            ):
                raise CameraTimeout(f"no frame within {timeout_s} s")
            frame, self._frame = self._frame, None
            assert frame is not None  # wait_for guarantees it
            return frame


def recording_dir(config: Config) -> Path | None:
    """Where this run's frames are recorded, created; None when not recording."""
    if not config.paths.record_frames:
        return None
    frames_dir = config.paths.state_dir / "frames" / time.strftime("%Y%m%d-%H%M%S")
    try:
        frames_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        log.warning("not recording frames: cannot create %s: %s", frames_dir, exc.strerror)
        return None
    return frames_dir


class Capture:
    def __init__(
        self,
        *,
        camera: ReopeningSource,
        mailbox: FrameMailbox,
        frames_dir: Path | None,
        camera_ok: threading.Event,
        announcer: Announcer,
        stop: threading.Event,
    ) -> None:
        self.camera = camera
        self._mailbox = mailbox
        self.frames_dir = frames_dir
        self._camera_ok = camera_ok
        self._announcer = announcer
        self._stop = stop

    def run(self) -> None:
        while not self._stop.is_set():
            try:
                frame = self.camera.read(timeout_s=0.5)
            except CameraTimeout:
                frame = None
            except EndOfStream as exc:
                log.info("camera: %s", exc)
                self._camera_ok.clear()
                self._announcer.announce("camera stream ended", 4)
                self._stop.wait()
                return
            except CameraError as exc:
                log.debug("camera: %s", exc)
                frame = None
            ok = frame is not None or self.camera.healthy
            self._announcer.condition("camera", ok, time.monotonic())
            if ok:
                self._camera_ok.set()
            else:
                self._camera_ok.clear()
            if frame is not None:
                self._mailbox.put(frame)
                self._record(frame)

    def _record(self, frame: Frame) -> None:
        """Save the frame for replay; a full disk stops the recording, not the camera."""
        if self.frames_dir is None:
            return
        try:
            write_frame(self.frames_dir, frame)
        except CameraError as exc:
            log.warning("frame recording stopped: %s", exc)
            self.frames_dir = None
