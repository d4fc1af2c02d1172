"""``rescue-sim demo``: the product on a simulated mission, what ``make demo`` runs.

By default the demo is deterministic: the simulated rover's mission is recorded in
simulated time (``scenarios.record``: frames and the autopilot's telemetry, the
same for a seed on every machine), the companion's own pipeline processes every
frame of it as on the Pi (``companion.commands.mission_run``: the default person
detector, geolocation, tracker, reporting policy), and each report it decides goes,
in order, as a RESCUE_VICTIM_REPORT over UDP to a real ``rescue-hq`` child process,
which stores, merges and acknowledges it (resent until acknowledged). A fixed seed
gives the same victims, IDs and figures whatever the machine's speed. The companion
is in the recording's loop (scenarios/inloop.py) with its closer looks on: the
rover leaves its route to look again at what the companion is unsure of, as the
simulated ArduPilot Rover is told in MAVLink, and the map draws each look and what
it settled (``--no-looks``: the route alone, recorded first, then replayed).

``--live`` runs the whole product in real time instead: the simulated rover and its
two cameras in this process (scenarios.live), the real ``rescue-companion run`` (its
config with the ``[thermal]`` section of the simulator's Lepton) and
``rescue-hq`` as child processes wired as on a robot (our reports reach the HQ only
inside TUNNEL, routed by the rover as ArduPilot would). The companion then
processes what frames its CPU allows, so two runs on a loaded machine can differ.

Either way the demo prints the HQ's victim table, then each true victim beside what
the HQ holds for it (ID, urgency, error, seconds from first in view to first
report) with the totals, and writes a mission map PNG (debris, the rover's path,
true and reported victims with their 95 % ellipses, a legend) of what the HQ holds.
Every run starts fresh (the previous run's outputs in the folder are removed)
unless ``--resume`` is given.
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
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from companion.commands.mission_run import ReplayReport
from companion.commands.missionmap import MapLook
from companion.commands.replay import replay
from companion.config_load import load_config
from hq.simrobot import SimRobot
from mavlink_io import convert
from scenarios.demo_summary import DemoResult, summarise
from scenarios.errors import SimError
from scenarios.inloop import InLoopCompanion, recording_config
from scenarios.live import LiveSim
from scenarios.motion import Trajectory, route_of
from scenarios.record import record
from scenarios.score import (
    load_truth,
)
from scenarios.world import World

log = logging.getLogger(__name__)

_STOP_TIMEOUT_S = 10.0
_ROUTE_SAMPLE_S = 0.5
DEMO_FPS = 5.0  # as the scenario suite (bench/accuracy.py)
_ACK_TIMEOUT_S = 2.0
_SEND_ATTEMPTS = 5


class DemoError(SimError):
    """The demo could not run (rescue-hq did not start or answer)."""


def _companion_config(sim: LiveSim, out_dir: Path) -> Path:
    path = out_dir / "companion.toml"
    path.write_text(
        "# Written by rescue-sim demo: the companion on the simulated rover.\n"
        f'[vehicle]\nurl = "{sim.vehicle_url}"\n\n'
        '[hq]\nurl = ""  # reports go inside TUNNEL through the rover, as through ArduPilot\n'
        "tunnel = true\n\n"
        f'[camera]\nsource = "{sim.camera_source}"\n\n'
        f'[paths]\nstate_dir = "{out_dir / "companion-state"}"\n\n'
        + sim.thermal_toml  # the Lepton beside the colour camera, served by the simulator
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
    "mission",  # the recorded mission (deterministic demo)
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
    live: bool = False,
    looks: bool = True,
) -> DemoResult:
    """Run a mission (recorded and replayed, or ``live``); every output, the
    children's logs included, lands in ``out_dir``. ``looks``: the recorded mission
    has the companion in its loop, taking the rover on closer looks.

    Fresh unless ``resume``: the previous run's state, logs and exports in
    ``out_dir`` are removed first (nothing else there is touched)."""
    out_dir = out_dir.resolve()  # the children resolve paths from elsewhere
    out_dir.mkdir(parents=True, exist_ok=True)
    if not resume:
        _fresh(out_dir)
    if live:
        return _run_live(world, out_dir, duration_s, speed_m_s)
    return _run_recorded(world, out_dir, duration_s, speed_m_s, looks)


def _start_hq(out_dir: Path, log_file: IO[bytes], *extra: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [
            sys.executable, "-m", "hq.cli", "--db", str(out_dir / "hq.sqlite"),
            "--export-dir", str(out_dir / "exports"), *extra,
        ],
        stdout=subprocess.PIPE, stderr=log_file,
    )  # fmt: skip


def _listening_port(hq: subprocess.Popen[bytes], timeout_s: float = 30.0) -> int:
    """The UDP port rescue-hq printed (``rescue-hq: listening on udpin:H:P``)."""
    assert hq.stdout is not None
    found: list[int] = []

    def read() -> None:
        assert hq.stdout is not None
        for raw in hq.stdout:
            line = raw.decode(errors="replace")
            if "listening on" in line and not found:
                found.append(int(line.rsplit(":", 1)[1]))
        # keep reading (the HQ's event lines) so its pipe never fills

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + timeout_s
    while not found:
        if hq.poll() is not None or time.monotonic() > deadline:
            raise DemoError("rescue-hq did not start (see hq.log)")
        time.sleep(0.05)
    return found[0]


@dataclass(frozen=True)
class _ReplayStatus:
    """What the replayed companion would say of itself at the mission's end."""

    uptime_s: float  # the mission's length
    fps: float  # frames processed per second of mission (every frame, in a replay)
    vision_ms: float  # wall time of the replay per frame
    confirmed: int
    origin: bool  # the vehicle had a global origin


def _status_msg(m: Any, status: _ReplayStatus) -> Any:
    flags = (
        m.RESCUE_STATUS_FLAGS_VEHICLE_LINK
        | m.RESCUE_STATUS_FLAGS_CAMERA
        | m.RESCUE_STATUS_FLAGS_HQ_LINK
        | m.RESCUE_STATUS_FLAGS_CLOCK_SYNCED
        | (m.RESCUE_STATUS_FLAGS_GLOBAL_ORIGIN if status.origin else 0)
    )
    return m.MAVLink_rescue_status_message(
        int(status.uptime_s), status.fps, 0.0, status.vision_ms, flags,
        min(status.confirmed, 0xFFFF), 0, 0,
    )  # fmt: skip


def _deliver(
    reports: list[ReplayReport], hq_address: tuple[str, int], status: _ReplayStatus
) -> int:
    """Send each report, in order, until rescue-hq acknowledges it; how many resends.
    Each robot first sends its RESCUE_STATUS at the mission's end, so the HQ's robot
    table is filled in as a live companion's would be (the HQ handles a robot's
    messages in order: the first report's acknowledgement means the status is in)."""
    resends = 0
    robots: dict[int, SimRobot] = {}
    try:
        for seq, r in enumerate(reports, start=1):
            sysid = r.report.robot_sysid
            robot = robots.get(sysid)
            if robot is None:
                robot = robots[sysid] = SimRobot(sysid, hq_address)
                robot.send(_status_msg(robot.m, status))
            msg = convert.victim_report_to_msg(
                r.report, seq, r.flags, r.t_unix_s, r.merged_into, robot.m
            )
            for attempt in range(_SEND_ATTEMPTS):
                robot.send(msg)
                try:
                    robot.wait_for("RESCUE_ACK", _ACK_TIMEOUT_S, seq=seq)
                    break
                except TimeoutError:
                    resends += 1
                    if attempt == _SEND_ATTEMPTS - 1:
                        raise DemoError(f"rescue-hq did not acknowledge report {seq}") from None
    finally:
        for robot in robots.values():
            robot.close()
    return resends


def _route_s(world: World, speed_m_s: float) -> float:
    return Trajectory(
        world.start_ne_m,
        world.start_heading_rad,
        route_of(world),
        speed_m_s=speed_m_s,
        seed=world.seed,
    ).duration_s()


def _run_recorded(
    world: World, out_dir: Path, duration_s: float | None, speed_m_s: float, looks: bool
) -> DemoResult:
    mission = out_dir / "mission"
    print(
        f"demo: world {world.name or world.seed!r} with {len(world.victims)} victims; "
        f"recording the mission in simulated time ({DEMO_FPS:g} frames/s) into {mission}"
        + (", the companion in the loop with closer looks on" if looks else ""),
        flush=True,
    )
    route_s = _route_s(world, speed_m_s) + 2.0
    # The mission is set to end now (whole seconds), so the HQ's "last seen" reads
    # naturally; only differences of times enter the figures.
    start_unix_s = float(math.floor(time.time() - (duration_s or route_s)))
    companion = None
    if looks:
        config = recording_config(mission, DEMO_FPS)
        companion = InLoopCompanion(config, looks=True, thermal=True)
    started_s = time.monotonic()
    rec = record(
        world,
        mission,
        duration_s=duration_s if looks else (duration_s or route_s),
        fps=DEMO_FPS,
        start_unix_s=start_unix_s,
        speed_m_s=speed_m_s,
        thermal=True,  # the Lepton beside the colour camera: thermal/ and [thermal]
        companion=companion,
    )
    print(
        f"demo: {rec.frames} frames and {rec.thermal_frames} thermal frames of a "
        f"{rec.duration_s:.0f} s mission; the companion's pipeline (the Pi's default "
        "person detector and the thermal detector) processes every frame of both cameras",
        flush=True,
    )
    map_looks: list[MapLook] = []
    if companion is not None:
        result = companion.result()
        for k, e in enumerate(companion.events, 1):
            print(
                f"demo: closer look {k} at {e.started_unix_s - start_unix_s:.0f} s, to a "
                f"{e.kind} {math.dist(e.start_ne_m, e.candidate_ne_m):.1f} m from the route: "
                f"{e.outcome or 'under way at the end'}",
                flush=True,
            )
            map_looks.append(MapLook(e.start_ne_m, e.view_ne_m, e.candidate_ne_m, e.outcome))
        extra_s = rec.duration_s - route_s
        print(
            f"demo: {len(companion.events)} closer look(s); the mission took "
            f"{rec.duration_s:.0f} s, {extra_s:+.0f} s against its route alone",
            flush=True,
        )
    else:
        started_s = time.monotonic()
        result = replay(
            load_config(mission / "camera.toml"),
            mission / "mission.tlog",
            mission / "frames",
            mission / "thermal",
        )
    status = _ReplayStatus(
        uptime_s=rec.duration_s,
        fps=result.frames / rec.duration_s if rec.duration_s > 0 else 0.0,
        vision_ms=1000.0 * (time.monotonic() - started_s) / max(1, result.frames),
        confirmed=len(result.victims),
        origin=result.origin is not None,
    )
    print(f"demo: {len(result.reports)} reports decided; sending them to rescue-hq", flush=True)
    with (out_dir / "hq.log").open("wb") as hq_log:
        hq = _start_hq(
            out_dir, hq_log, "--listen", "udpin:127.0.0.1:0", "--no-table", "--no-web",
            "--sbs", "off",
        )  # fmt: skip
    try:
        resends = _deliver(result.reports, ("127.0.0.1", _listening_port(hq)), status)
        if resends:
            print(f"demo: {resends} report(s) resent before rescue-hq acknowledged them")
    finally:
        hq_exit = _stop(hq, "rescue-hq")
    truth = load_truth(mission / "ground_truth.json")
    first_in_view = {
        v.victim_id: v.first_in_view_unix_s
        for v in truth.victims
        if v.first_in_view_unix_s is not None
    }
    reported_at = {(result.robot_sysid, vid): t for vid, t in result.first_reported_unix_s.items()}
    return summarise(
        world,
        out_dir,
        result.route_ne_m,
        first_in_view,
        0,
        hq_exit,
        reported_at,
        result.coverage,
        map_looks,
    )


def _run_live(
    world: World, out_dir: Path, duration_s: float | None, speed_m_s: float
) -> DemoResult:
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
                [python, "-m", "companion.commands.cli", "run", "--config", str(cfg)],
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
        first_in_view = sim.first_in_view_unix_s  # by either camera: the earlier
    return summarise(world, out_dir, route, first_in_view, companion_exit, hq_exit)
