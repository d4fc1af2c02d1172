"""``rescue-companion detect``: the perception step on image files.

For each image: every detection's box ``[x, y, w, h]`` in pixels, score, cues,
visibility in percent and urgency; ``--json`` prints one JSON object per image.
Without ``--config`` (a photo of unknown geometry) visibility is measured against
the body's own extent in the image. With a config, the frame is taken as seen by
that camera, on its mount, from a level vehicle on a flat floor: visibility is
then measured against a whole lying adult at the detection's floor point.

An unreadable or truncated image is named on stderr and skipped; the exit status
is then 2.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from companion.config import Config, DetectorConfig
from companion.errors import CompanionError
from companion.vision import Detector, FrameGeometry, assess, make_detector
from fusion.types import Detection, PoseSample, Urgency

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"}
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
    if data[:2] == b"\xff\xd8" and not data.rstrip(b"\x00").endswith(b"\xff\xd9"):
        raise ImageError(f"{path}: truncated JPEG (no end-of-image marker)")
    if data[:8] == b"\x89PNG\r\n\x1a\n" and b"IEND" not in data[-16:]:
        raise ImageError(f"{path}: truncated PNG (no IEND chunk)")
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise ImageError(f"{path}: not an image OpenCV can decode")
    return image


def expand(inputs: Sequence[Path]) -> Iterator[Path]:
    """Files as given; folders as their image files, sorted."""
    for p in inputs:
        if p.is_dir():
            yield from sorted(f for f in p.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
        else:
            yield p


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


def run_detect(
    config: Config | None, inputs: Sequence[Path], as_json: bool, annotate_dir: Path | None
) -> int:
    detector_config = config.detector if config is not None else DetectorConfig()
    detector: Detector = make_detector(detector_config, single_images=True)
    if annotate_dir is not None:
        annotate_dir.mkdir(parents=True, exist_ok=True)
    failed = 0
    for path in expand(inputs):
        try:
            image = read_image(path)
        except ImageError as exc:
            print(f"rescue-companion: detect: {exc}", file=sys.stderr)
            failed += 1
            continue
        h, w = image.shape[:2]
        geometry = level_geometry(config, w, h) if config is not None else None
        t0 = time.perf_counter()
        dets = detector.detect(image, geometry, 0.0)
        ms = (time.perf_counter() - t0) * 1000.0
        rows = [describe(d, geometry) for d in dets]
        if as_json:
            print(json.dumps({"image": str(path), "ms": round(ms, 1), "detections": rows}))
        else:
            print(f"{path}: {len(rows)} detection(s), {ms:.0f} ms")
            for r in rows:
                vis = r["visibility_pct"]
                vis_txt = "   ?  " if vis is None else f"{vis:5.1f}%"
                print(
                    f"  box {r['box']} score {r['score']:.2f} {vis_txt} {r['urgency'] or '?':8s} "
                    f"cues {','.join(r['cues'])}"  # type: ignore[arg-type]
                )
        if annotate_dir is not None:
            out = annotate_dir / (path.stem + ".png")
            if not cv2.imwrite(str(out), annotate(image, rows)):
                print(f"rescue-companion: detect: cannot write {out}", file=sys.stderr)
                failed += 1
    return 2 if failed else 0
