"""``rescue-companion detect``: the perception step on image and video files.

For each image: every detection's box ``[x, y, w, h]`` in pixels, score, cues,
visibility in percent and urgency; ``--json`` prints one JSON object per image.
Without ``--config`` (a photo of unknown geometry) visibility is measured against
the body's own extent in the image. With a config, the frame is taken as seen by
that camera, on its mount, from a level vehicle on a flat floor: visibility is
then measured against a whole lying adult at the detection's floor point.

A video file (by its suffix) is read frame by frame, every ``--every``-th frame
detected as the companion does on a live camera: one detector for the stream, its
extra passes and part detectors taking turns over the frames (an image gets all of
them). The text output lists the frames with detections and a summary line; JSON
has one object per frame detected, with ``frame`` (its index in the file) and
``t_s`` (its time in the video). ``--annotate`` writes the video, annotated, as
``DIR/<name>.mp4``.

Thermal pictures are detected by the thermal detector (companion/vision/thermal.py):
a FLIR radiometric JPEG (its raw counts and Planck constants read with exiftool) or
a 16-bit single-channel PNG in centi-kelvin (a thermal frames folder's
``<unix_time_us>.png``; a folder of them is one stream, its frames' times from
their names, so a fading warm imprint is told from a person). Their JSON has
``thermal: {min_c, ambient_c, max_c}`` and each detection its ``peak_c``,
``mean_c`` and ``area_m2`` (null without a geometry); ``--annotate`` draws them in
false colour with a temperature scale. With ``--config`` and a ``[thermal]``
section they are seen by that camera on its mount. A FLIR JPEG without raw data (a
false-colour picture) is named and skipped: it holds no temperatures.

An unreadable or truncated image, or a video that cannot be opened, has frames
that do not decode (they are skipped, the frames after them still detected) or
ends before the frame count its header gives, is named on stderr (an image is
skipped, a video's decoded frames are kept); the exit status is then 2.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from companion.config import Config, DetectorConfig
from companion.errors import CompanionError
from companion.sources.base import CameraError, EndOfStream, decode_image, truncation
from companion.sources.flir import FlirError, read_flir
from companion.sources.opencv import VideoFileSource
from companion.vision.backends import make_detector
from companion.vision.base import Detector, FrameGeometry
from companion.vision.thermal import ThermalDetector, ThermalFind, ThermalResult
from companion.vision.thermal_picture import thermal_picture
from companion.vision.visibility import assess
from fusion.types import Detection, PoseSample, Urgency

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
VIDEO_SUFFIXES = {".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".ts"}
URGENCY_BGR = {
    Urgency.LIGHT: (80, 200, 60),
    Urgency.MEDIUM: (0, 170, 255),
    Urgency.CRITICAL: (40, 40, 230),
}


class ImageError(CompanionError):
    """An image file that cannot be used; the message names it and says why."""


def read_image(path: Path) -> np.ndarray:
    """A BGR image; ImageError for a missing, unreadable, truncated or empty file."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ImageError(f"{path}: cannot read: {exc.strerror}") from None
    if (why := truncation(data)) is not None:
        raise ImageError(f"{path}: {why}")
    if not data:
        raise ImageError(f"{path}: empty file")
    image = decode_image(data)
    if image is None:
        raise ImageError(f"{path}: not an image OpenCV can decode")
    return image


# Temperatures a thermal camera's frame can hold; outside: not centi-kelvin.
FRAME_MIN_C, FRAME_MAX_C = -60.0, 700.0


def is_flir_jpeg(data: bytes) -> bool:
    """A JPEG carrying FLIR's APP1 segments (radiometric or not: read_flir tells)."""
    return data[:2] == b"\xff\xd8" and b"FLIR\x00" in data[:262144]


def thermal_png(data: bytes, path: Path) -> np.ndarray | None:
    """°C of a 16-bit single-channel PNG in centi-kelvin; None if it is another
    picture (colour or 8-bit); ImageError for absurd temperatures."""
    if not data.startswith(b"\x89PNG\r\n\x1a\n") or len(data) < 26:
        return None
    bit_depth, colour_type = data[24], data[25]  # the IHDR chunk
    if bit_depth != 16 or colour_type != 0:
        return None
    raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16 or raw.ndim != 2:
        raise ImageError(f"{path}: a 16-bit PNG OpenCV cannot decode")
    temps = (raw.astype(np.float32) / 100.0 - 273.15).astype(np.float32)
    lo, hi = float(temps.min()), float(temps.max())
    if lo < FRAME_MIN_C or hi > FRAME_MAX_C:
        raise ImageError(
            f"{path}: temperatures {lo:.1f}..{hi:.1f} °C outside {FRAME_MIN_C:.0f}.."
            f"{FRAME_MAX_C:.0f}: not a thermal frame in centi-kelvin"
        )
    return temps


def read_thermal(path: Path) -> np.ndarray | None:
    """°C of a thermal picture (FLIR radiometric JPEG, centi-kelvin PNG); None if
    the file is not one (a colour picture); ImageError naming what is wrong."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ImageError(f"{path}: cannot read: {exc.strerror}") from None
    if (why := truncation(data)) is not None:
        raise ImageError(f"{path}: {why}")
    if is_flir_jpeg(data):
        try:
            return read_flir(path).temps_c
        except FlirError as exc:
            raise ImageError(str(exc)) from None
    return thermal_png(data, path)


def thermal_geometry(config: Config, width_px: int, height_px: int) -> FrameGeometry | None:
    """The configured thermal camera on a level vehicle; None without [thermal]."""
    from companion.calibration import camera_model
    from fusion.camera import CameraModel

    if config.thermal is None:
        return None
    cam = camera_model(config.thermal)
    if (cam.intrinsics.width_px, cam.intrinsics.height_px) != (width_px, height_px):
        cam = CameraModel(cam.intrinsics.scaled(width_px, height_px), cam.mount)
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return FrameGeometry.from_pose(cam, pose, config.geolocation)


def expand(inputs: Sequence[Path]) -> Iterator[Path]:
    """Files as given; folders as their image and video files, sorted."""
    known = IMAGE_SUFFIXES | VIDEO_SUFFIXES
    for p in inputs:
        if p.is_dir():
            yield from sorted(f for f in p.iterdir() if f.suffix.lower() in known)
        else:
            yield p


def is_video(path: Path) -> bool:
    return path.suffix.lower() in VIDEO_SUFFIXES


def level_geometry(config: Config, width_px: int, height_px: int) -> FrameGeometry:
    """The configured camera on a level vehicle at the origin, frame size as given."""
    from companion.calibration import camera_model
    from fusion.camera import CameraModel

    cam = camera_model(config.camera)
    if (cam.intrinsics.width_px, cam.intrinsics.height_px) != (width_px, height_px):
        cam = CameraModel(cam.intrinsics.scaled(width_px, height_px), cam.mount)
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return FrameGeometry.from_pose(
        cam, pose, config.geolocation, config.detector.body_silhouette_fill
    )


def describe(det: Detection, geometry: FrameGeometry | None) -> dict[str, object]:
    a = assess(det, geometry)
    return {
        "box": list(det.bbox_xywh_px),
        "score": round(det.score, 3),
        "cues": list(det.cues),
        "visibility_pct": None if a is None else round(a.visibility_pct, 1),
        "urgency": None if a is None else a.urgency.name,
    }


def describe_thermal(find: ThermalFind, geometry: FrameGeometry | None) -> dict[str, object]:
    row = describe(find.detection, geometry)
    row.update(
        peak_c=round(find.peak_c, 2),
        mean_c=round(find.mean_c, 2),
        area_m2=None if find.area_m2 is None else round(find.area_m2, 4),
    )
    return row


def thermal_summary(result: ThermalResult) -> dict[str, float]:
    return {
        "min_c": round(result.min_c, 2),
        "ambient_c": round(result.ambient_c, 2),
        "max_c": round(result.max_c, 2),
    }


def annotate_thermal(temps_c: np.ndarray, rows: list[dict[str, object]]) -> np.ndarray:
    """False colour with a scale; each find's box in its urgency's colour."""
    boxes = []
    for r in rows:
        x, y, w, h = (int(v) for v in r["box"])  # type: ignore[attr-defined]
        urgency = r["urgency"]
        colour = URGENCY_BGR[Urgency[urgency]] if isinstance(urgency, str) else (200, 200, 200)
        boxes.append(((x, y, w, h), f"{urgency or '?'} {r['peak_c']:.1f}C", colour))
    return thermal_picture(temps_c, boxes)


def annotate(image: np.ndarray, rows: list[dict[str, object]]) -> np.ndarray:
    out = image.copy()
    for r in rows:
        x, y, w, h = (int(v) for v in r["box"])  # type: ignore[attr-defined]
        urgency = r["urgency"]
        colour = URGENCY_BGR[Urgency[urgency]] if isinstance(urgency, str) else (200, 200, 200)
        cv2.rectangle(out, (x, y), (x + w, y + h), colour, 2)
        vis = r["visibility_pct"]
        label = f"{urgency or '?'} {vis if vis is not None else '?'}% {'+'.join(r['cues'])}"  # type: ignore[arg-type]
        ty = y - 6 if y > 18 else y + h + 16
        cv2.putText(
            out, label, (x + 2, ty), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA
        )
        cv2.putText(out, label, (x + 2, ty), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1, cv2.LINE_AA)
    return out


class _Output:
    """Prints each image's or video frame's detections, as text or JSON lines."""

    def __init__(self, as_json: bool) -> None:
        self.as_json = as_json

    def frame(
        self,
        name: str,
        rows: list[dict[str, object]],
        ms: float,
        video_at: tuple[int, float] | None = None,
        thermal: dict[str, float] | None = None,
    ) -> None:
        """``video_at``: a video frame's index and time in seconds; None: an image.
        ``thermal``: a thermal picture's min, ambient and max temperatures."""
        if self.as_json:
            doc: dict[str, object] = {"image": name}
            if video_at is not None:
                doc.update(frame=video_at[0], t_s=round(video_at[1], 3))
            if thermal is not None:
                doc.update(thermal=thermal)
            doc.update(ms=round(ms, 1), detections=rows)
            print(json.dumps(doc))
            return
        if video_at is not None and not rows:
            return  # a video's empty frames: counted in its summary line
        where = name if video_at is None else f"{name} frame {video_at[0]} ({video_at[1]:.1f} s)"
        temps = (
            ""
            if thermal is None
            else f", {thermal['min_c']:.1f}..{thermal['max_c']:.1f} °C, "
            f"ambient {thermal['ambient_c']:.1f} °C"
        )
        print(f"{where}: {len(rows)} detection(s), {ms:.0f} ms{temps}")
        for r in rows:
            vis = r["visibility_pct"]
            vis_txt = "   ?  " if vis is None else f"{vis:5.1f}%"
            peak = f" peak {r['peak_c']:.1f} °C" if "peak_c" in r else ""
            print(
                f"  box {r['box']} score {r['score']:.2f} {vis_txt} {r['urgency'] or '?':8s} "
                f"cues {','.join(r['cues'])}{peak}"  # type: ignore[arg-type]
            )


def _fail(message: str) -> None:
    print(f"rescue-companion: detect: {message}", file=sys.stderr)


def run_detect(
    config: Config | None,
    inputs: Sequence[Path],
    as_json: bool,
    annotate_dir: Path | None,
    every: int = 1,
) -> int:
    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    detector_config = config.detector if config is not None else DetectorConfig()
    colour: list[Detector] = []  # built at the first colour picture (thermal needs none)
    if annotate_dir is not None:
        annotate_dir.mkdir(parents=True, exist_ok=True)
    out = _Output(as_json)
    thermal = _ThermalRun(config, out, annotate_dir)
    failed = 0
    for path in expand(inputs):
        if is_video(path):
            ok = _detect_video(
                make_detector(detector_config), config, path, out, annotate_dir, every
            )
            failed += not ok
            continue
        try:
            temps = read_thermal(path)
            if temps is not None:
                failed += not thermal.detect(path, temps)
                continue
            image = read_image(path)
        except ImageError as exc:
            _fail(str(exc))
            failed += 1
            continue
        if not colour:
            colour.append(make_detector(detector_config, single_images=True))
        detector = colour[0]
        h, w = image.shape[:2]
        geometry = level_geometry(config, w, h) if config is not None else None
        t0 = time.perf_counter()
        dets = detector.detect(image, geometry, 0.0)
        ms = (time.perf_counter() - t0) * 1000.0
        rows = [describe(d, geometry) for d in dets]
        out.frame(str(path), rows, ms)
        if annotate_dir is not None:
            target = annotate_dir / (path.stem + ".png")
            if not cv2.imwrite(str(target), annotate(image, rows)):
                _fail(f"cannot write {target}")
                failed += 1
    return 2 if failed else 0


class _ThermalRun:
    """Thermal pictures: a frames folder's ``<unix_time_us>.png`` files are one stream
    (one detector, their names' times: the fading imprint test needs time); any
    other thermal picture is alone (a detector of its own)."""

    def __init__(self, config: Config | None, out: _Output, annotate_dir: Path | None) -> None:
        self.params = config.thermal.detector if config and config.thermal else None
        self.config = config
        self.out = out
        self.annotate_dir = annotate_dir
        self.streams: dict[Path, ThermalDetector] = {}

    def _detector(self, path: Path) -> tuple[ThermalDetector, float]:
        if path.suffix.lower() == ".png" and path.stem.isdigit():
            t_s = int(path.stem) / 1e6
            if path.parent not in self.streams:
                self.streams[path.parent] = ThermalDetector(self.params)
            return self.streams[path.parent], t_s
        return ThermalDetector(self.params), 0.0

    def detect(self, path: Path, temps: np.ndarray) -> bool:
        """Detect on one thermal picture; False if its annotated copy cannot be written."""
        h, w = temps.shape
        geometry = thermal_geometry(self.config, w, h) if self.config is not None else None
        detector, t_s = self._detector(path)
        t0 = time.perf_counter()
        result = detector.analyse(temps, geometry, t_s)
        ms = (time.perf_counter() - t0) * 1000.0
        rows = [describe_thermal(f, geometry) for f in result.finds]
        self.out.frame(str(path), rows, ms, thermal=thermal_summary(result))
        if self.annotate_dir is not None:
            target = self.annotate_dir / (path.stem + ".png")
            if not cv2.imwrite(str(target), annotate_thermal(temps, rows)):
                _fail(f"cannot write {target}")
                return False
        return True


class _AnnotatedVideo:
    """``DIR/<name>.mp4``, opened at the first frame (its size); ``ok`` is False once
    it could not be opened (said once on stderr)."""

    def __init__(self, target: Path, fps: float) -> None:
        self.target = target
        self.fps = fps
        self.ok = True
        self._writer: cv2.VideoWriter | None = None

    def write(self, image: np.ndarray, rows: list[dict[str, object]]) -> None:
        if not self.ok:
            return
        if self._writer is None:
            h, w = image.shape[:2]
            fourcc = cv2.VideoWriter.fourcc(*"mp4v")
            self._writer = cv2.VideoWriter(str(self.target), fourcc, self.fps, (w, h))
            if not self._writer.isOpened():
                _fail(f"cannot write {self.target}")
                self.ok = False
                return
        self._writer.write(annotate(image, rows))

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()


def _detect_video(
    detector: Detector,
    config: Config | None,
    path: Path,
    out: _Output,
    annotate_dir: Path | None,
    every: int,
) -> bool:
    """Detect on every ``every``-th frame of a video file; False if the file could not
    be opened, had frames that did not decode, was cut short or its annotated copy
    could not be written."""
    try:
        source = VideoFileSource(path, fallback_fps=10.0)
    except CameraError as exc:
        _fail(str(exc))
        return False
    copy = (
        None
        if annotate_dir is None
        else _AnnotatedVideo(annotate_dir / (path.stem + ".mp4"), source.fps / every)
    )
    geometry: FrameGeometry | None = None
    with_people = 0
    times: list[float] = []
    try:
        while True:
            try:
                frame = source.read(0.0)
            except EndOfStream:
                break
            if frame.index % every:
                continue
            image = frame.image
            if config is not None and geometry is None:
                geometry = level_geometry(config, image.shape[1], image.shape[0])
            t_s = frame.index / source.fps
            t0 = time.perf_counter()
            dets = detector.detect(image, geometry, t_s)
            times.append((time.perf_counter() - t0) * 1000.0)
            rows = [describe(d, geometry) for d in dets]
            with_people += bool(rows)
            out.frame(str(path), rows, times[-1], (frame.index, t_s))
            if copy is not None:
                copy.write(image, rows)
    finally:
        source.close()
        if copy is not None:
            copy.close()
    frames, expected = source.frames_read, source.frames_in_header
    if frames == 0:
        _fail(f"{path}: no frame OpenCV can decode")
        return False
    if not out.as_json:
        ms = f", median {statistics.median(times):.0f} ms a frame" if times else ""
        print(
            f"{path}: {frames} frames, {len(times)} detected (every {every}), "
            f"{with_people} with detections{ms}"
        )
    ok = copy is None or copy.ok
    if source.frames_corrupt:
        _fail(
            f"{path}: {source.frames_corrupt} of its {frames} frames could not be decoded (skipped)"
        )
        ok = False
    # Some containers only estimate their frame count (from duration x rate): a few
    # frames short is not a cut file.
    if expected > 0 and expected - frames > max(1, expected // 50):
        _fail(f"{path}: ended after {frames} of the {expected} frames its header gives")
        ok = False
    return ok
