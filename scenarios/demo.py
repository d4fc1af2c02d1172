"""``rescue-sim demo``: the whole product on loopback, what ``make demo`` runs.

The simulated rover and its camera run in this process (scenarios.live); the real
``rescue-companion run`` and ``rescue-hq`` run as child processes, wired as on a
robot: companion <-> rover on one UDP port, rover <-> HQ on another. Our reports
reach the HQ only inside TUNNEL, routed by the rover as ArduPilot would. The HQ's
live table shows victims as they are confirmed; at the end the demo prints the
HQ's victim table, then each true victim beside what the HQ received for it (ID,
urgency, error, seconds from first in view to first report) and the totals, and
writes a mission map PNG (debris, the rover's path, true and reported victims with
their 95 % ellipses, a legend) of what the HQ holds.

Every run starts fresh (the previous run's state in the output folder is removed)
unless ``--resume`` is given. The mission runs live, in real time: the companion
processes what frames its CPU allows, so two runs on a loaded machine can differ in
a frame or two; ``rescue-sim record`` + ``rescue-companion replay`` (and the
scenario suite in ``make bench``) are the deterministic route.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

from companion.missionmap import MapTruth, MapVictim, draw_mission_map
from fusion.types import TrackState
from hq.registry import Registry
from hq.view import hq_victims
from scenarios.live import LiveSim
from scenarios.score import (
    GroundTruth,
    ReportedVictim,
    ScoreResult,
    TrueVictim,
    format_score,
    score,
)
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
        f'[paths]\nstate_dir = "{out_dir / "companion-state"}"\n\n'
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


def _truth(world: World, first_in_view: dict[int, float]) -> GroundTruth:
    return GroundTruth(
        tuple(
            TrueVictim(
                v.victim_id,
                v.north_m,
                v.east_m,
                v.urgency,
                None if math.isnan(v.visible_north_m) else v.visible_north_m,
                None if math.isnan(v.visible_east_m) else v.visible_east_m,
                first_in_view.get(v.victim_id),
            )
            for v in world.victims
        )
    )


# What a demo run writes into its folder; a fresh run (no --resume) removes them first.
_OUTPUTS = (
    "companion-state",
    "exports",
    "hq.sqlite",
    "hq.sqlite-wal",
    "hq.sqlite-shm",
    "hq.sqlite.epoch",  # a fresh registry starts at ID 1 again
    "companion.toml",
    "companion.log",
    "hq.log",
    "mission_map.png",
)


def _fresh(out_dir: Path) -> None:
    for name in _OUTPUTS:
        path = out_dir / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()


def run_demo(
    world: World,
    out_dir: Path,
    duration_s: float | None,
    speed_m_s: float,
    resume: bool = False,
) -> DemoResult:
    """Run a live mission; the children's logs and every output land in ``out_dir``.

    Fresh unless ``resume``: the previous run's state, logs and exports in
    ``out_dir`` are removed first (nothing else there is touched)."""
    out_dir = out_dir.resolve()  # the children resolve paths from elsewhere
    out_dir.mkdir(parents=True, exist_ok=True)
    if not resume:
        _fresh(out_dir)
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
        first_in_view = dict(sim.camera.first_in_view_unix_s)
    return _summarise(world, out_dir, route, first_in_view, companion_exit, hq_exit)


def _summarise(
    world: World,
    out_dir: Path,
    route: list[tuple[float, float]],
    first_in_view: dict[int, float],
    companion_exit: int,
    hq_exit: int,
) -> DemoResult:
    """Score and map what the HQ holds (the victims ``rescue-hq list`` shows)."""
    registry = Registry(out_dir / "hq.sqlite")
    try:
        victims = [v for v in hq_victims(registry) if v.state is not TrackState.FALSE_ALARM]
        received = registry.first_received_unix_s()
    finally:
        registry.close()
    reported = [
        ReportedVictim(
            v.hq_id,
            v.urgency,
            v.north_m,
            v.east_m,
            v.first_seen_unix_s,
            min((received[s] for s in v.sources if s in received), default=None),
            ((v.sigma_m**2, 0.0), (0.0, v.sigma_m**2)),
        )
        for v in victims
    ]
    result = score(_truth(world, first_in_view), reported)
    map_png = out_dir / "mission_map.png"
    draw_mission_map(
        map_png,
        route,
        [
            MapVictim(
                f"V{v.hq_id}",
                v.urgency,
                v.north_m,
                v.east_m,
                ((v.sigma_m**2, 0.0), (0.0, v.sigma_m**2)),
                v.visibility_pct,
            )
            for v in victims
        ],
        [MapTruth(f"T{v.victim_id}", v.urgency, v.north_m, v.east_m) for v in world.victims],
        [d.polygon for d in world.debris],
        (0.0, world.size_m[0], 0.0, world.size_m[1]),
    )
    table = _victim_table(world, result, reported, first_in_view)
    return DemoResult(
        out_dir,
        len(victims),
        map_png,
        table + "\n\n" + format_score(result),
        companion_exit,
        hq_exit,
    )


def _victim_table(
    world: World,
    result: ScoreResult,
    reported: list[ReportedVictim],
    first_in_view: dict[int, float],
) -> str:
    """One line per true victim: what the HQ got for it."""
    by_true = {m.true_id: m for m in result.matches}
    by_id = {r.victim_id: r for r in reported}
    lines = ["true victim   urgency    reported as          error   first report"]
    for v in world.victims:
        m = by_true.get(v.victim_id)
        if m is None:
            lines.append(f"T{v.victim_id:<11d} {v.urgency.name:<10s} not reported")
            continue
        r = by_id[m.reported_id]
        seen = first_in_view.get(v.victim_id)
        delay = (
            f"{r.first_reported_unix_s - seen:5.1f} s after first in view"
            if seen is not None and r.first_reported_unix_s is not None
            else "n/a"
        )
        lines.append(
            f"T{v.victim_id:<11d} {v.urgency.name:<10s} V{r.victim_id:<3d} "
            f"{r.urgency.name:<16s} {m.error_m:4.2f} m  {delay}"
        )
    false = [r for r in reported if r.victim_id not in {m.reported_id for m in result.matches}]
    for r in false:
        lines.append(
            f"{'(none)':<12s} {'':<10s} V{r.victim_id:<3d} {r.urgency.name:<16s} false victim"
        )
    return "\n".join(lines)


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
