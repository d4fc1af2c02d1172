"""Thermal detector on the real radiometric photos (FLIR R-JPEGs read with exiftool).

Data: ../shared/data/images. people_thermal/: four radiometric photos of people,
each person a point counted by eye (a face; the man in the water: his head, his
hands are part of the same find). A person is found when a find's box holds their
point; a find holding no person is false. thermal_radiometric/ (eight photos of
warm things that are not people) and negatives/wm_termografia_building_ir.jpg:
every find is false. negatives/tdp_IMG_0022_dog_only_thermal.jpg is a false-colour
picture: refused as not radiometric, it cannot give a detection. Photos have no
geometry: the detector's photo size prior (a whole body = photo_body_share of the
frame) gives visibility and urgency. Targets (issue 41): every person found, the
man in the water as one `warm_part` find, CRITICAL; no find on the nine negatives.
Time: ``ThermalDetector.analyse`` on 160x120 frames (the Lepton-sized street photo
and the busy seated group, raw size 160x120), with the Lepton's geometry on the
default mount (a level rover) and without, on one core; target 5 ms a frame. The
machine is shared: the 95th percentile moves with the others' load (the 1-minute
load average during the run is given).

Where the targets are not met, and why (2026-11-28): the laboratory group, the
seated group and the two people in the street are each one find over several
people (people closer than the merge gap, 6 % of a photo's width, are one find:
the gap that makes the man's head and cold hands one find). The dog beside the man
in the water is found (its eyes and muzzle read 27 °C, as his head does: an animal
cannot be told from a person by temperature). wm03: a duck's head reads 23 °C over
9 °C water, as the street's faces at night read 22-23 °C: found. wm13: a bowl of
water at 35 °C, person-sized, at skin temperature and not flat: found.
wm10 (until 2026-11-29): a 34 °C object cut by the frame's top edge (three rows
in view) at skin temperature was found; a find cut by a photo's edge that reaches
less than 2 % of the picture into it (``photo_min_cut_share``) is now a sliver of
something beyond it and is not judged (on a rover those rows see no floor anyway).
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from companion.calibration import camera_model
from companion.config import Config, ThermalConfig
from companion.sources.flir import FlirError, NotRadiometric, read_flir
from companion.vision.base import FrameGeometry
from companion.vision.thermal import ThermalDetector, ThermalResult
from companion.vision.visibility import assess
from fusion.types import PoseSample

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "images"
# Each person's point (u, v) in the raw thermal image's pixels, counted by eye.
PEOPLE: dict[str, list[tuple[int, int]]] = {
    "wm_infrared_people_in_laboratory.jpg": [(28, 39), (92, 43), (131, 45), (156, 41), (88, 81)],
    "wm_videocamera_termica_seated_group.jpg": [
        (3, 38),
        (37, 31),
        (46, 37),
        (72, 24),
        (72, 40),
        (96, 40),
        (119, 26),
        (142, 38),
        (150, 23),
    ],
    "wm_thermographie_de_rue_night.jpg": [(80, 50), (93, 47)],
    "wm_man_in_water_ir.jpg": [(328, 215)],
}
MAN_IN_WATER = "wm_man_in_water_ir.jpg"
NEGATIVES = [
    *sorted((DATA / "thermal_radiometric").glob("*.jpg")),
    DATA / "negatives" / "wm_termografia_building_ir.jpg",
    DATA / "negatives" / "tdp_IMG_0022_dog_only_thermal.jpg",
]
TIMED = ("wm_thermographie_de_rue_night.jpg", "wm_videocamera_termica_seated_group.jpg")


def _holds(box: tuple[int, int, int, int], point: tuple[int, int]) -> bool:
    x, y, w, h = box
    return x <= point[0] < x + w and y <= point[1] < y + h


def _people(figures: dict[str, object]) -> None:
    want = found = false = 0
    for name, points in PEOPLE.items():
        path = DATA / "people_thermal" / name
        result = ThermalDetector().analyse(read_flir(path).temps_c, None, 0.0)
        boxes = [f.detection.bbox_xywh_px for f in result.finds]
        got = sum(any(_holds(b, p) for b in boxes) for p in points)
        wrong = sum(not any(_holds(b, p) for p in points) for b in boxes)
        want, found, false = want + len(points), found + got, false + wrong
        figures[f"{name}: people found / expected, finds, false finds"] = (
            f"{got}/{len(points)}, {len(boxes)}, {wrong} ({_ambient(result)})"
        )
        if name == MAN_IN_WATER:
            figures["man in water: finds over him, cues, urgency"] = _man(result, points[0])
    figures["people found / expected (4 photos)"] = f"{found}/{want}"
    figures["false finds on the people photos"] = false


def _ambient(result: ThermalResult) -> str:
    return f"ambient {result.ambient_c:.1f} °C, max {result.max_c:.1f} °C"


def _man(result: ThermalResult, head: tuple[int, int]) -> str:
    over = [f for f in result.finds if _holds(f.detection.bbox_xywh_px, head)]
    if not over:
        return "not found"
    det = over[0].detection
    a = assess(det, None)
    urgency = "?" if a is None else f"{a.urgency.name} ({a.visibility_pct:.1f} % of a body)"
    return f"{len(over)}, {'+'.join(det.cues)}, {urgency}, peak {over[0].peak_c:.1f} °C"


def _negatives(figures: dict[str, object]) -> None:
    total = 0
    for path in NEGATIVES:
        try:
            result = ThermalDetector().analyse(read_flir(path).temps_c, None, 0.0)
        except NotRadiometric:
            figures[f"{path.name}: finds"] = "refused: not radiometric (false colour)"
            continue
        except FlirError as exc:
            figures[f"{path.name}: finds"] = f"unreadable: {exc}"
            continue
        total += len(result.finds)
        what = ", ".join(
            f"{f.peak_c:.1f} °C {f.detection.visible_area_px:.0f} px" for f in result.finds
        )
        figures[f"{path.name}: finds"] = f"{len(result.finds)}" + (f" ({what})" if what else "")
    figures["finds on the nine negatives"] = total


def _lepton_geometry() -> FrameGeometry:
    config = Config()
    cam = camera_model(ThermalConfig())
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return FrameGeometry.from_pose(cam, pose, config.geolocation)


def _timing(figures: dict[str, object]) -> None:
    cv2.setNumThreads(1)
    geometry = _lepton_geometry()
    for name in TIMED:
        temps = read_flir(DATA / "people_thermal" / name).temps_c
        assert temps.shape == (120, 160), temps.shape
        rng = np.random.default_rng(0)
        for label, geo in (("photo", None), ("Lepton geometry", geometry)):
            detector = ThermalDetector()
            times = []
            for i in range(400):
                frame = temps + rng.normal(0.0, 0.05, temps.shape).astype(np.float32)
                t0 = time.perf_counter()
                detector.analyse(frame, geo, i / 8.7)
                times.append((time.perf_counter() - t0) * 1000.0)
            times.sort()
            figures[f"ms per 160x120 frame, {name.split('_')[1]} ({label}): median, p95"] = (
                f"{statistics.median(times):.2f}, {times[int(0.95 * len(times))]:.2f}"
            )


def run() -> dict[str, object]:
    figures: dict[str, object] = {}
    if not DATA.is_dir():
        return {"skipped": f"no real data at {DATA}"}
    _people(figures)
    _negatives(figures)
    _timing(figures)
    figures["load average (1 min) after the timing, 2 cores"] = round(os.getloadavg()[0], 2)
    return figures
