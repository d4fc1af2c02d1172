"""The simulated camera: a TCP client of the scenarios package's camera server.

Wire format, per frame: a 4-byte big-endian unsigned length N of what follows, an
8-byte big-endian unsigned capture time in Unix microseconds, then N - 8 bytes of
JPEG. The capture time becomes ``t_mono_s`` through the offset between
``time.monotonic()`` and ``time.time()`` sampled when the frame arrives.

A closed connection or a length that cannot be a frame (the stream is out of step)
is a CameraError: ReopeningSource then reconnects. A JPEG that does not decode is
skipped and counted (``frames_corrupt``); the stream stays in step.
"""

from __future__ import annotations

import contextlib
import socket
import struct

import numpy as np

from companion.sources.base import (
    CameraError,
    ColourSource,
    F,
    Frame,
    ThreadedSource,
    decode_image,
    mono_minus_unix_s,
)

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 5600
MAX_FRAME_BYTES = 16 * 1024 * 1024  # far above any 640x480..1920x1080 JPEG
_HEADER = struct.Struct(">I")
_STAMP = struct.Struct(">Q")
_CONNECT_TIMEOUT_S = 2.0


class SimStream(ThreadedSource[bytes, F]):
    """The simulator's frame stream at host:port (colour JPEGs or thermal PNGs)."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__(f"sim:{host}:{port}")
        try:
            self._sock = socket.create_connection((host, port), timeout=_CONNECT_TIMEOUT_S)
        except OSError as exc:
            raise CameraError(f"{self.name}: cannot connect: {exc.strerror or exc}") from None
        self._sock.settimeout(None)  # the grabber blocks; close() shuts the socket down
        self._start()

    def _recv_exactly(self, n: int) -> bytes:
        chunks = bytearray()
        while len(chunks) < n:
            try:
                chunk = self._sock.recv(min(n - len(chunks), 1 << 20))
            except OSError as exc:
                raise CameraError(f"{self.name}: connection failed: {exc}") from None
            if not chunk:
                raise CameraError(f"{self.name}: the camera server closed the connection")
            chunks += chunk
        return bytes(chunks)

    def _grab(self) -> tuple[bytes, float, float]:
        (length,) = _HEADER.unpack(self._recv_exactly(_HEADER.size))
        if not _STAMP.size < length <= MAX_FRAME_BYTES:
            raise CameraError(
                f"{self.name}: frame length {length} is not possible; the stream is out of step"
            )
        body = self._recv_exactly(length)
        (t_us,) = _STAMP.unpack_from(body)
        t_unix_s = t_us / 1e6
        return body[_STAMP.size :], t_unix_s + mono_minus_unix_s(), t_unix_s

    def _interrupt(self) -> None:
        with contextlib.suppress(OSError):  # not connected any more: nothing to unblock
            self._sock.shutdown(socket.SHUT_RDWR)

    def _release(self) -> None:
        self._sock.close()


class SimSource(SimStream[Frame], ColourSource[bytes]):
    """Colour frames from the scenarios camera server at host:port."""

    def _decode(self, payload: bytes) -> np.ndarray | None:
        return decode_image(payload)


def encode_sim_frame(jpeg: bytes, t_unix_s: float) -> bytes:
    """One frame in the wire format (for servers and tests)."""
    return _HEADER.pack(len(jpeg) + _STAMP.size) + _STAMP.pack(round(t_unix_s * 1e6)) + jpeg
