"""Vision figures: time per 640x480 frame, scenario accuracy, real-photo counts.

``run() -> dict`` (collected by ``python -m bench``); ``python -m bench.vision``
prints the dict as JSON. One OpenCV thread (cv2.setNumThreads(1)): "one core".

- timing_ms: median and p90 over synthetic scenes for enhancement (full frame and
  the classic backend's 320 px working size), classic detection (including its own
  enhancement), visibility, and the whole vision step; hog for comparison. The
  whole step again on rover views (``rover_vision_step``): frames rendered by the
  scenarios package from the rover's camera (0.3 m up, grazing view) around the
  ``mixed`` victims, with the geometry built from the pose as the pipeline does.
- scenarios: for each preset of the scenarios package, frames rendered from poses
  that look at each victim from 1.5, 2.5 and 3.5 m (three bearings each; a grid
  over the floor when there are no victims), fixed seeds. Recall = frames where a
  victim with >= 150 visible pixels has a detection within 0.75 m of its visible
  centroid on the floor / such victim-frames; false detections per frame =
  detections matched to no victim (duplicates included); urgency accuracy =
  matched detections whose class equals the world's ground truth.
- photos: detections per image of ../shared/data/images for each backend
  available (no geometry: photos have no pose).
"""

from __future__ import annotations

import json
import math
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.config import DetectorConfig
from companion.vision import FrameGeometry, assess, make_detector
from companion.vision.enhance import Enhancer
from companion.vision.synthetic import make_scene

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "images"
MIN_VISIBLE_PX = 150  # a victim showing fewer pixels is not expected to be found
MATCH_M = 0.75


def _timed(fn: Callable[[int], object], n: int, repeat: int = 3) -> dict[str, float]:
    fn(0)  # warm-up
    times = []
    for _ in range(repeat):
        for i in range(n):
            t0 = time.perf_counter()
            fn(i)
            times.append((time.perf_counter() - t0) * 1e3)
    times.sort()
    return {
        "median_ms": round(statistics.median(times), 2),
        "p90_ms": round(times[int(0.9 * (len(times) - 1))], 2),
    }


def timing() -> dict[str, Any]:
    kinds = ["full", "half", "hand", "two", "debris", "text", "dark", "dark_empty", "empty"]
    scenes = [make_scene(k, s) for k in kinds for s in range(2)]
    n = len(scenes)
    enh = Enhancer()
    small = [cv2.resize(s.image, (320, 240), interpolation=cv2.INTER_AREA) for s in scenes]
    classic = make_detector(DetectorConfig(backend="classic"))
    plain = make_detector(DetectorConfig(backend="classic", enhance=False))
    dets = [classic.detect(s.image, s.geometry, 0.0) for s in scenes]

    def step(i: int) -> None:
        for d in classic.detect(scenes[i].image, scenes[i].geometry, 0.0):
            assess(d, scenes[i].geometry)

    out: dict[str, Any] = {
        "frames": n,
        "enhance_640x480": _timed(lambda i: enh(scenes[i].image), n),
        "enhance_320x240": _timed(lambda i: enh(small[i]), n),
        "classic_detect_with_enhance": _timed(
            lambda i: classic.detect(scenes[i].image, scenes[i].geometry, 0.0), n
        ),
        "classic_detect_without_enhance": _timed(
            lambda i: plain.detect(scenes[i].image, scenes[i].geometry, 0.0), n
        ),
        "visibility": _timed(lambda i: [assess(d, scenes[i].geometry) for d in dets[i]], n),
        "vision_step": _timed(step, n),
    }
    rover = _rover_frames()
    if rover:

        def rover_step(i: int) -> None:
            image, geometry = rover[i]
            for d in classic.detect(image, geometry, 0.0):
                assess(d, geometry)

        out["rover_frames"] = len(rover)
        out["rover_vision_step"] = _timed(rover_step, len(rover))
    if hasattr(cv2, "HOGDescriptor"):
        hog = make_detector(DetectorConfig(backend="hog", enhance=False))
        out["hog_detect"] = _timed(lambda i: hog.detect(scenes[i].image, None, 0.0), 4, 1)
    return out


def _rover_frames() -> list[tuple[np.ndarray, FrameGeometry]]:
    """Rover-camera frames (and their geometry) around the mixed preset's victims."""
    try:
        from scenarios.camera import VEHICLE_HEIGHT_M, default_camera
        from scenarios.render import Renderer
        from scenarios.world import preset
    except ImportError:
        return []
    from fusion.params import GeolocationParams
    from fusion.types import PoseSample

    world = preset("mixed")
    camera = default_camera()
    renderer = Renderer(world, camera, seed=7)
    frames = []
    for k, (n, e, yaw) in enumerate(_poses_for(world)):
        pose = PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, yaw)
        image = renderer.render(pose, frame_key=k).image
        frames.append((image, FrameGeometry.from_pose(camera, pose, GeolocationParams())))
    return frames


# -- scenarios ------------------------------------------------------------------------


def _poses_for(world: Any) -> list[tuple[float, float, float]]:
    """(north, east, yaw) viewpoints: each victim from 3 ranges x 3 bearings."""
    poses = []
    if not world.victims:
        n_max, e_max = world.size_m
        for n in np.linspace(1.0, n_max - 1.0, 4):
            for e in np.linspace(1.0, e_max - 1.0, 3):
                for yaw in (0.0, math.pi / 2, math.pi, -math.pi / 2):
                    poses.append((float(n), float(e), yaw))
        return poses
    for v in world.victims:
        for rng_m in (1.5, 2.5, 3.5):
            for bearing in (0.3, 2.4, 4.4):
                n = v.visible_north_m - rng_m * math.cos(bearing)
                e = v.visible_east_m - rng_m * math.sin(bearing)
                poses.append((n, e, bearing))
    return poses


def scenarios() -> dict[str, Any]:
    try:
        from scenarios.render import Renderer
        from scenarios.world import PRESETS, preset
    except ImportError as exc:
        return {"skipped": f"scenarios package not importable: {exc}"}
    from fusion.errors import GeolocationRejected
    from fusion.geolocate import geolocate
    from fusion.params import GeolocationParams
    from fusion.types import PoseSample
    from scenarios.camera import VEHICLE_HEIGHT_M, default_camera

    params = GeolocationParams()
    camera = default_camera()
    detector = make_detector(DetectorConfig(backend="classic"))
    results: dict[str, Any] = {}
    for name in PRESETS:
        world = preset(name)
        renderer = Renderer(world, camera, seed=7)
        expected = found = false = matched = correct = frames = 0
        for k, (n, e, yaw) in enumerate(_poses_for(world)):
            pose = PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, yaw)
            frame = renderer.render(pose, frame_key=k)
            geometry = FrameGeometry.from_pose(camera, pose, params)
            dets = detector.detect(frame.image, geometry, 0.0)
            frames += 1
            in_view = {vid for vid, px in frame.visible_px.items() if px >= MIN_VISIBLE_PX}
            expected += len(in_view)
            hit: set[int] = set()
            for d in dets:
                try:
                    fix = geolocate(camera, pose, d.u_px, d.v_px, params)
                except GeolocationRejected:
                    false += 1
                    continue
                best = min(
                    world.victims,
                    key=lambda v: math.hypot(
                        fix.north_m - v.visible_north_m, fix.east_m - v.visible_east_m
                    ),
                    default=None,
                )
                if (
                    best is None
                    or best.victim_id in hit
                    or math.hypot(
                        fix.north_m - best.visible_north_m, fix.east_m - best.visible_east_m
                    )
                    > MATCH_M
                ):
                    false += 1
                    continue
                hit.add(best.victim_id)
                matched += 1
                a = assess(d, geometry)
                correct += int(a is not None and a.urgency == best.urgency)
            found += len(hit & in_view)
        results[name] = {
            "frames": frames,
            "victim_frames": expected,
            "recall": round(found / expected, 3) if expected else None,
            "false_per_frame": round(false / frames, 3),
            "urgency_accuracy": round(correct / matched, 3) if matched else None,
            "truth": {
                v.victim_id: (round(v.visibility_pct, 1), v.urgency.name) for v in world.victims
            },
        }
    return results


# -- real photos ----------------------------------------------------------------------


def photos() -> dict[str, Any]:
    if not DATA.is_dir():
        return {"skipped": f"{DATA} not found"}
    backends = {"classic": make_detector(DetectorConfig(backend="classic"))}
    if hasattr(cv2, "HOGDescriptor"):
        backends["hog"] = make_detector(DetectorConfig(backend="hog"))
    out: dict[str, Any] = {}
    for folder in ("people_rgb", "people_thermal", "negatives"):
        for path in sorted((DATA / folder).iterdir()):
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if image is None:
                continue
            if image.shape[1] > 960:  # photos up to 1920 px: detect at a camera's size
                f = 960 / image.shape[1]
                image = cv2.resize(image, None, fx=f, fy=f, interpolation=cv2.INTER_AREA)
            out[f"{folder}/{path.name}"] = {
                name: len(det.detect(image, None, 0.0)) for name, det in backends.items()
            }
    return out


def run() -> dict[str, Any]:
    cv2.setNumThreads(1)
    return {"timing": timing(), "scenarios": scenarios(), "photos": photos()}


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
