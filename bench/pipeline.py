"""Whole pipeline throughput on one core: frames per second at 640x480, vision time per frame, with the thermal camera beside it

A mission is recorded with ``scenarios.record.record`` (preset "mixed", the first
60 s of its route, 10 frames/s, 640x480 JPEG, fixed start time) and its frames go
through ``companion.pipeline.Pipeline.process`` exactly as in replay and live: pose
interpolation, vision (enhancement, detection, visibility), geolocation, Kalman
tracking and the reporting policy. The recorded camera.toml is the configuration.
OpenCV runs with one thread (``python -m bench`` also pins the process to one core).
Timed: ``Pipeline.process`` only. JPEG decoding and telemetry decoding happen
outside the timer (the live service gets decoded frames from the camera thread and
poses from the link thread); decoding is reported on its own. ``vision_ms`` is the
pipeline's own measure (detection, visibility and geolocation of every detection);
``track_report_ms`` is the rest (tracker update and reporting decisions). Times are
wall clock; ``pipeline_fps_cpu_time`` uses the thread's CPU time instead, which other
processes on a shared machine do not inflate.
Target (issue 8): comfortably above the camera's 10 frames/s on the Pi 5.
The detector is the default (``backend = "people"``, the MediaPipe models on one
LiteRT thread each, live schedule). Until 2026-11-23 this section measured the
colour backend ``classic``, then the default: 89 frames/s, vision 7.9 ms a frame.
A Pi 5's core is slower than this machine's; one that cannot keep 10 frames/s
sets ``detector.model_threads = 2`` (real_images measures it) or the lite landmark
model.
Since issue 41 the recording carries the simulated Lepton's frames too (160x120 at
8.7 frames/s) and they go through ``Pipeline.process_thermal`` in capture-time
order, as the service's mailbox hands them over: ``thermal_ms`` is that step
(thermal detection, geolocation, tracking, reporting) per thermal frame, and
``colour_and_thermal_ms_per_frame`` is the colour and thermal work together per
colour frame (target: 5 ms per thermal frame, 60 ms together). ``peak_rss_mb`` is
the process's peak resident memory with the models loaded (target 400 MB).
Since 2026-11-29 (later) the person models' far-band search, which asks every colour
frame's geometry for the metres per pixel of 60 rows, gets them in one vectorised
pass (``fusion.geolocate.ground_sample_distances_m``, the same numbers) instead of
one ray fix with 11 perturbed rays per row: 1.3 ms a frame instead of 25 ms. The
same benchmark on the code just before, run the same day: pipeline 86.9 ms median
a colour frame, colour and thermal together 93.2 ms. The run before that (code
a5c0ae7, the same search) had measured 57.5 and 63.2 ms; why the search cost so much
less then was not found.
"""

from __future__ import annotations

import logging
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.calibration import camera_model
from companion.commands.mission_run import LOOKAHEAD_S
from companion.config_load import load_config
from companion.pipeline import Pipeline, ThermalEye
from companion.reporting.policy import ReportPolicy
from companion.sources.base import Frame, mono_minus_unix_s
from companion.sources.thermal import ThermalFrame
from companion.sources.thermal_folder import read_thermal_png
from companion.vision.backends import make_detector
from companion.vision.thermal import ThermalDetector
from fusion.pose import PoseHistory
from fusion.tracker import VictimTracker
from fusion.types import PoseSample
from mavlink_io.telemetry import TelemetryDecoder, is_autopilot_heartbeat
from mavlink_io.tlog import read_tlog
from scenarios.record import record
from scenarios.world import preset

log = logging.getLogger(__name__)

WORLD = "mixed"
DURATION_S = 60.0
FPS = 10.0
START_UNIX_S = 1_700_000_000.0


def _poses(tlog: Path, offset_s: float) -> list[PoseSample]:
    """Every pose the autopilot sent, in order (one vehicle, no reboots in a recording)."""
    decoder = TelemetryDecoder()
    sysid = 0
    out = []
    for t_unix_s, msg in read_tlog(tlog):
        if is_autopilot_heartbeat(msg, sysid):
            sysid = sysid or msg.get_srcSystem()
            continue
        if sysid and (msg.get_srcSystem(), msg.get_srcComponent()) == (sysid, 1):
            update = decoder.handle(msg, t_unix_s + offset_s)
            if update.pose is not None:
                out.append(update.pose)
    return out


def _pct(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)), 2)


def _measure(mission: Path) -> dict[str, Any]:
    config = load_config(mission / "camera.toml")
    offset_s = mono_minus_unix_s()
    poses = _poses(mission / "mission.tlog", offset_s)
    history = PoseHistory(config.vehicle.pose_history_s)
    rep = config.reporting
    assert config.thermal is not None  # the recorder writes [thermal]
    pipeline = Pipeline(
        config,
        camera_model(config.camera),
        make_detector(config.detector),
        VictimTracker(config.tracker),
        ReportPolicy(rep.move_threshold_sigma, rep.move_min_m, rep.update_min_interval_s),
        ThermalEye(camera_model(config.thermal), ThermalDetector(config.thermal.detector)),
    )
    files = sorted((mission / "frames").glob("*.jpg"), key=lambda p: int(p.stem))
    thermal = sorted((mission / "thermal").glob("*.png"), key=lambda p: int(p.stem))
    thermal_ms: list[float] = []
    warm_finds = 0
    next_thermal = 0
    total_ms: list[float] = []
    vision_ms: list[float] = []
    decode_ms: list[float] = []
    cpu_ms: list[float] = []
    detections = 0
    next_pose = 0
    for index, path in enumerate(files):
        t0 = time.perf_counter()
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        decode_ms.append((time.perf_counter() - t0) * 1e3)
        if image is None:
            raise RuntimeError(f"{path}: the recorder wrote a frame OpenCV cannot read")
        t_unix_s = int(path.stem) / 1e6
        while next_pose < len(poses) and poses[next_pose].t_mono_s <= (
            t_unix_s + offset_s + LOOKAHEAD_S
        ):
            history.add(poses[next_pose])
            next_pose += 1
        while next_thermal < len(thermal) and int(thermal[next_thermal].stem) / 1e6 < t_unix_s:
            words, why = read_thermal_png(thermal[next_thermal])
            if words is None:
                raise RuntimeError(f"{thermal[next_thermal]}: {why}")
            t_th = int(thermal[next_thermal].stem) / 1e6
            temps_c = (words.astype(np.float32) / 100.0 - 273.15).astype(np.float32)
            tframe = ThermalFrame(temps_c, t_th + offset_s, t_th, next_thermal)
            t0 = time.perf_counter()
            warm_finds += len(pipeline.process_thermal(tframe, history).detections)
            thermal_ms.append((time.perf_counter() - t0) * 1e3)
            next_thermal += 1
        frame = Frame(image, t_unix_s + offset_s, t_unix_s, index)
        t0, c0 = time.perf_counter(), time.thread_time()
        outcome = pipeline.process(frame, history)
        total_ms.append((time.perf_counter() - t0) * 1e3)
        cpu_ms.append((time.thread_time() - c0) * 1e3)
        vision_ms.append(outcome.vision_ms)
        detections += len(outcome.detections)
    rest = [t - v for t, v in zip(total_ms, vision_ms, strict=True)]
    return {
        "frames": len(files),
        "frames_without_pose": pipeline.counters.frames_without_pose,
        "detections_per_frame": round(detections / max(len(files), 1), 2),
        "pipeline_fps": round(1e3 * len(total_ms) / sum(total_ms), 1),
        "pipeline_fps_cpu_time": round(1e3 * len(cpu_ms) / sum(cpu_ms), 1),
        "pipeline_ms_median": round(statistics.median(total_ms), 2),
        "pipeline_ms_p95": _pct(total_ms, 95),
        "vision_ms_median": round(statistics.median(vision_ms), 2),
        "vision_ms_p95": _pct(vision_ms, 95),
        "track_report_ms_median": round(statistics.median(rest), 3),
        "track_report_ms_p95": _pct(rest, 95),
        "jpeg_decode_ms_median": round(statistics.median(decode_ms), 2),
        "victims_tracked": len(pipeline.tracker.victims()),
        "thermal_frames": len(thermal_ms),
        "warm_finds_per_thermal_frame": round(warm_finds / max(len(thermal_ms), 1), 2),
        "thermal_ms_median": round(statistics.median(thermal_ms), 2) if thermal_ms else None,
        "thermal_ms_p95": _pct(thermal_ms, 95) if thermal_ms else None,
        "colour_and_thermal_ms_per_frame": round(
            (sum(total_ms) + sum(thermal_ms)) / max(len(total_ms), 1), 2
        ),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def run() -> dict[str, Any]:
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with tempfile.TemporaryDirectory(prefix="bench-pipeline-") as tmp:
            mission = Path(tmp)
            record(
                preset(WORLD), mission, duration_s=DURATION_S, fps=FPS, start_unix_s=START_UNIX_S
            )
            figures = _measure(mission)
    finally:
        cv2.setNumThreads(threads)
    shape = f"640x480, preset {WORLD}, {DURATION_S:g} s at {FPS:g} frames/s"
    return {"mission": shape, **figures}


if __name__ == "__main__":
    import json
    import os

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    logging.basicConfig(level=logging.WARNING)
    print(json.dumps(run(), indent=1))
    sys.exit(0)
