"""A seeded, bounded chaos mission: the real companion and HQ under loss and faults.

    result = run_chaos(Path("out"), mission_s=1200.0, seed=16)
    result.failures   # [] when every check passed
    result.figures()  # what BENCHMARKS.md shows

The simulated rover patrols across each person of ``chaos_world()`` in turn
(``patrol_route``: the ``mixed`` preset's three people, fully visible, 8 m apart)
while the real ``rescue-companion run`` and
``rescue-hq`` run as children (scenarios.supervise: restarted as systemd would).
The HQ hears the rover's ground port only through a scenarios.radio.Radio (30 % of datagrams
lost each way). A seeded schedule (``plan_faults``) kills the companion with
SIGKILL at random moments, stops the HQ once with SIGTERM and once with SIGKILL
(each restarted), reboots the simulated autopilot, and fills the companion's state
disk (its own small tmpfs: needs root and mount; skipped and said so otherwise)
for a while. At the end the camera stops (no new news), the harness waits until
the companion's outbox holds no report and every victim it reported is at the HQ
(bounded), stops both, and checks (``scenarios.chaoscheck.check``):

- every true victim the companion confirmed is at the HQ with exactly one HQ ID,
  and no victim the companion's store reported is missing at the HQ;
- every report the HQ acknowledged (seen on the radio) is in its registry;
- no process exited without being asked to soon after its start (a restart loop),
  nor at all; both stop cleanly at the end; no traceback in any log;
- every person is confirmed (each lies in plain view for a third of the patrol), and
  a companion up for more than 30 s never goes 30 s without a camera frame.
"""

from __future__ import annotations

import dataclasses
import errno
import logging
import math
import os
import random
import signal
import sqlite3
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from scenarios.camserver import CameraServer
from scenarios.chaoscheck import (
    ChaosResult,
    check,
    companion_reported,
    hq_sources,
    longest_silence_s,
)
from scenarios.live import LiveSim
from scenarios.motion import Trajectory
from scenarios.radio import Radio
from scenarios.supervise import Supervised
from scenarios.world import PointNE, World, preset

log = logging.getLogger(__name__)

LOSS = 0.30  # share of datagrams lost on the radio, each way
CAMERA_FPS = 5.0  # ~100 ms of vision a frame on a loaded 2-core machine
SPEED_M_S = 0.25  # slow enough for a handful of processed frames per pass
RESTART_DELAY_S = 2.0  # systemd/rescue-companion.service: RestartSec=2
DISK_BYTES = 96 * 1024 * 1024  # above the companion's 64 MB "disk full" warning level
DRAIN_MAX_S = 240.0  # resends back off to 30 s; at 30 % loss each way, a few rounds
POLL_S = 1.0
_LEAD_M = 2.5  # a pass starts this far short of its victim and ends as far beyond


_SPACING_M = 8.0  # between the people, east: out of the camera's view during another's patrol
_PLACES_NE_M = ((3.0, 3.0), (5.0, 3.0 + _SPACING_M), (3.5, 3.0 + 2 * _SPACING_M))


CAMERA_SILENCE_DUMP_S = 30.0  # no frame to any client this long: dump the threads once


def watch_camera(
    camera: CameraServer,
    path: Path,
    silence_s: float,
    stop: threading.Event,
    say: Callable[[str], None],
) -> None:
    """Once the camera server has sent no frame for ``silence_s`` (the chaos check's
    limit), write every thread's stack of this process to ``path``: a silent camera
    shows there where its threads wait (it found the BLAS hang scenarios/__init__.py
    tells of, which had left the camera silent with no traceback). Returns after one
    dump, when ``stop`` is set, or when the server is closed."""
    while not stop.wait(1.0) and not camera.closed:
        if time.monotonic() - camera.last_sent_mono_s < silence_s:
            continue
        frames = sys._current_frames()
        lines = [
            f"camera silent for {silence_s:g} s; clients (sent, dropped): "
            f"{camera.client_stats()}; frames rendered: {camera.frames_rendered}\n"
        ]
        for t in threading.enumerate():
            frame = frames.get(t.ident or -1)
            lines.append(f"\n--- thread {t.name}\n")
            lines.extend(traceback.format_stack(frame) if frame is not None else ["(no frame)\n"])
        path.write_text("".join(lines), encoding="utf-8")
        say(f"chaos: the camera sent no frame for {silence_s:g} s; thread stacks in {path}")
        return


def chaos_world() -> World:
    """The ``mixed`` preset's three people, fully visible (debris and dark zone
    cleared, so the detector finds each on a pass), 8 m apart along the east of an
    8 m x 22 m floor. The route is set per mission by ``patrol_route``."""
    base = preset("mixed")
    victims = tuple(
        dataclasses.replace(v, north_m=n, east_m=e)
        for v, (n, e) in zip(base.victims, _PLACES_NE_M, strict=True)
    )
    first = victims[0]
    return dataclasses.replace(
        base,
        name="chaos",
        size_m=(8.0, 3.0 + 2 * _SPACING_M + 3.0),
        debris=(),
        light_zones=(),
        victims=victims,
        start_ne_m=(max(0.3, first.north_m - _LEAD_M), first.east_m),
        start_heading_rad=0.0,
        route_ne_m=(),
    )


def patrol_route(world: World, mission_s: float) -> tuple[PointNE, ...]:
    """Back and forth (north-south) across one person after the other, a third of the
    mission each, so the people are found one at a time while the faults come: from
    one patrol the next person is 8 m to the side, out of view. The passes are counted
    by the time the rover takes to drive them, turns included. The last patrol goes
    on past the mission's end (the rover never stops).

    This bench tests the service under faults, not the search: the rover drives this
    route as given, over each person (``LiveSim(route=...)``), for a broadside view of
    the whole body on every pass. A route driven around a person, as
    ``scenarios.motion.route_of`` plans it, shows this pass only the legs of a body
    lying across it, and the third person was not confirmed (2026-11-27)."""
    n_max = world.size_m[0] - 0.3
    share_s = mission_s / len(world.victims)
    route: list[PointNE] = []
    elapsed_s = 0.0
    here, heading = world.start_ne_m, world.start_heading_rad
    for i, v in enumerate(world.victims):
        near = (max(0.3, v.north_m - _LEAD_M), v.east_m)
        far = (min(n_max, v.north_m + _LEAD_M), v.east_m)
        if here != near:
            elapsed_s += _drive_s(here, heading, (near,))
        route.append(near)
        one = _drive_s(near, 0.0, (far, near))
        lap_s = _drive_s(near, 0.0, (far, near, far, near)) - one  # with its turns
        end_s = share_s * (i + 1) if i < len(world.victims) - 1 else mission_s + 2 * share_s
        laps = max(1, round((end_s - elapsed_s) / lap_s))
        route += [far, near] * laps
        elapsed_s += laps * lap_s
        here, heading = near, math.pi  # back at the near end, heading south
    return tuple(route)


def _drive_s(start: PointNE, heading_rad: float, route: tuple[PointNE, ...]) -> float:
    """Seconds the rover takes to drive ``route`` from ``start``."""
    return Trajectory(start, heading_rad, route, speed_m_s=SPEED_M_S).duration_s()


@dataclass(frozen=True)
class Fault:
    at_s: float
    kind: str  # "companion-kill", "hq-term", "hq-kill", "reboot", "disk-fill", "disk-free"


def plan_faults(mission_s: float, seed: int) -> list[Fault]:
    """The seeded schedule over ``[0, mission_s)``: one SIGKILL of the companion per
    150 s (at least one) at random moments at least 15 s apart, the HQ's SIGTERM and
    SIGKILL, one autopilot reboot, and the disk full for 5 % of the mission (10-60 s)."""
    rng = random.Random(seed)
    d = mission_s
    plan = [
        Fault(rng.uniform(0.20, 0.30) * d, "hq-term"),
        Fault(rng.uniform(0.40, 0.50) * d, "reboot"),
        Fault(rng.uniform(0.55, 0.65) * d, "hq-kill"),
    ]
    fill = rng.uniform(0.70, 0.75) * d
    plan += [Fault(fill, "disk-fill"), Fault(fill + min(60.0, max(10.0, 0.05 * d)), "disk-free")]
    kills: list[float] = []
    wanted = max(1, round(d / 150.0))
    spacing = min(15.0, d / (3 * wanted))
    while len(kills) < wanted:
        t = rng.uniform(0.10, 0.90) * d
        if all(abs(t - k) >= spacing for k in kills):
            kills.append(t)
    plan += [Fault(t, "companion-kill") for t in kills]
    return sorted(plan, key=lambda f: f.at_s)


# -- the state disk --------------------------------------------------------------------


@contextmanager
def small_disk(mount_point: Path) -> Iterator[str]:
    """A tmpfs of DISK_BYTES at ``mount_point``; yields "" or why there is none."""
    mount_point.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        yield "skipped: mounting a small tmpfs needs root"
        return
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES}", "tmpfs", str(mount_point)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if done.returncode != 0:
        yield f"skipped: cannot mount a tmpfs here ({done.stderr.strip()})"
        return
    try:
        yield ""
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


def fill(directory: Path) -> Path:
    """Fill the filesystem of ``directory`` to the last byte; the filler file."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        for size in (1024 * 1024, 64 * 1024, 4096, 512, 1):
            try:
                while True:
                    os.write(fd, bytes(size))
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
    finally:
        os.close(fd)
    return filler


def _wait(condition: Callable[[], bool], timeout_s: float, stop: threading.Event) -> float | None:
    """Seconds until ``condition`` held (checked every POLL_S), None on timeout."""
    start = time.monotonic()
    while True:
        try:
            if condition():
                return time.monotonic() - start
        except sqlite3.Error as exc:  # a database mid-checkpoint: ask again
            log.debug("chaos: condition not readable yet: %s", exc)
        if time.monotonic() - start >= timeout_s or stop.wait(POLL_S):
            return None


# -- the mission -----------------------------------------------------------------------


def _companion_config(out: Path, sim: LiveSim, state_dir: Path) -> Path:
    cfg = out / "companion.toml"
    cfg.write_text(
        "# Written by scenarios.chaos\n"
        f'[vehicle]\nurl = "{sim.vehicle_url}"\n'
        '[hq]\nurl = ""\ntunnel = true\n'
        f'[camera]\nsource = "{sim.camera_source}"\n'
        f'[paths]\nstate_dir = "{state_dir}"\n'
        "[video]\nenabled = false\n"
    )
    return cfg


def run_chaos(
    out: Path, mission_s: float, seed: int, *, say: Callable[[str], None] = print
) -> ChaosResult:
    """The mission of the module docstring in ``out`` (logs, databases); its result."""
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    result = ChaosResult(seed, mission_s)
    world = chaos_world()
    route = patrol_route(world, mission_s)
    plan = plan_faults(mission_s, seed)
    say(
        f"chaos: seed {seed}, {mission_s:.0f} s, {len(world.victims)} victims, "
        f"{LOSS:.0%} loss; faults: " + ", ".join(f"{f.kind}@{f.at_s:.0f}s" for f in plan)
    )
    state_dir = out / "companion-state"
    hq_db = out / "hq.sqlite"
    start = time.monotonic()
    result.started_unix_s = time.time()
    stop = threading.Event()
    with (
        small_disk(state_dir) as disk_problem,
        # The chaos mission tests the service's survival, with the colour camera
        # only: no thermal camera rendered that nobody reads.
        LiveSim(
            world, fps=CAMERA_FPS, speed_m_s=SPEED_M_S, seed=seed, route=route, thermal=False
        ) as sim,
        Radio(
            ("127.0.0.1", sim.rover.local_address(1)[1]),
            loss=LOSS,
            seed=seed,
            baud=None,
            log_reports=True,
        ) as radio,  # fmt: skip
    ):
        if disk_problem:
            say(f"chaos: state disk {disk_problem}")
            plan = [f for f in plan if not f.kind.startswith("disk")]
        result.disk_note = disk_problem or "not yet"
        env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
        companion = Supervised(
            "rescue-companion",
            [
                sys.executable,
                "-m",
                "companion.commands.cli",
                "run",
                "--config",
                str(_companion_config(out, sim, state_dir)),
            ],
            out / "companion.log",
            restart_delay_s=RESTART_DELAY_S,
            env=env,
        )
        hq = Supervised(
            "rescue-hq",
            [
                sys.executable, "-m", "hq.cli", "--listen", radio.ground_url,
                "--db", str(hq_db), "--no-table", "--no-web", "--sbs", "off",
            ],
            out / "hq.log",
            restart_delay_s=RESTART_DELAY_S,
            env=env,
        )  # fmt: skip
        hq.start()
        companion.start()
        filler: Path | None = None
        watch = threading.Thread(
            target=watch_camera,
            args=(sim.camera, out / "camera-silence-threads.txt", CAMERA_SILENCE_DUMP_S, stop, say),
            name="chaos-camera-watch",
            daemon=True,
        )
        watch.start()
        try:
            for fault in plan:
                if stop.wait(max(0.0, start + fault.at_s - time.monotonic())):
                    break
                filler = _inject(fault, companion, hq, sim, state_dir, filler, result, say)
            stop.wait(max(0.0, start + mission_s - time.monotonic()))
        finally:
            if filler is not None:
                filler.unlink(missing_ok=True)
            sim.camera.close()  # no new news: what is known must now reach the HQ
            watch.join(timeout=2.0)
            result.longest_silence_s = longest_silence_s(
                sim.camera.silences, [(r.started_mono_s, r.ended_mono_s) for r in companion.runs]
            )
        say("chaos: mission over, camera off; waiting for the outbox to drain")
        state_db = state_dir / "companion.sqlite"

        def drained() -> bool:
            reported, pending = companion_reported(state_db)
            return pending == 0 and set(reported) <= hq_sources(hq_db, 1)

        result.drain_s = _wait(drained, DRAIN_MAX_S, stop)
        rc_companion = companion.stop()
        rc_hq = hq.stop()
        result.radio = radio.snapshot()
        reported, pending = companion_reported(state_db)  # before the tmpfs goes
    result.total_s = time.monotonic() - start
    if rc_companion not in (0, None) or rc_hq not in (0, None):
        result.failures.append(f"exit status at the end: companion {rc_companion}, HQ {rc_hq}")
    if rc_companion is None or rc_hq is None:
        result.failures.append(
            f"not running at the end: companion {rc_companion is None}, HQ {rc_hq is None}"
        )
    check(result, world, reported, pending, hq_db, companion, hq, out, DRAIN_MAX_S)
    for line in result.details:
        say(f"chaos: {line}")
    return result


def _inject(
    fault: Fault,
    companion: Supervised,
    hq: Supervised,
    sim: LiveSim,
    state_dir: Path,
    filler: Path | None,
    result: ChaosResult,
    say: Callable[[str], None],
) -> Path | None:
    """Apply one fault; the filler file while the disk is full."""
    done = True
    if fault.kind == "companion-kill":
        done = companion.signal(signal.SIGKILL)
    elif fault.kind == "hq-term":
        done = hq.signal(signal.SIGTERM)
    elif fault.kind == "hq-kill":
        done = hq.signal(signal.SIGKILL)
    elif fault.kind == "reboot":
        sim.rover.reboot()
    elif fault.kind == "disk-fill":
        filler = fill(state_dir)
        result.disk_note = "full, not yet freed"
    elif fault.kind == "disk-free" and filler is not None:
        filler.unlink()
        filler = None
        result.disk_note = f"once, for {_disk_seconds(fault, result):.0f} s"
    if done:
        result.faults_done[fault.kind] = result.faults_done.get(fault.kind, 0) + 1
    say(f"chaos: {fault.at_s:6.0f} s {fault.kind}{'' if done else ' (was not running)'}")
    return filler


def _disk_seconds(free: Fault, result: ChaosResult) -> float:
    fill_at = [f.at_s for f in plan_faults(result.mission_s, result.seed) if f.kind == "disk-fill"]
    return free.at_s - fill_at[0] if fill_at else 0.0
