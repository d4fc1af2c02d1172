"""Coverage map: the detectors' range, the map's over- and under-claim against the simulator's truth, its cost per frame and its radio bytes

**Range.** Whole lying adults (bench/sim_burial.py's postures, sizes, skins and
clothes; no debris) on a 20 x 20 m floor, seen from the rover's camera (0.3 m up, 12
deg down) at 1.5-7.5 m from four bearings, three colour frames a view (the extra
passes take turns, as live) or two thermal frames; a view is a find when a
detection's floor point lies within 1 m of the body. Colour in full light and in a
world at 5 % light (the headlight lights the near floor). The share of views found
per range is the detection curve companion/coverage.py uses (COLOUR_LIT, and
COLOUR_DARK, THERMAL: see docs/COVERAGE.md for how they were chosen).

**Claim against truth, per mission of the accuracy suite** (bench/accuracy.py's
worlds, cameras and whole routes at 5 frames/s, the simulator's true poses): the
claim is companion/coverage.py as the service runs it (the footprint of each frame
from a new viewpoint, its luma from the rendered frame); the truth is
scenarios/coverage_truth.py (a cell is seen in a frame when two of its four quarter
points show unoccluded within 7.5 m, by the renderer's own ray casting),
accumulated with the same curve on the same looks. Over the world's floor: *over-claim* = the share
of the cells claimed searched (p >= 0.9 "well", p >= 0.3 "glanced at") that no frame
ever saw; *under-claim* = the share of cells the truth has at p >= 0.3 that the claim
has below 0.3. *Floor searched well* = the share of the floor at p >= 0.9, claim /
truth. Target: over-claim under 10 % of the claimed area in open worlds (no debris
taller than 0.3 m and no warm objects; the others are cluttered: cartons, racking,
machinery), pooled over each kind of world.

**Cost**: ``CoverageMapper.add`` per colour frame (block luma, footprint, grid
update) on one core, median and p95 over the frames that count as a look (a new
viewpoint: about one in three at 5 frames/s and 0.4 m/s; the others cost a
comparison) (target <= 2 ms). **Radio**: the grid's deltas
(5 bytes a changed cell, 20 a message) sent every 10 s of mission, bytes per minute,
before MAVLink framing (the transport is to come).

Each route here is the whole lawnmower search of a 12 x 8 m world, which ends with
nearly every cell looked at from several sides: the over-claim left at the end is
the floor that no viewpoint of the route saw (behind cartons, racking, machinery,
piles and people), and it grows with clutter. The cost was measured with the
machine shared (the load average below; on 2 cores): with less load, 1.7 ms median
(docs/COVERAGE.md).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import multiprocessing
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.accuracy import SUITE, SUITE_FPS, Scenario
from bench.sim_burial import _victim
from companion.config import DetectorConfig
from companion.coverage import COLOUR_LIT, CoverageMapper
from companion.vision.backends import make_detector
from companion.vision.base import FrameGeometry
from companion.vision.thermal import ThermalDetector
from companion.vision.thermal_params import ThermalDetectorParams
from fusion.camera import CameraModel
from fusion.coverage import GLANCED_AT_P, SEARCHED_WELL_P, CoverageGrid
from fusion.errors import GeolocationRejected
from fusion.geolocate import geolocate
from fusion.params import GeolocationParams
from fusion.types import Detection, PoseSample, Sensor
from scenarios.body3d import SLEEVES
from scenarios.camera import VEHICLE_HEIGHT_M, default_camera, default_thermal_camera
from scenarios.coverage_truth import CoverageTruth
from scenarios.motion import Trajectory, TruePose, route_of
from scenarios.render import Renderer
from scenarios.thermal import ThermalRenderer
from scenarios.world import Floor, World

RANGES_M = (1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5)
BEARINGS_RAD = (0.4, 2.0, 3.6, 5.2)
DELTA_PERIOD_S = 10.0
TALL_M = 0.3  # a world with debris this tall (cartons, racking) or warm objects is cluttered


def detection_by_range(kind: str, light: float = 1.0, bodies: int = 6) -> list[float]:
    """The share of views of a whole lying adult found, per range of RANGES_M."""
    params = GeolocationParams()
    rng = np.random.default_rng([7, 0])
    views = np.zeros(len(RANGES_M))
    found = np.zeros(len(RANGES_M))
    camera = default_camera() if kind == "colour" else default_thermal_camera()
    detect: Callable[[np.ndarray, FrameGeometry, float], list[Detection]]
    if kind == "colour":
        detect = make_detector(DetectorConfig()).detect
    else:
        detect = ThermalDetector(ThermalDetectorParams()).detect
    for k in range(bodies):
        v = dataclasses.replace(_victim(rng, SLEEVES[k % 2]), north_m=10.0, east_m=10.0)
        world = World(size_m=(20.0, 20.0), floor=Floor(ambient_light=light), victims=(v,), seed=k)
        v = world.victims[0]
        colour = Renderer(world, camera, seed=k) if kind == "colour" else None
        warm = ThermalRenderer(world, camera, seed=k) if kind != "colour" else None
        key = 0
        for j, r in enumerate(RANGES_M):
            for b in BEARINGS_RAD:
                n, e = v.north_m - r * math.cos(b), v.east_m - r * math.sin(b)
                pose = PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, b)
                geometry = FrameGeometry.from_pose(camera, pose, params)
                hit = False
                for f in range(3 if colour is not None else 2):
                    key += 1
                    t_s = 1.0 + 0.115 * f
                    if colour is not None:
                        frame = colour.render(pose, frame_key=key).image
                    else:
                        assert warm is not None
                        frame = warm.render(pose, t_s, frame_key=key).temps_c
                    for d in detect(frame, geometry, t_s):
                        try:
                            fix = geolocate(camera, pose, d.u_px, d.v_px, params)
                        except GeolocationRejected:
                            continue
                        hit |= math.hypot(fix.north_m - v.north_m, fix.east_m - v.east_m) < 1.0
                views[j] += 1
                found[j] += hit
    return [round(float(x), 3) for x in found / views]


def _pose(tp: TruePose) -> PoseSample:
    return PoseSample(
        0.0, tp.t_s, tp.north_m, tp.east_m, tp.down_m, tp.roll_rad, tp.pitch_rad, tp.yaw_rad
    )


@dataclasses.dataclass
class MissionCoverage:
    over_well: float | None
    over_glanced: float | None
    under: float | None
    floor_well_claim: float
    floor_well_truth: float
    cost_ms: list[float]
    radio_bytes_per_min: float
    frames: int
    cluttered: bool
    counts: tuple[int, int, int, int]  # claimed well, of them never seen; same, glanced at


def measure_mission(scenario: Scenario, duration_s: float | None = None) -> MissionCoverage:
    """The claim, the truth and their comparison for one mission of the suite."""
    world = scenario.make_world()
    camera: CameraModel = scenario.camera()
    trajectory = Trajectory(
        world.start_ne_m, world.start_heading_rad, route_of(world), speed_m_s=0.4, seed=world.seed
    )
    if duration_s is None:
        duration_s = trajectory.duration_s() + 2.0
    geo = GeolocationParams()
    renderer = Renderer(world, camera)
    truth = CoverageTruth(world, camera, reach_m=COLOUR_LIT.max_range_m)
    mapper = CoverageMapper(CoverageGrid(), geo, camera)
    truth_grid = CoverageGrid()
    seen_ever = CoverageGrid()
    cost_ms: list[float] = []
    sent_version, next_send, radio_bytes = 0, DELTA_PERIOD_S, 0
    frames = int(duration_s * SUITE_FPS)
    for i in range(frames):
        t_s = (i + 0.5) / SUITE_FPS
        tp = trajectory.pose_at(t_s)
        pose = _pose(tp)
        image = renderer.render(tp, frame_key=i).image
        counted = mapper.new_viewpoint(pose, Sensor.COLOUR)
        start = time.perf_counter()
        mapper.add(pose, Sensor.COLOUR, image)
        if counted:  # a frame from the same viewpoint costs a comparison only
            cost_ms.append((time.perf_counter() - start) * 1000.0)
            seen = truth.frame(tp)
            truth_grid.add_look(seen.cells, COLOUR_LIT.at(seen.range_m))
            seen_ever.add_look(seen.cells, np.ones(len(seen.cells)))
        if t_s >= next_send:
            delta = mapper.grid.delta_since(sent_version)
            radio_bytes += len(delta.encode()) if len(delta) else 0
            sent_version, next_send = delta.to_version, next_send + DELTA_PERIOD_S
    n_cells, e_cells = (int(s / 0.25) for s in world.size_m)
    nn, ee = np.meshgrid(np.arange(n_cells), np.arange(e_cells), indexing="ij")
    floor = np.column_stack([nn.ravel(), ee.ravel()])
    claim = mapper.grid.p_at(floor)
    true_p = truth_grid.p_at(floor)
    never = seen_ever.p_at(floor) == 0.0

    def share(part: np.ndarray, whole: np.ndarray) -> float | None:
        return round(float(part.sum() / whole.sum()), 3) if whole.sum() else None

    well, glanced = claim >= SEARCHED_WELL_P, claim >= GLANCED_AT_P
    return MissionCoverage(
        over_well=share(well & never, well),
        over_glanced=share(glanced & never, glanced),
        under=share((true_p >= GLANCED_AT_P) & ~glanced, true_p >= GLANCED_AT_P),
        floor_well_claim=round(float(well.mean()), 3),
        floor_well_truth=round(float((true_p >= SEARCHED_WELL_P).mean()), 3),
        cost_ms=cost_ms,
        radio_bytes_per_min=round(radio_bytes / (duration_s / 60.0), 1),
        frames=frames,
        cluttered=bool(world.warm_objects) or any(d.height_m >= TALL_M for d in world.debris),
        counts=(
            int(well.sum()),
            int((well & never).sum()),
            int(glanced.sum()),
            int((glanced & never).sum()),
        ),
    )


def _task(task: tuple[str, ...]) -> Any:
    """One piece of the section, in a worker process: a detection curve or a mission."""
    if task[0] == "range":
        return detection_by_range(task[1], float(task[2]), int(task[3]))
    (scenario,) = [s for s in SUITE if s.key == task[1]]
    return measure_mission(scenario)


def run() -> dict[str, Any]:
    """The section's figures. The pieces run in parallel processes, one per CPU this
    process may use (``python -m bench`` pins one: there they run one after another)."""
    ranges = " / ".join(f"{r:g}" for r in RANGES_M)
    curves = {
        f"colour, full light: views found at {ranges} m": ("range", "colour", "1.0", "6"),
        f"colour, 5 % light: views found at {ranges} m": ("range", "colour", "0.05", "4"),
        f"thermal: views found at {ranges} m": ("range", "thermal", "1.0", "6"),
    }
    tasks = list(curves.values()) + [("mission", s.key) for s in SUITE]
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    jobs = min(len(tasks), cpus or 1)
    if jobs > 1:
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
            results = list(pool.map(_task, tasks))
    else:
        results = [_task(t) for t in tasks]
    out: dict[str, Any] = dict(zip(curves, results[: len(curves)], strict=True))
    costs: list[float] = []
    radio: list[float] = []
    pooled = {"open": np.zeros(4, int), "cluttered": np.zeros(4, int)}
    for scenario, m in zip(SUITE, results[len(curves) :], strict=True):
        costs += m.cost_ms
        radio.append(m.radio_bytes_per_min)
        kind = "cluttered" if m.cluttered else "open"
        pooled[kind] += np.array(m.counts)
        out[f"{scenario.key} ({kind}): over-claim well / glanced, under-claim"] = (
            f"{m.over_well} / {m.over_glanced}, {m.under}"
        )
        out[f"{scenario.key}: floor searched well, claim / truth"] = (
            f"{m.floor_well_claim} / {m.floor_well_truth}"
        )
    for kind, (well, well_never, glanced, glanced_never) in pooled.items():
        out[f"{kind} worlds pooled: over-claim well / glanced"] = (
            f"{well_never / max(well, 1):.3f} / {glanced_never / max(glanced, 1):.3f}"
        )
    out["cost per counted colour frame (a new viewpoint), median ms"] = round(
        float(np.median(costs)), 3
    )
    out["cost per counted colour frame, p95 ms"] = round(float(np.percentile(costs, 95)), 3)
    out["radio, deltas every 10 s: bytes per minute, median / max over missions"] = (
        f"{np.median(radio):.0f} / {max(radio):.0f}"
    )
    out["load average while measuring (1 min)"] = round(os.getloadavg()[0], 2)
    return out


if __name__ == "__main__":  # pragma: no cover
    import sys

    if sys.argv[1:2] == ["missions"]:
        for sc in SUITE:
            if sys.argv[2:] and sc.key not in sys.argv[2:]:
                continue
            m = measure_mission(sc)
            print(
                sc.key,
                {k: v for k, v in dataclasses.asdict(m).items() if k != "cost_ms"},
                f"cost median {np.median(m.cost_ms):.3f} p95 {np.percentile(m.cost_ms, 95):.3f}",
                flush=True,
            )
    else:
        for key, value in run().items():
            print(f"{key}: {value}")
