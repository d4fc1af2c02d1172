"""Closer looks on the scenario suite: the companion in the loop, taking the rover.

The accuracy suite's missions (bench/accuracy.py: the same worlds, cameras, frame
rate, start time and 1 m gate), each recorded with the companion in the simulator's
loop (scenarios/inloop.py) and closer looks on at their defaults: the real pipeline
on every frame of both cameras, the looks stepped five times a second, their
commands sent to the simulated ArduPilot Rover as MAVLink bytes, which drives them;
the mission ends when the rover has driven its whole route. Scored as the accuracy
suite is; the section accuracy is the same suite without looks (the rover on its
route alone, the same figures a closed loop with looks off gives: tests/test_inloop.py).

Figures: per mission its finds, false victims, urgency and error as in accuracy,
how many looks it made and what they settled, and the mission time against the
route alone. Time to first report: from a victim's first clear view, the first
frame of either camera that shows it on at least 150 colour pixels or 20 warm
thermal pixels (the truth's first_in_view / first_warm_in_view, whichever comes
first), to the first report of it. Targets (issue 42): 0 false victims, recall in
view >= 0.95, median time to first report <= 10 s, mission time added <= 15 %.
"""

from __future__ import annotations

import collections
import concurrent.futures
import logging
import multiprocessing
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import scenarios  # noqa: F401  (BLAS single-threaded before numpy)
from bench.accuracy import GATE_M, START_UNIX_S, SUITE, Scenario, figures, totals
from companion.commands.replay import result_document
from scenarios.inloop import InLoopCompanion, recording_config
from scenarios.motion import Trajectory
from scenarios.record import MISSION_END_S, record
from scenarios.score import ScoreResult, load_truth, report_from_dict, score

log = logging.getLogger(__name__)


def measure_one(scenario: Scenario, work_dir: Path) -> tuple[dict[str, Any], ScoreResult]:
    """Record one mission with the companion and its looks in the loop; (figures, score)."""
    start = time.perf_counter()
    world = scenario.make_world()
    camera = scenario.camera()
    config = recording_config(work_dir, scenario.fps, camera)
    companion = InLoopCompanion(config, looks=True, thermal=True)
    rec = record(
        world,
        work_dir,
        duration_s=scenario.duration_s,
        fps=scenario.fps,
        camera=camera,
        start_unix_s=START_UNIX_S,
        companion=companion,
    )
    route_s = Trajectory.for_world(world).duration_s() + MISSION_END_S  # as without looks
    reported = report_from_dict(result_document(companion.result()), work_dir / "inloop.json")
    scored = score(load_truth(work_dir / "ground_truth.json"), reported, gate_m=GATE_M)
    out = figures(scored)
    settled = collections.Counter(e.outcome.split(" to ")[0] for e in companion.events)
    out.update(
        looks=len(companion.events),
        settled=dict(sorted(settled.items())),
        duration_s=round(rec.duration_s, 1),
        route_s=round(route_s, 1),
        run_s=round(time.perf_counter() - start, 1),
    )
    return out, scored


def _measure_in_tmp(scenario: Scenario) -> tuple[dict[str, Any], ScoreResult]:
    with tempfile.TemporaryDirectory(prefix=f"looks-{scenario.key}-") as tmp:
        log.info("looks: %s (%s)", scenario.key, scenario.world)
        return measure_one(scenario, Path(tmp))


def run() -> dict[str, Any]:
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    jobs = min(len(SUITE), cpus or 1)
    if jobs > 1:
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=context) as pool:
            results = list(pool.map(_measure_in_tmp, SUITE))
    else:
        results = [_measure_in_tmp(s) for s in SUITE]
    out: dict[str, Any] = {}
    looks = 0
    settled: collections.Counter[str] = collections.Counter()
    mission_s = route_s = 0.0
    for s, (fig, _scored) in zip(SUITE, results, strict=True):
        looks += fig["looks"]
        settled.update(fig["settled"])
        mission_s += fig["duration_s"]
        route_s += fig["route_s"]
        out[s.key] = (
            f"{fig['matched']} of {fig['true_victims']} found, {fig['false_victims']} false, "
            f"urgency {fig['urgency_correct']} right, error median {fig['error_median_m']} m, "
            f"first report {fig['time_to_report_median_s']} s (median); {fig['looks']} looks "
            f"{fig['settled'] or ''}, {fig['duration_s']} s against {fig['route_s']} s"
        )
    t = totals([scored for _fig, scored in results])
    out["total: found / in view (recall in view; target >= 0.95)"] = (
        f"{t['matched']} ({t['recall_in_view']})"
    )
    out["total: false victims (target 0)"] = t["false_victims"]
    out["total: urgency right"] = f"{t['urgency_correct']} of {t['matched']}"
    out["total: error median, m"] = t["error_median_m"]
    out["total: time to first report, median / max, s (target median <= 10)"] = (
        f"{t['time_to_report_median_s']} / {t['time_to_report_max_s']}"
    )
    out["total: looks made, and what they settled"] = f"{looks}: " + ", ".join(
        f"{n} {what}" for what, n in sorted(settled.items())
    )
    out["total: mission time added by looks (target <= 15 %)"] = (
        f"{100.0 * (mission_s - route_s) / route_s:.1f} % ({mission_s:.0f} s against "
        f"{route_s:.0f} s)"
        if route_s > 0
        else None
    )
    return out


if __name__ == "__main__":  # pragma: no cover
    for key, value in run().items():
        print(f"{key}: {value}")
