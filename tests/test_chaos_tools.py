"""The chaos mission's tools (the mission itself is `make chaos`: 20 minutes, too long
for the default run on this machine): its seeded fault schedule, the lossy radio
(scenarios/radio.py without a byte rate) and the systemd-like supervisor."""

from __future__ import annotations

import itertools
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from scenarios.camserver import CameraServer
from scenarios.chaos import SPEED_M_S, chaos_world, patrol_route, plan_faults, watch_camera
from scenarios.chaoscheck import CAMERA_GRACE_S, longest_silence_s
from scenarios.motion import Trajectory
from scenarios.radio import Radio
from scenarios.supervise import Supervised


@pytest.mark.parametrize("mission_s", [90.0, 1200.0])
def test_fault_plan_is_seeded_bounded_and_complete(mission_s: float) -> None:
    plan = plan_faults(mission_s, 16)
    assert plan == plan_faults(mission_s, 16)
    assert plan != plan_faults(mission_s, 17)
    assert all(0.0 < f.at_s < mission_s for f in plan)
    kinds = [f.kind for f in plan]
    for once in ("hq-term", "hq-kill", "reboot", "disk-fill", "disk-free"):
        assert kinds.count(once) == 1
    kills = [f.at_s for f in plan if f.kind == "companion-kill"]
    assert len(kills) == max(1, round(mission_s / 150.0))
    assert all(
        b - a >= min(15.0, mission_s / (3 * len(kills))) for a, b in itertools.pairwise(kills)
    )
    assert kinds.index("disk-fill") < kinds.index("disk-free")


def test_the_patrol_finds_the_people_one_at_a_time() -> None:
    world = chaos_world()
    route = patrol_route(world, 600.0)
    assert route[0] == world.start_ne_m
    # The route visits each person's east in turn and never comes back to an earlier one.
    easts = [e for _, e in route]
    assert easts == sorted(easts) and len(set(easts)) == len(world.victims)
    # As the rover drives it (turns included), it reaches each next person about a
    # third of the mission (200 s here) after the last: within half a pass (about
    # 25 s) and the 8 m drive between them (about 33 s).
    trajectory = Trajectory(world.start_ne_m, world.start_heading_rad, route, speed_m_s=SPEED_M_S)
    for i, v in enumerate(world.victims[1:], start=1):
        arrival_s = next(
            t for t in range(1000) if abs(trajectory.pose_at(float(t)).east_m - v.east_m) < 0.5
        )
        assert abs(arrival_s - 200.0 * i) <= 25.0 + 8.5 / SPEED_M_S, (v.victim_id, arrival_s)


def _udp() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.05)
    return sock


def _drain(sock: socket.socket, quiet_s: float = 0.5) -> tuple[int, object]:
    """Datagrams that arrive until none came for ``quiet_s``, and the last sender."""
    n, last, sender = 0, time.monotonic(), None
    while time.monotonic() - last < quiet_s:
        try:
            _data, sender = sock.recvfrom(65535)
        except TimeoutError:
            continue
        n, last = n + 1, time.monotonic()
    return n, sender


def _send(sock: socket.socket, to: object, n: int) -> None:
    for _ in range(n):
        sock.sendto(b"x", to)
        time.sleep(0.001)  # paced: a burst would overflow loopback's socket buffers


def test_radio_loses_its_share_each_way_and_answers_the_latest_hq() -> None:
    rover, hq, hq_again = _udp(), _udp(), _udp()
    with Radio(rover.getsockname(), loss=0.3, seed=16, baud=None) as radio:
        _send(hq, ("127.0.0.1", radio.port), 150)
        up, radio_side = _drain(rover)  # the rover answers where the radio speaks from
        _send(rover, radio_side, 150)
        down, _ = _drain(hq)
        _send(hq_again, ("127.0.0.1", radio.port), 1)  # the HQ restarted on a new port
        restarted, _ = _drain(rover, 0.3)
        _send(rover, radio_side, 10)
        again, _ = _drain(hq_again, 0.3)
        log = radio.snapshot()
    for sock in (rover, hq, hq_again):
        sock.close()
    # 150 Bernoulli(0.7) trials (few enough for loopback's socket buffers): sd ~5.6,
    # so +-25 is more than 4 sd.
    assert abs(up - 105) <= 25 and abs(down - 105) <= 25
    assert (log.to_rover.datagrams, log.to_ground.datagrams) == (151, 160)
    assert log.to_rover.dropped == 151 - up - restarted
    assert log.to_ground.dropped == 160 - down - again
    assert again >= 1  # all 10 lost: 0.3^10


def test_supervisor_restarts_as_systemd_and_counts_a_restart_loop(tmp_path: Path) -> None:
    crash = Supervised(
        "crash",
        [sys.executable, "-c", "import sys; sys.exit(1)"],
        tmp_path / "crash.log",
        restart_delay_s=0.1,
    ).start()
    deadline = time.monotonic() + 20.0
    while len(crash.runs) < 3 and time.monotonic() < deadline:
        time.sleep(0.1)
    crash.stop()
    assert len(crash.runs) >= 3
    assert crash.quick_unplanned_exits() >= 2
    sleeper = Supervised(
        "sleeper",
        [sys.executable, "-c", "import time; time.sleep(60)"],
        tmp_path / "sleeper.log",
        restart_delay_s=0.1,
    ).start()
    try:
        assert sleeper.signal(signal.SIGKILL)
        deadline = time.monotonic() + 20.0
        while len(sleeper.runs) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(sleeper.runs) == 2 and sleeper.runs[0].planned == "SIGKILL"
        assert sleeper.unplanned_exits() == []
    finally:
        assert sleeper.stop() == -signal.SIGTERM
    assert (tmp_path / "sleeper.log").read_text().count("--- chaos: start sleeper") == 2


def test_camera_silence_counts_only_while_the_companion_is_settled() -> None:
    """A silence while the companion starts (its first CAMERA_GRACE_S) or is down
    between a kill and its restart is not the companion's; the rest is."""
    g = CAMERA_GRACE_S
    runs = [(0.0, 100.0), (105.0, None)]
    assert longest_silence_s([], runs) == 0.0
    assert longest_silence_s([(0.0, g)], runs) == 0.0  # the first start
    assert longest_silence_s([(100.0, 105.0 + g)], runs) == 0.0  # down, then restarting
    assert longest_silence_s([(g + 10.0, g + 50.0)], runs) == 40.0
    assert longest_silence_s([(90.0, 400.0)], runs) == 400.0 - (105.0 + g)  # across a kill


def test_a_silent_camera_gets_its_thread_stacks_written_once(tmp_path: Path) -> None:
    """A camera server whose renderer hangs sends nothing; the chaos watcher writes
    where every thread waits (the renderer's own function among them) and says so."""
    release = threading.Event()

    class _Result:
        def __init__(self) -> None:
            self.image = np.zeros((48, 64, 3), np.uint8)
            self.visible_px: dict[int, int] = {}

    class _HangingRenderer:
        def render(self, pose: object) -> _Result:
            release.wait(30.0)  # the stuck render the watcher must show
            return _Result()

    said: list[str] = []
    path = tmp_path / "threads.txt"
    renderer: Any = _HangingRenderer()
    no_pose: Any = None  # the hanging renderer never looks at it
    camera = CameraServer(renderer, lambda: (no_pose, time.time()), fps=10.0)
    camera.start()
    try:
        watch_camera(camera, path, 0.5, threading.Event(), said.append)
    finally:
        release.set()
        camera.close()
    text = path.read_text()
    assert "--- thread cam-render" in text and "release.wait(30.0)" in text
    assert "--- thread cam-accept" in text
    assert said == [f"chaos: the camera sent no frame for 0.5 s; thread stacks in {path}"]


def test_the_simulator_runs_blas_on_one_thread() -> None:
    """Imported before numpy (as rescue-sim and the benches do), scenarios keeps
    OpenBLAS from starting worker threads, which hung the chaos camera on a fork."""
    code = "import scenarios, numpy, os; print(len(os.listdir('/proc/self/task')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"
