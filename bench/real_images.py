"""Real images: person detection on real frames, beside HOG and classic.

Data: ../shared/data/images (beside the checkout). real_falls: 24 frames of real
people (11 lying on the floor) with boxes; a detection hits a box when IoU >= 0.3
or its centre lies inside the box (the data's README). people_rgb: 5 photos whose
people are counted by eye (2 are mannequins, counted as people). negatives: 6
photos without people (debris, gravel, bricks, an empty room, thermal): every
detection there is false. Each backend runs on one core (cv2.setNumThreads(1);
the models use one LiteRT thread), without a camera geometry (photos have no pose),
so visibility is measured against the body's own extent.

Targets (issue 14): recall on lying people >= 0.95, precision >= 0.95, no false
detection on the negatives; the whole perception step <= 50 ms median per 640x480
frame on one core (the real_falls frames are 640x360; section vision times 640x480
rover frames); peak RSS of a process with the models loaded <= 400 MB (the
whole companion stays under that with its other threads: bench/e2e.py). Each photo
is scored as ``rescue-companion detect`` sees it, alone: every extra detector pass
runs on it (the two turned frames; without a geometry, a zoomed tile of the
frame's centre). ``ms_median`` is the live schedule, where one extra pass runs per
frame, taking turns, and the face and palm detectors take turns too (a live camera
sees a body on many frames), timed on the same frames; ``photo_ms_median`` is the
single-photo time with every pass and both part detectors. On the virtual machine
of 2026-11-26/27 the same code's medians varied by up to 20 ms from run to run (compare
``people`` and ``people_enhanced``, which do the same work on these bright frames).
``people_enhanced`` enhances dark frames (mean luma under
0.25) before the models. ``people_lite`` is ``people`` with the lite landmark
model (``detector.pose_landmarks = "lite"``; full is the default since 2026-11-28):
~4 ms less per body found, the ratio below. None of the 24 real frames is dark, so ``dark:`` repeats
the real_falls scoring on the same frames made dark as in an unlit warehouse
(light scaled to 12 %, a gamma of 1.3, Gaussian sensor noise of sigma 3 grey
levels, seeded), with and without enhancement. ``people, 2 model threads`` is the
default's live schedule with ``detector.model_threads = 2`` on two cores (every
other figure is one core's): for a Pi that cannot keep its frame rate on one.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.commands.detect import read_image
from companion.config import DetectorConfig
from companion.vision.backends import make_detector
from companion.vision.base import Detector, DetectorUnavailable
from fusion.types import Detection

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "images"
FALLS = DATA / "real_falls"
# People counted by eye in people_rgb (mannequins count: a detector should find them).
PEOPLE_RGB = {
    "uvify_mannequins_standing_indoor_hall.png": 2,
    "uvify_mannequin_child_standing_indoor.png": 1,
    "intel_worker_zone_frame030_warehouse.png": 1,
    "skimage_astronaut.png": 1,
    "skimage_camera_gray.png": 1,
}
BACKENDS = {
    "people": DetectorConfig(backend="people", enhance=False),
    "people_enhanced": DetectorConfig(backend="people", enhance=True),
    "people_lite": DetectorConfig(backend="people", enhance=False, pose_landmarks="lite"),
    "hog": DetectorConfig(backend="hog", enhance=False),
    "classic": DetectorConfig(backend="classic", enhance=True),
}


def hits_box(det: Detection, box: list[float]) -> bool:
    x, y, w, h = box
    dx, dy, dw, dh = det.bbox_xywh_px
    cx, cy = dx + dw / 2, dy + dh / 2
    if x <= cx <= x + w and y <= cy <= y + h:
        return True
    ix = max(0.0, min(x + w, dx + dw) - max(x, dx))
    iy = max(0.0, min(y + h, dy + dh) - max(y, dy))
    inter = ix * iy
    return inter / (w * h + dw * dh - inter) >= 0.3


def match(dets: list[Detection], boxes: list[list[float]]) -> tuple[list[Detection | None], int]:
    """The detection that found each box (None if none did), and the false detections."""
    found_by: list[Detection | None] = [None] * len(boxes)
    false = 0
    for d in dets:
        j = next(
            (i for i, b in enumerate(boxes) if found_by[i] is None and hits_box(d, b)),
            None,
        )
        if j is None:
            false += 1
        else:
            found_by[j] = d
    return found_by, false


def darken(image: np.ndarray, seed: int) -> np.ndarray:
    """The frame as an unlit room would show it: 12 % light, gamma 1.3, sensor noise."""
    rng = np.random.default_rng(seed)
    dark = 255.0 * (image.astype(np.float64) / 255.0) ** 1.3 * 0.12
    dark += rng.normal(0.0, 3.0, image.shape)
    return np.clip(dark, 0, 255).astype(np.uint8)


def score_falls(detector: Detector, dark: bool = False) -> dict[str, Any]:
    gt = json.loads((FALLS / "gt.json").read_text())
    fp = found = found_lying = people = lying = 0
    times: list[float] = []
    for rel, truth in sorted(gt.items()):
        img = read_image(FALLS / rel)
        if dark:
            img = darken(img, seed=len(times))
        t0 = time.perf_counter()
        dets = detector.detect(img, None, 0.0)
        times.append((time.perf_counter() - t0) * 1000.0)
        found_by, false = match(dets, truth["people"])
        matched = [d is not None for d in found_by]
        fp += false
        people += len(matched)
        found += sum(matched)
        lying += sum(truth["lying"])
        found_lying += sum(m and ly for m, ly in zip(matched, truth["lying"], strict=True))
    return {
        "recall_lying": found_lying / lying,
        "recall_all": found / people,
        "precision": found / (found + fp) if found + fp else 1.0,
        "false": fp,
        "ms_median": statistics.median(times),
    }


def count_photos(detector: Detector) -> dict[str, Any]:
    found = want = false_neg = 0
    for name, n in PEOPLE_RGB.items():
        path = DATA / "people_rgb" / name
        if path.exists():
            found += min(n, len(detector.detect(read_image(path), None, 0.0)))
            want += n
    for path in sorted((DATA / "negatives").iterdir()):
        false_neg += len(detector.detect(read_image(path), None, 0.0))
    return {"people_rgb_found": f"{found}/{want}", "negatives_false": false_neg}


# VmHWM, not getrusage's ru_maxrss: Linux keeps ru_maxrss across exec, so a child
# forked from this (large) benchmark process reported this process's resident set
# (377-418 MB until 2026-11-27, against 175 MB of its own).
_RSS_SCRIPT = """
import re, sys, cv2
from companion.config import Config
from companion.vision.backends import make_detector
cv2.setNumThreads(1)
det = make_detector(Config().detector)
det.detect(cv2.imread(sys.argv[1]), None, 0.0)
status = open("/proc/self/status").read()
print(int(re.search(r"VmHWM:\\s+(\\d+) kB", status).group(1)) / 1024.0)
"""


def peak_rss_mb(image: Path) -> float:
    """Peak RSS of a fresh process that loads the default detector and runs one frame
    (the companion's own imports and the models: what the models add to it)."""
    out = subprocess.run(
        [sys.executable, "-c", _RSS_SCRIPT, str(image)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    )
    return float(out.stdout.strip().splitlines()[-1])


def two_threads_ms() -> float | str:
    """The live schedule's median ms a frame with ``detector.model_threads = 2``, on two
    cores (``python -m bench`` pins this process to one: widened for this alone)."""
    cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
    every = set(range(os.cpu_count() or 1))
    if len(every) < 2 or not hasattr(os, "sched_setaffinity"):
        return "not measured: one CPU"
    try:
        os.sched_setaffinity(0, every)
    except OSError as exc:  # CPUs this process may not use (a container's cpuset)
        return f"not measured: {exc.strerror}"
    try:
        live = make_detector(DetectorConfig(backend="people", model_threads=2))
        return float(score_falls(live)["ms_median"])
    finally:
        os.sched_setaffinity(0, cpus)


def run() -> dict[str, object]:
    if not FALLS.exists():
        return {"skipped": f"no data at {FALLS}"}
    cv2.setNumThreads(1)
    figures: dict[str, object] = {}
    medians = {}
    for name, cfg in BACKENDS.items():
        try:
            det = make_detector(cfg, single_images=True)
            live = make_detector(cfg)
        except DetectorUnavailable as exc:
            figures[f"{name}: unavailable"] = str(exc)
            continue
        falls = score_falls(det)
        photos = count_photos(det)
        falls["photo_ms_median"] = falls.pop("ms_median")
        falls["ms_median"] = medians[name] = score_falls(live)["ms_median"]
        for k, v in {**falls, **photos}.items():
            figures[f"{name}: {k}"] = v
        if name.startswith("people"):
            dark = score_falls(det, dark=True)
            dark["ms_median"] = score_falls(live, dark=True)["ms_median"]
            for k in ("recall_lying", "recall_all", "precision", "ms_median"):
                figures[f"{name}: dark: {k}"] = dark[k]
    figures["people, 2 model threads: ms_median"] = two_threads_ms()
    first = sorted((FALLS / "frames").iterdir())[0]
    figures["default detector loaded + one frame: peak RSS MB"] = peak_rss_mb(first)
    if "people" in medians:
        for other in ("people_lite", "hog", "classic"):
            if other in medians:
                figures[f"time ratio {other}/people"] = medians[other] / medians["people"]
    return figures


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
