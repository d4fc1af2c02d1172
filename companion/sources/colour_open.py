"""The colour camera, as ``[camera] source`` names it.

=========================  ==========================================================
``source``                 camera
=========================  ==========================================================
``sim``                    the simulated camera at 127.0.0.1:5600 (same as below)
``sim:HOST:PORT``          the scenarios package's camera server (TCP, see sim.py)
``device:N``               V4L2 device number N (``/dev/videoN``)
``/dev/videoN``            the same, by path
``gstreamer:PIPELINE``     a GStreamer pipeline ending in appsink (e.g. libcamerasrc)
``rtsp://`` ``http(s)://`` a network stream through FFmpeg
``file:PATH``              a video file (EndOfStream at its end)
``frames:DIR``             recorded ``<unix_time_us>.jpg|png`` frames (replay)
``picamera2``              the Pi camera through Picamera2 (Raspberry Pi OS)
=========================  ==========================================================

``open_source(config)`` opens one; ``open_camera(config)`` wraps it in a
ReopeningSource that retries with backoff, its frames at the configured size
(``size.SizedSource``). ``parse_source`` checks the string only
(for the config stage). Relative PATH/DIR are taken as given (the config loader
does not resolve them: they are strings).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2

from companion.config import CameraConfig
from companion.sources.base import CameraError, FrameSource
from companion.sources.folder import FramesDirSource
from companion.sources.reopen import ReopeningSource
from companion.sources.sim import DEFAULT_HOST, DEFAULT_PORT, SimSource

Kind = Literal["sim", "device", "gstreamer", "url", "file", "frames", "picamera2"]


@dataclass(frozen=True)
class SourceSpec:
    kind: Kind
    target: str  # device number, pipeline, URL, path, or "host:port"
    port: int = 0  # sim only


def parse_source(source: str) -> SourceSpec:
    """Understand a ``[camera] source`` string; CameraError names what is wrong."""
    text = source.strip()
    if text == "sim":
        return SourceSpec("sim", DEFAULT_HOST, DEFAULT_PORT)
    if text.startswith("sim:"):
        host, sep, port = text[4:].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise CameraError(f"source {source!r}: expected sim:HOST:PORT (port 1..65535)")
        return SourceSpec("sim", host, int(port))
    if text.startswith("device:"):
        number = text[7:]
        if not number.isdigit():
            raise CameraError(f"source {source!r}: expected device:N with N a number")
        return SourceSpec("device", number)
    if text.startswith("/dev/video") and text[10:].isdigit():
        return SourceSpec("device", text[10:])
    if text.startswith("gstreamer:") and text[10:].strip():
        return SourceSpec("gstreamer", text[10:].strip())
    if text.split("://", 1)[0].lower() in ("rtsp", "rtsps", "http", "https") and "://" in text:
        return SourceSpec("url", text)
    if text.startswith("file:") and text[5:]:
        return SourceSpec("file", text[5:])
    if text.startswith("frames:") and text[7:]:
        return SourceSpec("frames", text[7:])
    if text == "picamera2":
        return SourceSpec("picamera2", "")
    raise CameraError(
        f"source {source!r}: not understood; use sim, sim:HOST:PORT, device:N, /dev/videoN, "
        "gstreamer:PIPELINE, rtsp://..., file:PATH, frames:DIR or picamera2"
    )


def open_source(camera: CameraConfig) -> FrameSource:
    """Open the configured camera once; CameraError when it cannot be opened."""
    from companion.sources.opencv import LiveCaptureSource, VideoFileSource

    spec = parse_source(camera.source)
    size = (camera.width_px, camera.height_px, camera.fps)
    if spec.kind == "sim":
        return SimSource(spec.target, spec.port)
    if spec.kind == "device":
        return LiveCaptureSource(f"/dev/video{spec.target}", int(spec.target), cv2.CAP_V4L2, *size)
    if spec.kind == "gstreamer":
        return LiveCaptureSource(f"gstreamer:{spec.target}", spec.target, cv2.CAP_GSTREAMER)
    if spec.kind == "url":
        return LiveCaptureSource(spec.target, spec.target, cv2.CAP_FFMPEG)
    if spec.kind == "file":
        return VideoFileSource(Path(spec.target), camera.fps)
    if spec.kind == "frames":
        return FramesDirSource(Path(spec.target))
    from companion.sources.picam import Picamera2Source

    return Picamera2Source(*size)


def open_camera(camera: CameraConfig) -> ReopeningSource:
    """The configured camera behind a ReopeningSource (the companion's normal use): a
    live one silent for ``stall_timeout_s`` is reopened; a recording never is."""
    spec = parse_source(camera.source)  # a malformed string is a config error, not a retry loop
    live = spec.kind not in ("file", "frames")
    from companion.sources.size import SizedSource

    return ReopeningSource(
        lambda: SizedSource(open_source(camera), camera.width_px, camera.height_px),
        max_backoff_s=camera.reopen_max_backoff_s,
        initial_backoff_s=min(0.2, camera.reopen_max_backoff_s),
        stall_timeout_s=camera.stall_timeout_s if live and camera.stall_timeout_s > 0 else None,
        name=camera.source,
    )
