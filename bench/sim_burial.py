"""Burial in the simulator: the default detector's recall and urgency per level, beside the real burial benchmark.

Seeded victims drawn as 3-D bodies (scenarios.body3d: postures on the back, side,
face down and curled; adults and children; skin very dark to very pale; plain,
patterned, hi-vis and dusty clothes; every other one in short sleeves) lie on the
simulated warehouse floor, each buried by a slab (scenarios.generate.bury) until
about 100, 50, 20 or 5 % of its footprint stays uncovered. Each is seen from the
rover's camera (0.3 m up, 12 deg down) at 1.5, 2.5 and 3.5 m from four bearings,
three frames per view as live (the detector's extra passes take turns over frames),
with the camera geometry built from the pose as the pipeline does. A view counts
when the renderer shows at least 300 pixels of the body; it is found when a
detection's floor point lies within 1 m of the body's centre or of its visible
part. Urgency is judged on the found views: 100 % LIGHT, 50 % LIGHT or MEDIUM (the
boundary), 20 % MEDIUM, 5 % CRITICAL.

Compare with the real burial benchmark (section burial): if the simulator were
much easier than real images it would hide the detector's limits.

Since 2026-11-27 a body's visible share is capped at the share of its main joints
whose heatmaps see them (never below a quarter). From the rover's camera the
simulator's whole bodies give the landmark model's heatmaps weak peaks on most
joints (logits -0.5 to -1.2, as the covered joints of real people do; uncovered
real joints peak at a median +0.17), so more than a third of the uncovered views
read MEDIUM here (urgency right at 100 %: 0.909 before the cap), while those at
20 % read right more often (0.27 before). That is the low view more than the
bodies: the same uncovered bodies seen from 0.75 m up, about where the real frames
were taken, see 0.77 of their main joints (a median over the views), from 0.3 m
0.62 (docs/VISION.md, "The camera's height"). Those figures are of the lite
landmark model; with full, the default since 2026-11-28, the uncovered views read
LIGHT more often (urgency right at 100 %: 0.69 against lite's 0.60 on the same
views), those at 20 % a little less often (0.67 against 0.71).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.config import DetectorConfig
from companion.vision.backends import make_detector
from companion.vision.base import FrameGeometry
from companion.vision.visibility import assess
from fusion.camera import CameraModel
from fusion.errors import GeolocationRejected
from fusion.geolocate import geolocate
from fusion.params import GeolocationParams
from fusion.types import Detection, PoseSample, Urgency
from scenarios.body3d import PATTERNS, POSTURES, SLEEVES, Sleeves
from scenarios.camera import VEHICLE_HEIGHT_M, default_camera, default_thermal_camera
from scenarios.generate import CLOTHING, HAIR, SKIN, TROUSERS, bury
from scenarios.render import Renderer
from scenarios.thermal import ThermalRenderer
from scenarios.world import Victim, World

LEVELS_PCT = (100, 50, 20, 5)
RIGHT_URGENCY = {
    100: {Urgency.LIGHT},
    50: {Urgency.LIGHT, Urgency.MEDIUM},
    20: {Urgency.MEDIUM},
    5: {Urgency.CRITICAL},
}
VICTIMS_PER_LEVEL = 8
RANGES_M = (1.5, 2.5, 3.5)
BEARINGS_RAD = (0.4, 2.0, 3.6, 5.2)
FRAMES_PER_VIEW = 3
MIN_VIEW_PX = 300
GATE_M = 1.0


def _victim(rng: np.random.Generator, sleeves: Sleeves) -> Victim:
    child = rng.random() < 0.2
    pick = lambda palette: palette[int(rng.integers(len(palette)))]  # noqa: E731
    return Victim(
        victim_id=1,
        north_m=5.0,
        east_m=4.0,
        heading_rad=float(rng.uniform(-math.pi, math.pi)),
        height_m=float(rng.uniform(1.1, 1.45) if child else rng.uniform(1.5, 1.9)),
        skin_rgb=pick(SKIN),
        top_rgb=pick(CLOTHING),
        trousers_rgb=pick(TROUSERS),
        hair_rgb=pick(HAIR),
        posture=POSTURES[int(rng.integers(len(POSTURES)))],
        pattern=PATTERNS[int(rng.integers(len(PATTERNS)))],
        dust=float(rng.uniform(0.0, 0.6)),
        left_arm_rad=math.radians(float(rng.uniform(0, 80))),
        right_arm_rad=math.radians(float(rng.uniform(0, 80))),
        sleeves=sleeves,
    )


def measure_level(level_pct: int, seed: int = 0) -> dict[str, Any]:
    rng = np.random.default_rng([seed, level_pct])
    camera = default_camera()
    params = GeolocationParams()
    detector = make_detector(DetectorConfig())
    views = found = right = 0
    for k in range(VICTIMS_PER_LEVEL):
        v = _victim(rng, SLEEVES[k % 2])
        debris = tuple(bury(rng, v, float(level_pct))) if level_pct < 100 else ()
        world = World(size_m=(10.0, 8.0), debris=debris, victims=(v,), seed=seed * 100 + k)
        v = world.victims[0]
        renderer = Renderer(world, camera, seed=k)
        for rng_m in RANGES_M:
            for bearing in BEARINGS_RAD:
                pose = _facing(v, rng_m, bearing)
                res = renderer.render(pose, frame_key=views)
                if res.visible_px.get(v.victim_id, 0) < MIN_VIEW_PX:
                    continue
                views += 1
                geometry = FrameGeometry.from_pose(camera, pose, params)
                hit = None
                for _ in range(FRAMES_PER_VIEW):
                    for d in detector.detect(res.image, geometry, 0.0):
                        try:
                            fix = geolocate(camera, pose, d.u_px, d.v_px, params)
                        except GeolocationRejected:
                            continue  # as the pipeline: no floor point, no observation
                        err = min(
                            math.hypot(fix.north_m - v.north_m, fix.east_m - v.east_m),
                            math.hypot(
                                fix.north_m - v.visible_north_m, fix.east_m - v.visible_east_m
                            ),
                        )
                        if err < GATE_M and hit is None:
                            hit = d
                if hit is not None:
                    found += 1
                    a = assess(hit, geometry)
                    right += int(a is not None and a.urgency in RIGHT_URGENCY[level_pct])
    return {
        "views": views,
        "recall": round(found / views, 3) if views else None,
        "urgency_right": round(right / found, 3) if found else None,
    }


THERMAL_LEVELS_PCT = (50, 20, 5)
MIN_THERMAL_VIEW_PX = 20  # the colour views' 300 pixels at the Lepton's 1/16 pixel count


@dataclass(frozen=True)
class ThermalView:
    """One view of a buried body by the simulated thermal camera."""

    level_pct: int
    victim: Victim  # its truth: visibility_pct, warm_visibility_pct, visible centre
    pose: PoseSample
    camera: CameraModel
    temps_c: np.ndarray  # float32 120 x 160, degrees C
    warm_px: int  # pixels of the body's warmth in the frame
    range_m: float
    bearing_rad: float
    # The frames before it as the rover drives up to it along the bearing (farthest
    # first), ``APPROACH_STEP_M`` apart: (pose, temps_c); none for a first sight.
    approach: tuple[tuple[PoseSample, np.ndarray], ...] = ()


APPROACH_STEP_M = 0.3  # a frame every 0.3 m as the rover drives up to a view


def thermal_views(level_pct: int, seed: int = 0, approach_m: float = 0.0) -> Iterator[ThermalView]:
    """The thermal burial benchmark's views at one visible share: the colour
    benchmark's bodies and slabs for that level (the same random draws), from every
    range and bearing where at least MIN_THERMAL_VIEW_PX warm pixels show; with
    ``approach_m``, each with the frames of the last ``approach_m`` driven up to it."""
    rng = np.random.default_rng([seed, level_pct])
    camera = default_thermal_camera()
    key = 0
    for k in range(VICTIMS_PER_LEVEL):
        v = _victim(rng, SLEEVES[k % 2])
        debris = tuple(bury(rng, v, float(level_pct))) if level_pct < 100 else ()
        world = World(size_m=(10.0, 8.0), debris=debris, victims=(v,), seed=seed * 100 + k)
        v = world.victims[0]
        renderer = ThermalRenderer(world, camera, seed=k)
        for rng_m in RANGES_M:
            for bearing in BEARINGS_RAD:
                pose = _facing(v, rng_m, bearing)
                shot = renderer.render(pose, 1.0, frame_key=key)
                key += 1
                px = shot.warm_px.get(v.victim_id, 0)
                if px < MIN_THERMAL_VIEW_PX:
                    continue
                approach = []
                for j in range(round(approach_m / APPROACH_STEP_M), 0, -1):
                    before = _facing(v, rng_m + j * APPROACH_STEP_M, bearing)
                    # Their own noise seeds, apart from the views' (which stay as they were).
                    frame = renderer.render(before, 1.0, frame_key=1_000_000 + 16 * key + j)
                    approach.append((before, frame.temps_c))
                yield ThermalView(
                    level_pct, v, pose, camera, shot.temps_c, px, rng_m, bearing, tuple(approach)
                )


def _facing(v: Victim, range_m: float, bearing_rad: float) -> PoseSample:
    """The rover ``range_m`` from the victim's visible centre, facing it on that bearing."""
    n = v.visible_north_m - range_m * math.cos(bearing_rad)
    e = v.visible_east_m - range_m * math.sin(bearing_rad)
    return PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, bearing_rad)


def measure_thermal_level(
    level_pct: int,
    detect: Callable[[list[tuple[np.ndarray, FrameGeometry]]], list[Detection]],
    urgency: Callable[[Detection, FrameGeometry], Urgency | None],
    seed: int = 0,
    approach_m: float = 0.0,
) -> dict[str, Any]:
    """Recall and urgency of a thermal detector over ``thermal_views(level_pct,
    seed, approach_m)``: ``detect(frames)`` gives its detections in the last of the
    frames ((temps_c, geometry), the approach first), ``urgency(detection,
    geometry)`` the class the pipeline would give the find."""
    params = GeolocationParams()
    views = found = right = 0
    for view in thermal_views(level_pct, seed, approach_m):
        views += 1
        v = view.victim
        geometry = FrameGeometry.from_pose(view.camera, view.pose, params)
        frames = [
            (temps_c, FrameGeometry.from_pose(view.camera, pose, params))
            for pose, temps_c in view.approach
        ]
        hit = None
        for d in detect([*frames, (view.temps_c, geometry)]):
            try:
                fix = geolocate(view.camera, view.pose, d.u_px, d.v_px, params)
            except GeolocationRejected:
                continue
            err = min(
                math.hypot(fix.north_m - v.north_m, fix.east_m - v.east_m),
                math.hypot(fix.north_m - v.visible_north_m, fix.east_m - v.visible_east_m),
            )
            if err < GATE_M:
                hit = d
                break
        if hit is not None:
            found += 1
            right += int(urgency(hit, geometry) in RIGHT_URGENCY[level_pct])
    return {
        "views": views,
        "recall": round(found / views, 3) if views else None,
        "urgency_right": round(right / found, 3) if found else None,
    }


def run() -> dict[str, Any]:
    out: dict[str, Any] = {}
    for level in LEVELS_PCT:
        m = measure_level(level)
        out[f"recall at {level} % visible (views: {m['views']})"] = m["recall"]
        out[f"urgency right at {level} % visible"] = m["urgency_right"]
    return out


if __name__ == "__main__":  # pragma: no cover
    for key, value in run().items():
        print(f"{key}: {value}")
