"""The simulated camera: renders frames from the rover's true pose and serves them over TCP.

Wire format, per frame (the companion's "sim" camera source reads it):

    uint32 big-endian N     length of what follows
    uint64 big-endian       capture time, Unix microseconds (the rover's clock:
                            time.time() when time_scale is 1)
    N - 8 bytes             JPEG

Every connected client gets every frame it can take: each has a small queue
(``queue_frames``); when it is full the oldest frame is dropped, so a slow client
sees fewer, fresh frames and the server's memory stays bounded.

``silences``: each stretch of more than ``SILENCE_S`` in which no client got a
frame, as (start, end) on the monotonic clock, from ``start()`` to ``close()``
(the chaos mission checks that a running companion is never left without frames).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import socket
import struct
import threading
import time
from collections.abc import Callable

from mavlink_io.convert import usec_from_unix_s
from scenarios.motion import TruePose
from scenarios.render import MIN_VIEW_PX, Renderer, encode_jpeg

log = logging.getLogger(__name__)

HEADER = struct.Struct(">IQ")  # length of the rest, capture time in Unix µs
SILENCE_S = 2.0  # a gap between two frames sent (to any client) longer than this is a silence


def pack_frame(t_unix_s: float, jpeg: bytes) -> bytes:
    return HEADER.pack(len(jpeg) + 8, usec_from_unix_s(t_unix_s)) + jpeg


class _Client:
    def __init__(self, sock: socket.socket, addr: object, queue_frames: int) -> None:
        self.sock, self.addr = sock, addr
        self.frames: queue.Queue[bytes | None] = queue.Queue(maxsize=queue_frames)
        self.dropped = 0
        self.sent = 0

    def offer(self, packet: bytes) -> None:
        while True:
            try:
                self.frames.put_nowait(packet)
                return
            except queue.Full:
                with contextlib.suppress(queue.Empty):
                    self.frames.get_nowait()
                    self.dropped += 1


class CameraServer:
    """Renders at ``fps`` and sends to all clients (see the module docstring)."""

    def __init__(
        self,
        renderer: Renderer,
        pose_now: Callable[[], tuple[TruePose, float]],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        fps: float = 10.0,
        jpeg_quality: int = 85,
        queue_frames: int = 2,
        time_scale: float = 1.0,
    ) -> None:
        """``pose_now()`` returns the true pose now and its capture time (Unix s)."""
        if fps <= 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.renderer = renderer
        self.pose_now = pose_now
        self.fps = fps
        self.jpeg_quality = jpeg_quality
        self.queue_frames = queue_frames
        self.time_scale = time_scale
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(0.2)
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.frames_rendered = 0
        self.silences: list[tuple[float, float]] = []
        self._last_sent_mono_s = time.monotonic()
        # Ground truth for scoring: when each victim first showed enough of itself.
        self.first_in_view_unix_s: dict[int, float] = {}

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._listener.getsockname()[:2]
        return str(host), int(port)

    def start(self) -> CameraServer:
        self._last_sent_mono_s = time.monotonic()
        for target, name in ((self._accept, "cam-accept"), (self._render, "cam-render")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def __enter__(self) -> CameraServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def closed(self) -> bool:
        return self._stop.is_set()

    def close(self) -> None:
        """Stop rendering, disconnect clients; safe to call twice."""
        if not self._stop.is_set():
            self._note_sent()  # a silence up to now is one too
        self._stop.set()
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            c.offer(b"")  # wakes the sender, which then sees the stop flag
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()
        with contextlib.suppress(OSError):
            self._listener.close()

    @property
    def last_sent_mono_s(self) -> float:
        """When a client last got a frame (monotonic clock; start() before the first)."""
        with self._lock:
            return self._last_sent_mono_s

    def client_stats(self) -> list[tuple[int, int]]:
        """(sent, dropped) per connected client."""
        with self._lock:
            return [(c.sent, c.dropped) for c in self._clients]

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                sock, addr = self._listener.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self._stop.is_set():
                    return  # the listener was closed
                # A client gone before it was accepted (a companion killed while it
                # connected): serve the next one. Returning here left the camera
                # connectable but silent for every later client.
                log.info("camera accept failed: %s", exc)
                self._stop.wait(0.05)
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, addr, self.queue_frames)
            with self._lock:
                self._clients.append(client)
            t = threading.Thread(target=self._sender, args=(client,), name="cam-send", daemon=True)
            t.start()
            self._threads.append(t)
            log.info("camera client %s connected", addr)

    def _sender(self, client: _Client) -> None:
        try:
            while not self._stop.is_set():
                packet = client.frames.get()
                if not packet:
                    continue
                client.sock.sendall(packet)
                client.sent += 1
                self._note_sent()
        except OSError as exc:
            log.info("camera client %s gone: %s", client.addr, exc)
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)
            with contextlib.suppress(OSError):
                client.sock.close()

    def _note_sent(self) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._last_sent_mono_s > SILENCE_S:
                self.silences.append((self._last_sent_mono_s, now))
            self._last_sent_mono_s = now

    def _render(self) -> None:
        period_s = 1.0 / self.fps / self.time_scale
        while not self._stop.is_set():
            started = time.monotonic()
            pose, t_unix = self.pose_now()
            result = self.renderer.render(pose)
            packet = pack_frame(t_unix, encode_jpeg(result.image, self.jpeg_quality))
            self.frames_rendered += 1
            for vid, px in result.visible_px.items():
                if px >= MIN_VIEW_PX:
                    self.first_in_view_unix_s.setdefault(vid, t_unix)
            with self._lock:
                clients = list(self._clients)
            for c in clients:
                c.offer(packet)
            # Wait out the rest of the frame period (an Event wait: close() ends it at once).
            self._stop.wait(max(0.0, period_s - (time.monotonic() - started)))
