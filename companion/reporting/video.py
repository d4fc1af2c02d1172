"""The robot's eye in QGC: camera frames with the detections drawn, as live H.264 video.

QGC plays a stream that a MAVLink camera advertises (mavlink_io/camera.py answers
its CAMERA_INFORMATION and VIDEO_STREAM_INFORMATION requests): here H.264 in
MPEG-TS over UDP (VIDEO_STREAM_TYPE_MPEG_TS, QGC listens on the port the stream
information names) sent to ``[video] host:port``.

Each processed frame is offered with what to draw: the detections' boxes, and each
confirmed victim in view (projected from its tracked position with the frame's
pose) labelled with its ID and urgency in the urgency's colour. The video thread
takes the newest offer (a one-slot mailbox: a slow encoder drops frames, it never
delays processing), scales it to ``width_px`` x ``height_px``, at most ``fps``
frames a second, and encodes it with libx264 (PyAV's FFmpeg): ultrafast preset,
zero-latency tuning, a key frame every second (a receiver that joins shows
pictures within a second), ``bitrate_kbps`` with a matching VBV cap. The Pi 5 has
no hardware H.264 encoder; the CPU this costs is measured in bench/video.py.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction

import av
import cv2
import numpy as np

from companion.config import VideoConfig
from fusion.camera import CameraModel, rotation_zyx
from fusion.registry import Victim
from fusion.types import Detection, PoseSample, Urgency

log = logging.getLogger(__name__)

MPEG_TS_PACKET_BYTES = 188 * 7  # 1316: seven TS packets per UDP datagram
_BGR = {
    Urgency.CRITICAL: (40, 40, 230),
    Urgency.MEDIUM: (0, 165, 255),
    Urgency.LIGHT: (60, 200, 60),
}
_BOX_BGR = (255, 255, 0)


@dataclass(frozen=True)
class Label:
    u_px: float
    v_px: float
    text: str
    urgency: Urgency


@dataclass(frozen=True)
class Shot:
    """One frame to stream and what to draw on it (pixels of the camera image)."""

    image: np.ndarray
    boxes: tuple[tuple[int, int, int, int], ...]
    labels: tuple[Label, ...]


def labels_in_view(
    camera: CameraModel, pose: PoseSample, victims: Sequence[Victim], floor_down_m: float
) -> tuple[Label, ...]:
    """The victims whose floor point is in the image, labelled ``7 CRITICAL``."""
    if not victims:
        return ()
    points = np.array([[v.north_m, v.east_m, floor_down_m] for v in victims])
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    px, inside = camera.project_ned(
        points, vehicle, rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    )
    return tuple(
        Label(float(u), float(v), f"{victim.victim_id} {victim.urgency.name}", victim.urgency)
        for victim, (u, v), ok in zip(victims, px, inside, strict=True)
        if ok
    )


def shot(image: np.ndarray, detections: Sequence[Detection], labels: tuple[Label, ...]) -> Shot:
    return Shot(image, tuple(d.bbox_xywh_px for d in detections), labels)


def draw(s: Shot, width_px: int, height_px: int) -> np.ndarray:
    """The frame scaled to the stream's size with the boxes and labels drawn."""
    h, w = s.image.shape[:2]
    image = s.image if s.image.ndim == 3 else cv2.cvtColor(s.image, cv2.COLOR_GRAY2BGR)
    out = cv2.resize(image, (width_px, height_px), interpolation=cv2.INTER_AREA)
    sx, sy = width_px / w, height_px / h
    for x, y, bw, bh in s.boxes:
        p0 = (round(x * sx), round(y * sy))
        p1 = (round((x + bw) * sx), round((y + bh) * sy))
        cv2.rectangle(out, p0, p1, _BOX_BGR, 2)
    for label in s.labels:
        u, v = round(label.u_px * sx), round(label.v_px * sy)
        colour = _BGR[label.urgency]
        cv2.circle(out, (u, v), 6, colour, -1)
        (tw, th), _ = cv2.getTextSize(label.text, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 2)
        x0, y0 = min(max(0, u - tw // 2), width_px - tw), max(th + 4, v - 10)
        cv2.rectangle(out, (x0 - 2, y0 - th - 4), (x0 + tw + 2, y0 + 4), (0, 0, 0), -1)
        cv2.putText(out, label.text, (x0, y0), cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2)
    return out


class H264Encoder:
    """libx264 into MPEG-TS, written to ``url`` (``udp://host:port?pkt_size=1316``, or
    a file path for the bench). ``av.error.FFmpegError`` / OSError when it cannot open."""

    def __init__(self, url: str, cfg: VideoConfig) -> None:
        self.cfg = cfg
        self._container = av.open(url, "w", format="mpegts")
        stream = self._container.add_stream(
            "libx264", rate=Fraction(cfg.fps).limit_denominator(1000)
        )
        stream.width, stream.height, stream.pix_fmt = cfg.width_px, cfg.height_px, "yuv420p"
        kbps = round(cfg.bitrate_kbps)
        stream.bit_rate = kbps * 1000
        stream.options = {
            "preset": "ultrafast",
            "tune": "zerolatency",
            "g": str(max(1, round(cfg.fps))),  # a key frame every second
            "maxrate": f"{kbps}k",
            "bufsize": f"{kbps}k",  # a one-second VBV: the radio never sees a burst above it
        }
        stream.codec_context.time_base = Fraction(1, 1000)
        self._stream = stream
        self._t0_s: float | None = None
        self._last_pts = -1
        self.frames = 0
        self.bytes_out = 0

    def encode(self, image_bgr: np.ndarray, t_s: float) -> None:
        if self._t0_s is None:
            self._t0_s = t_s
        pts = max(self._last_pts + 1, round((t_s - self._t0_s) * 1000))
        self._last_pts = pts
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image_bgr), format="bgr24")
        frame.pts, frame.time_base = pts, Fraction(1, 1000)
        for packet in self._stream.encode(frame):
            self.bytes_out += packet.size
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        try:
            for packet in self._stream.encode(None):
                self._container.mux(packet)
        finally:
            self._container.close()


class VideoStreamer:
    """The video thread: the newest offered shot, drawn, encoded, sent."""

    def __init__(self, cfg: VideoConfig, host: str) -> None:
        self.cfg = cfg
        self.destination = f"udp://{host}:{cfg.port}"
        self._cond = threading.Condition()
        self._shot: Shot | None = None
        self._stop = threading.Event()
        self.offered = 0
        self.dropped = 0
        self.failed: str | None = None
        self.encoder: H264Encoder | None = None
        self._thread = threading.Thread(target=self._run, name="video", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def offer(self, s: Shot) -> None:
        with self._cond:
            if self._shot is not None:
                self.dropped += 1
            self._shot = s
            self.offered += 1
            self._cond.notify()

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        try:
            self.encoder = H264Encoder(
                f"{self.destination}?pkt_size={MPEG_TS_PACKET_BYTES}", self.cfg
            )
        except (av.error.FFmpegError, OSError) as exc:
            self.failed = f"video to {self.destination}: {exc}"
            log.warning("%s; no video", self.failed)
            return
        log.info(
            "video: H.264 %dx%d at %g fps, %g kbit/s, MPEG-TS to %s",
            self.cfg.width_px,
            self.cfg.height_px,
            self.cfg.fps,
            self.cfg.bitrate_kbps,
            self.destination,
        )
        period_s = 1.0 / self.cfg.fps
        next_s = 0.0
        try:
            while not self._stop.is_set():
                with self._cond:
                    self._cond.wait_for(lambda: self._shot is not None or self._stop.is_set(), 0.5)
                    s, self._shot = self._shot, None
                now = time.monotonic()
                if s is None:
                    continue
                if now < next_s:  # faster than fps: skip this one
                    self.dropped += 1
                    continue
                next_s = max(next_s + period_s, now - period_s)
                try:
                    self.encoder.encode(draw(s, self.cfg.width_px, self.cfg.height_px), now)
                except (av.error.FFmpegError, OSError) as exc:
                    log.debug("video frame not sent: %s", exc)  # no receiver yet, a full buffer
        finally:
            self.encoder.close()
