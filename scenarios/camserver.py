"""The simulated cameras: render frames from the rover's true pose and serve them over TCP.

Two servers, one per camera, each on its own TCP port, with one framing (the
companion's "sim" sources read it), per frame:

    uint32 big-endian N     length of what follows
    uint64 big-endian       capture time, Unix microseconds (the rover's clock:
                            time.time() when time_scale is 1)
    N - 8 bytes             the picture

- ``CameraServer``, the colour camera: a JPEG, 10 frames/s by default.
- ``ThermalCameraServer``, the Lepton beside it (scenarios.thermal.ThermalRenderer,
  the same world and true pose): a 16-bit single-channel PNG whose words are
  centi-kelvin (°C = value / 100 - 273.15, as a recorded thermal frames folder),
  8.7 frames/s; during a flat-field correction the previous frame again, as a real
  Lepton sends it (``frames_frozen`` counts them).

Every connected client gets every frame it can take: each has a small queue
(``queue_frames``); when it is full the oldest frame is dropped, so a slow client
sees fewer, fresh frames and the server's memory stays bounded.

``silences``: each stretch of more than ``SILENCE_S`` in which no client got a
frame, as (start, end) on the monotonic clock, from ``start()`` to ``close()``
(the chaos mission checks that a running companion is never left without frames).
``first_in_view_unix_s``: when each victim first showed enough of itself to the
camera (colour: ``MIN_VIEW_PX`` pixels; thermal: ``MIN_WARM_VIEW_PX`` warm pixels).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import socket
import struct
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable

from mavlink_io.convert import usec_from_unix_s
from scenarios.motion import TruePose
from scenarios.render import MIN_VIEW_PX, Renderer, encode_jpeg
from scenarios.thermal import LEPTON_FPS, MIN_WARM_VIEW_PX, ThermalRenderer, encode_centikelvin_png

log = logging.getLogger(__name__)

HEADER = struct.Struct(">IQ")  # length of the rest, capture time in Unix µs
SILENCE_S = 2.0  # a gap between two frames sent (to any client) longer than this is a silence


def pack_frame(t_unix_s: float, picture: bytes) -> bytes:
    return HEADER.pack(len(picture) + 8, usec_from_unix_s(t_unix_s)) + picture


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


class FrameServer(ABC):
    """Renders at ``fps`` and sends to all clients (see the module docstring);
    subclasses say what one frame is (``_shoot``)."""

    what = "camera"  # in log lines
    thread_prefix = "cam"  # threads: cam-accept, cam-render, cam-send

    def __init__(
        self,
        pose_now: Callable[[], tuple[TruePose, float]],
        *,
        host: str,
        port: int,
        fps: float,
        queue_frames: int,
        time_scale: float,
    ) -> None:
        """``pose_now()`` returns the true pose now and its capture time (Unix s)."""
        if fps <= 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.pose_now = pose_now
        self.fps = fps
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

    @abstractmethod
    def _shoot(self, pose: TruePose, t_unix_s: float) -> bytes:
        """Render the frame at this pose and time: the picture to send (and note
        which victims are in view)."""

    @property
    def address(self) -> tuple[str, int]:
        host, port = self._listener.getsockname()[:2]
        return str(host), int(port)

    def start(self) -> FrameServer:
        self._last_sent_mono_s = time.monotonic()
        prefix = self.thread_prefix
        for target, name in (
            (self._accept, f"{prefix}-accept"),
            (self._render, f"{prefix}-render"),
        ):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def __enter__(self) -> FrameServer:
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
                log.info("%s accept failed: %s", self.what, exc)
                self._stop.wait(0.05)
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, addr, self.queue_frames)
            with self._lock:
                self._clients.append(client)
            t = threading.Thread(
                target=self._sender, args=(client,), name=f"{self.thread_prefix}-send", daemon=True
            )
            t.start()
            self._threads.append(t)
            log.info("%s client %s connected", self.what, addr)

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
            log.info("%s client %s gone: %s", self.what, client.addr, exc)
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
            packet = pack_frame(t_unix, self._shoot(pose, t_unix))
            self.frames_rendered += 1
            with self._lock:
                clients = list(self._clients)
            for c in clients:
                c.offer(packet)
            # Wait out the rest of the frame period (an Event wait: close() ends it at once).
            self._stop.wait(max(0.0, period_s - (time.monotonic() - started)))


class CameraServer(FrameServer):
    """The colour camera: JPEG frames of ``Renderer`` (see the module docstring)."""

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
        super().__init__(
            pose_now,
            host=host,
            port=port,
            fps=fps,
            queue_frames=queue_frames,
            time_scale=time_scale,
        )
        self.renderer = renderer
        self.jpeg_quality = jpeg_quality

    def start(self) -> CameraServer:
        super().start()
        return self

    def __enter__(self) -> CameraServer:
        return self.start()

    def _shoot(self, pose: TruePose, t_unix_s: float) -> bytes:
        result = self.renderer.render(pose)
        for vid, px in result.visible_px.items():
            if px >= MIN_VIEW_PX:
                self.first_in_view_unix_s.setdefault(vid, t_unix_s)
        return encode_jpeg(result.image, self.jpeg_quality)


class ThermalCameraServer(FrameServer):
    """The thermal camera: centi-kelvin PNG frames of ``ThermalRenderer`` at the
    pose's mission time (see the module docstring)."""

    what = "thermal camera"
    thread_prefix = "thermal"

    def __init__(
        self,
        renderer: ThermalRenderer,
        pose_now: Callable[[], tuple[TruePose, float]],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        fps: float = LEPTON_FPS,
        queue_frames: int = 2,
        time_scale: float = 1.0,
    ) -> None:
        super().__init__(
            pose_now,
            host=host,
            port=port,
            fps=fps,
            queue_frames=queue_frames,
            time_scale=time_scale,
        )
        self.renderer = renderer
        self.frames_frozen = 0  # flat-field correction frames (the previous one again)

    def start(self) -> ThermalCameraServer:
        super().start()
        return self

    def __enter__(self) -> ThermalCameraServer:
        return self.start()

    def _shoot(self, pose: TruePose, t_unix_s: float) -> bytes:
        result = self.renderer.render(pose, pose.t_s)
        if result.frozen:
            self.frames_frozen += 1
        else:
            for vid, px in result.warm_px.items():
                if px >= MIN_WARM_VIEW_PX:
                    self.first_in_view_unix_s.setdefault(vid, t_unix_s)
        return encode_centikelvin_png(result.temps_c)
