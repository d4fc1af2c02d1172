"""A camera that comes back: failed or vanished sources are reopened with backoff.

``ReopeningSource.read`` never lets a camera failure escape as anything but
CameraTimeout (healthy, nothing yet) or CameraError (down; the message says why and
when the next attempt is): the caller reports the status and keeps going. Attempts
are spaced by an exponential backoff from ``initial_backoff_s`` up to
``max_backoff_s``, reset by the first good frame. EndOfStream is passed through: a
finished recording is not reopened. A live source that stays silent for
``stall_timeout_s`` is treated as failed and reopened.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from companion.sources.base import CameraError, CameraTimeout, EndOfStream, Frame, FrameSource

log = logging.getLogger(__name__)


class ReopeningSource:
    def __init__(
        self,
        factory: Callable[[], FrameSource],
        max_backoff_s: float,
        initial_backoff_s: float = 0.2,
        stall_timeout_s: float | None = None,
        name: str = "camera",
    ) -> None:
        if not 0.0 < initial_backoff_s <= max_backoff_s:
            raise ValueError(
                f"backoff: need 0 < initial_backoff_s ({initial_backoff_s}) "
                f"<= max_backoff_s ({max_backoff_s})"
            )
        self.name = name
        self._factory = factory
        self._max_backoff_s = max_backoff_s
        self._initial_backoff_s = initial_backoff_s
        self._stall_timeout_s = stall_timeout_s
        self._backoff_s = initial_backoff_s
        self._source: FrameSource | None = None
        self._next_attempt_mono_s = time.monotonic()
        self._last_frame_mono_s = time.monotonic()
        self._closed = threading.Event()
        self.last_error = ""
        self.opens = 0  # successful opens
        self.failures = 0  # failed opens plus failures of an open source
        self.frames = 0

    @property
    def healthy(self) -> bool:
        """An open source that has not failed since its last good frame."""
        return self._source is not None and not self.last_error

    def _fail(self, message: str) -> None:
        self.failures += 1
        self.last_error = message
        self._next_attempt_mono_s = time.monotonic() + self._backoff_s
        log.warning("%s; next attempt in %.1f s", message, self._backoff_s)
        self._backoff_s = min(self._max_backoff_s, 2.0 * self._backoff_s)
        if self._source is not None:
            source, self._source = self._source, None
            source.close()

    def _try_open(self) -> None:
        try:
            self._source = self._factory()
        except CameraError as exc:
            self._fail(str(exc))
            return
        self.opens += 1
        self.name = self._source.name
        self._last_frame_mono_s = time.monotonic()
        log.info("%s: open", self.name)

    def read(self, timeout_s: float) -> Frame:
        deadline = time.monotonic() + max(0.0, timeout_s)
        while not self._closed.is_set():
            now = time.monotonic()
            if self._source is None:
                if now >= self._next_attempt_mono_s:
                    self._try_open()
                    continue
                if now >= deadline:
                    break
                # Wait for the next attempt or the deadline; close() cuts it short.
                self._closed.wait(min(deadline, self._next_attempt_mono_s) - now)
                continue
            wait_s = max(0.0, deadline - now)
            stall = self._stall_timeout_s
            if stall is not None:  # wake in time to notice a stall within a long read
                wait_s = min(wait_s, max(0.0, self._last_frame_mono_s + stall - now) + 0.01)
            try:
                frame = self._source.read(wait_s)
            except EndOfStream:
                raise
            except CameraTimeout:
                if stall is not None and time.monotonic() - self._last_frame_mono_s > stall:
                    self._fail(f"{self.name}: no frame for {stall:.3g} s")
                    if time.monotonic() < deadline:
                        continue
                    break
                if time.monotonic() < deadline:
                    continue
                raise
            except CameraError as exc:
                self._fail(str(exc))
                continue
            self.frames += 1
            self._last_frame_mono_s = time.monotonic()
            self._backoff_s = self._initial_backoff_s
            self.last_error = ""
            return frame
        if self._closed.is_set():
            raise CameraError(f"{self.name}: closed")
        wait_s = max(0.0, self._next_attempt_mono_s - time.monotonic())
        raise CameraError(f"camera down: {self.last_error} (next attempt in {wait_s:.1f} s)")

    def close(self) -> None:
        self._closed.set()
        if self._source is not None:
            source, self._source = self._source, None
            source.close()
