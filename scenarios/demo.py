"""``rescue-sim demo``: the whole product on loopback, what ``make demo`` runs.

The simulated rover and its camera run in this process (scenarios.live); the real
``rescue-companion run`` and ``rescue-hq`` run as child processes, wired as on a
robot: companion <-> rover on one UDP port, rover <-> HQ on another. Our reports
reach the HQ only inside TUNNEL, routed by the rover as ArduPilot would. The HQ's
live table shows victims as they are confirmed; at the end the demo prints the
HQ's victim table, scores the companion against the world's ground truth and writes
a mission map PNG.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from companion.config import load_config
from companion.missionmap import draw_mission_map
from companion.store import Store
from fusion.tracker import VictimTracker
from fusion.types import TrackState
from scenarios.camera import SIM_DETECTOR_TOML
from scenarios.live import LiveSim
from scenarios.score import GroundTruth, ReportedVictim, TrueVictim, format_score, score
from scenarios.world import World

log = logging.getLogger(__name__)

_STOP_TIMEOUT_S = 10.0
_ROUTE_SAMPLE_S = 0.5


@dataclass(frozen=True)
class DemoResult:
    out_dir: Path
    confirmed: int
    map_png: Path
    score_text: str
    companion_exit: int
    hq_exit: int


def _companion_config(sim: LiveSim, out_dir: Path) -> Path:
    path = out_dir / "companion.toml"
    path.write_text(
        "# Written by rescue-sim demo: the companion on the simulated rover.\n"
        f'[vehicle]\nurl = "{sim.vehicle_url}"\n\n'
        '[hq]\nurl = ""  # reports go inside TUNNEL through the rover, as through ArduPilot\n'
        "tunnel = true\n\n"
        f'[camera]\nsource = "{sim.camera_source}"\n\n'
        f'[paths]\nstate_dir = "{out_dir / "companion-state"}"\n\n' + SIM_DETECTOR_TOML
    )
    return path


def _stop(proc: subprocess.Popen[bytes], name: str) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=_STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        log.error("%s did not stop within %.0f s; killed", name, _STOP_TIMEOUT_S)
        proc.kill()
        return proc.wait()


def _truth(world: World) -> GroundTruth:
    return GroundTruth(
        tuple(
            TrueVictim(
                v.victim_id,
                v.north_m,
                v.east_m,
                v.urgency,
                None if math.isnan(v.visible_north_m) else v.visible_north_m,
                None if math.isnan(v.visible_east_m) else v.visible_east_m,
            )
            for v in world.victims
        )
    )


def run_demo(world: World, out_dir: Path, duration_s: float | None, speed_m_s: float) -> DemoResult:
    """Run a live mission; the children's logs and every output land in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    python = sys.executable
    with LiveSim(world, speed_m_s=speed_m_s) as sim:
        route_s = sim.rover.trajectory.duration_s()
        mission_s = duration_s if duration_s is not None else route_s + 5.0
        cfg = _companion_config(sim, out_dir)
        print(
            f"demo: world {world.name or world.seed!r} with {len(world.victims)} victims, "
            f"a {mission_s:.0f} s mission; outputs in {out_dir}",
            flush=True,
        )
        with (
            (out_dir / "hq.log").open("wb") as hq_log,
            (out_dir / "companion.log").open("wb") as c_log,
        ):
            hq = subprocess.Popen(
                [
                    python, "-m", "hq.cli", "--listen", sim.ground_url,
                    "--db", str(out_dir / "hq.sqlite"), "--export-dir", str(out_dir / "exports"),
                ],
                stdout=None, stderr=hq_log, env=env,  # its live table (plain lines off a TTY)
            )  # fmt: skip
            companion = subprocess.Popen(
                [python, "-m", "companion.cli", "run", "--config", str(cfg)],
                stdout=c_log, stderr=subprocess.STDOUT, env=env,
            )  # fmt: skip
        route: list[tuple[float, float]] = []
        done = threading.Event()
        elapsed = 0.0
        try:
            while elapsed < mission_s and not done.wait(_ROUTE_SAMPLE_S):
                elapsed += _ROUTE_SAMPLE_S
                pose, _ = sim.rover.camera_pose()
                route.append((pose.north_m, pose.east_m))
                if companion.poll() is not None or hq.poll() is not None:
                    break
        finally:
            companion_exit = _stop(companion, "rescue-companion")
            hq_exit = _stop(hq, "rescue-hq")
    return _summarise(world, out_dir, cfg, route, companion_exit, hq_exit)


def _summarise(
    world: World,
    out_dir: Path,
    cfg: Path,
    route: list[tuple[float, float]],
    companion_exit: int,
    hq_exit: int,
) -> DemoResult:
    config = load_config(cfg)
    store = Store(config.paths.state_dir / "companion.sqlite")
    snapshot = store.get("tracker")
    store.close()
    tracker = (
        VictimTracker.restore(config.tracker, snapshot)
        if snapshot
        else VictimTracker(config.tracker)
    )
    victims = [
        v
        for v in tracker.victims()
        if v.state in (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
    ]
    map_png = out_dir / "mission_map.png"
    draw_mission_map(map_png, route, victims, [(v.north_m, v.east_m) for v in world.victims])
    reported = [
        ReportedVictim(v.victim_id, v.urgency, v.north_m, v.east_m, v.first_seen_unix_s)
        for v in victims
    ]
    result = score(_truth(world), reported)
    return DemoResult(out_dir, len(victims), map_png, format_score(result), companion_exit, hq_exit)


def print_summary(result: DemoResult) -> None:
    listing = subprocess.run(
        [sys.executable, "-m", "hq.cli", "list", "--db", str(result.out_dir / "hq.sqlite")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    print("\nvictims at the HQ:")
    print(listing.stdout.rstrip() or listing.stderr.rstrip())
    print("\nagainst the world's ground truth:")
    print(result.score_text)
    print(f"\nmission map: {result.map_png}")
    print(f"HQ exports: {result.out_dir / 'exports'} (GeoJSON, KML, CSV)")
    print(f"logs: {result.out_dir / 'companion.log'}, {result.out_dir / 'hq.log'}")
