"""Burial: real people covered by real debris texture, recall and urgency per level.

Data: ../shared/data/images (beside the checkout). Each of the 24 real_falls frames
is buried by a seeded generator: rotated patches cut from the real brick and gravel
photos in negatives (skimage, BSD), each with its own brightness and tint, are laid
over a pile 1.6 times each person's box (so the pile's outline is not a body's)
until about 50, 20 or 5 % of the box stays uncovered (100 %:
the frame as it is). The buried share is measured on the box, not on the body's
own pixels (the data has boxes, no masks), so a level is the body's visible share
only roughly. A detection finds a person as in real_images (IoU >= 0.3 or its
centre inside the box). The urgency a level should give: 100 % LIGHT, 50 % LIGHT or
MEDIUM (the boundary), 20 % MEDIUM, 5 % CRITICAL; it is judged on the found people,
without a camera geometry (photos have no pose), so visibility is measured against
the body's extent as the detector estimates it.

Targets (issue 14): recall >= 0.95 at 50 %, >= 0.8 at 20 %; urgency right in at
least 80 % of the detections.

Read with care: without geometry the body's extent is estimated from its landmarks.
The landmark model's mask fills in the covered part of a body it has found, so by
the mask alone a buried body read as mostly visible (urgency right at 20 %: 0.06,
until 2026-11-27). A body's visible share is now capped at the share of its main
joints whose heatmaps see them (companion/vision/seenparts.py), never below a
quarter: the heatmaps alone make a body MEDIUM, not CRITICAL, so the 5 % level is
judged right only where a small mask or a lone part shows. The cap also holds a
body the landmark model does not confirm (7 of the 16 found at 20 %, 3 of the 24
uncovered): its mask is the whole-frame segmentation, which spreads over debris.
Live, the camera model gives the area a whole lying adult covers at the floor
point, which this benchmark cannot exercise on photos without a pose. The 5 %
recall is what is honest: no model measured here finds a body that small.

Which landmark model: the default is BlazePose full since 2026-11-28 (lite before;
the counts above, dated earlier, are lite's). The ``lite:`` rows run the same
frames with the lite model (``detector.pose_landmarks = "lite"``), the person
detector and every other model unchanged: full's boxes and flags match more of
the buried people, and its heatmaps tell their covered joints more often.

``false_detections``: detections that match no person. The debris patches are small
textured shapes on an indoor scene, and the person detector with its landmark model
fires on some of them (on the whole brick and gravel photos it does not: real_images,
negatives). Some of the people missed at 50 % are such a detection on a patch
beside a body whose legs still show. Their person scores (0.5-0.78), landmark flags,
landmark visibilities and limb proportions overlap those of the buried people found
(measured 2026-11-26), so no rule on them removes these without losing buried people.
Live, one frame's detection becomes a victim only when the tracker has seen it on
several frames (three, with at most two misses between them).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.commands.detect import read_image
from companion.config import DetectorConfig, PoseLandmarks
from companion.vision.backends import make_detector
from companion.vision.base import Detector, DetectorUnavailable
from companion.vision.visibility import assess
from fusion.types import Urgency

from .real_images import DATA, FALLS, match

TEXTURES = ("skimage_brick_gray.png", "skimage_gravel_gray.png")
LEVELS_PCT = (100, 50, 20, 5)
RIGHT_URGENCY = {
    100: {Urgency.LIGHT},
    50: {Urgency.LIGHT, Urgency.MEDIUM},
    20: {Urgency.MEDIUM},
    5: {Urgency.CRITICAL},
}


def bury(
    image: np.ndarray,
    boxes: list[list[float]],
    visible_pct: float,
    textures: list[np.ndarray],
    seed: int,
) -> np.ndarray:
    """``image`` with debris patches over each box until ``visible_pct`` of it shows."""
    rng = np.random.default_rng(seed)
    out = image.copy()
    h_img, w_img = image.shape[:2]
    for x, y, w, h in boxes:
        x0, y0 = max(0, int(x)), max(0, int(y))
        x1, y1 = min(w_img, int(x + w)), min(h_img, int(y + h))
        if x1 <= x0 or y1 <= y0:
            continue
        covered = np.zeros((h_img, w_img), np.uint8)
        box_area = (x1 - x0) * (y1 - y0)
        for _ in range(2000):
            if 100.0 * (1.0 - covered[y0:y1, x0:x1].sum() / box_area) <= visible_pct:
                break
            size = rng.uniform(0.15, 0.45) * max(x1 - x0, y1 - y0)
            # Patches land on a pile 1.6x the box, so its outline is not the body's.
            mx, my = 0.3 * (x1 - x0), 0.3 * (y1 - y0)
            rect = (
                (float(rng.uniform(x0 - mx, x1 + mx)), float(rng.uniform(y0 - my, y1 + my))),
                (float(size * rng.uniform(0.5, 1.5)), float(size * rng.uniform(0.5, 1.0))),
                float(rng.uniform(0.0, 180.0)),
            )
            poly = cv2.boxPoints(rect).astype(np.int32)
            patch = np.zeros((h_img, w_img), np.uint8)
            cv2.fillConvexPoly(patch, poly, 1)
            tex = textures[int(rng.integers(len(textures)))]
            ty = int(rng.integers(0, max(1, tex.shape[0] - h_img)))
            tx = int(rng.integers(0, max(1, tex.shape[1] - w_img)))
            crop = cv2.resize(tex[ty:, tx:], (w_img, h_img)).astype(np.float32)
            tint = rng.uniform(0.5, 1.2) * np.array(
                [rng.uniform(0.7, 1.0), rng.uniform(0.8, 1.0), rng.uniform(0.9, 1.2)], np.float32
            )
            debris = np.clip(crop * tint, 0, 255).astype(np.uint8)
            sel = patch.astype(bool)
            out[sel] = debris[sel]
            covered |= patch
    return out


@dataclass(frozen=True)
class LevelResult:
    """One burial level over every real_falls frame."""

    people: int
    found: int
    false_detections: int
    urgencies: tuple[Urgency, ...]  # one per person found whose urgency could be judged


def measure_level(
    detector: Detector,
    falls_dir: Path,
    gt: dict[str, Any],
    textures: list[np.ndarray],
    level_pct: int,
) -> LevelResult:
    """Bury each frame's people to ``level_pct`` (100: the frame as it is), detect,
    match the detections to the boxes, and judge each found person's urgency without
    a camera geometry."""
    people = found = false = 0
    urgencies: list[Urgency] = []
    for n, (rel, truth) in enumerate(sorted(gt.items())):
        img = read_image(falls_dir / rel)
        if level_pct < 100:
            img = bury(img, truth["people"], level_pct, textures, seed=1000 * level_pct + n)
        found_by, n_false = match(detector.detect(img, None, 0.0), truth["people"])
        false += n_false
        people += len(found_by)
        for d in found_by:
            if d is None:
                continue
            found += 1
            if (a := assess(d, None)) is not None:
                urgencies.append(a.urgency)
    return LevelResult(people, found, false, tuple(urgencies))


def run() -> dict[str, object]:
    if not FALLS.exists():
        return {"skipped": f"no data at {FALLS}"}
    gt = json.loads((FALLS / "gt.json").read_text())
    textures = [read_image(DATA / "negatives" / name) for name in TEXTURES]
    result: dict[str, Any] = {}
    # The default (the full landmark model), then the lite one beside it.
    variants: tuple[tuple[str, PoseLandmarks], ...] = (("", "full"), ("lite: ", "lite"))
    for prefix, landmarks in variants:
        try:
            detector = make_detector(
                DetectorConfig(backend="people", enhance=False, pose_landmarks=landmarks),
                single_images=True,
            )
        except DetectorUnavailable as exc:
            return {"skipped": str(exc)}
        for level in LEVELS_PCT:
            r = measure_level(detector, FALLS, gt, textures, level)
            right = sum(u in RIGHT_URGENCY[level] for u in r.urgencies)
            result[f"{prefix}recall_at_{level}pct"] = r.found / r.people
            result[f"{prefix}urgency_right_at_{level}pct"] = (
                right / len(r.urgencies) if r.urgencies else math.nan
            )
            result[f"{prefix}false_detections_at_{level}pct"] = r.false_detections
    return result


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
