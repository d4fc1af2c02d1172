"""Evidence pictures over a simulated 57,600-baud radio at 10 % loss: bytes, transfer time, report latency

The real ``rescue-companion run`` on the simulated rover (``mixed`` world, its
lawnmower route, driven around debris and people) sends everything to the HQ through the rover's ArduPilot-like
router (TUNNEL), whose ground port reaches the real ``rescue-hq`` through
scenarios.radio: 5,760 bytes a second each way (57,600 baud, 8N1), a 4 kB radio
buffer, 10 % of the datagrams (one MAVLink frame each) lost each way, seeded. The
radio also carries the rover's own telemetry streams to the HQ and the HQ's
heartbeats and acknowledgements back. The same mission runs twice: pictures off,
then on with the defaults (``[pictures] max_bytes = 6000``, ``width_px = 240``,
``rate_bytes_s = 1000``). Both runs report a victim's quiet updates every second
(``[reporting] update_min_interval_s = 1``) to have many reports to time. The
companion runs on its own core (as in bench/e2e.py), the rest on the other.

- picture bytes: the JPEGs the HQ stored; bytes on the radio per picture (chunks
  and resends, as the sender counts them);
- transfer time: from the first chunk to the HQ's STORED coming back (the
  companion's log), and from the frame the view was taken in to the HQ storing it
  (with the wait behind other pictures);
- report latency: the HQ's arrival time minus the report's own time (both this
  machine's clock), all reports, and in the run with pictures the reports that
  arrived while a picture was being transferred. Target: no growth (reports go
  first, pictures at a bounded rate below what the radio carries);
- radio: bytes a second robot-to-HQ and drops because its buffer was full (a full
  buffer would drop reports too).

A mission confirms few victims in a few minutes, so the same path is also timed
under steady load ("steady"): a robot (hq.simrobot, in TUNNEL to the same rover
router, radio and rescue-hq) sends a report of a new victim every 0.5 s through
mavlink_io.reliable.Outbox (resent after 1 s, as the companion does) and, in the
run with pictures, keeps companion.reporting.pictures.PictureSender busy with the mission's
JPEGs one after the other, with the reporter thread's rule: reports first,
pictures only when no report is due, at the default 1000 B/s; 60 s without and 60 s
with pictures, twice, alternated (the machine is shared), pooled.
"""

from __future__ import annotations

import dataclasses
import os
import re
import select
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from companion.config import PicturesConfig
from companion.reporting.pictures import PictureSender
from companion.storage.store import StoredPicture
from hq.simrobot import SimRobot
from mavlink_io import picture
from mavlink_io.reliable import Outbox
from scenarios.live import LiveSim
from scenarios.motion import lawnmower
from scenarios.radio import Radio
from scenarios.rover import SimRover
from scenarios.world import preset

MISSION_S = 180.0
LOSS = 0.10
BAUD = 57_600
_DELIVERED = re.compile(
    r"picture (\d+) of victim (\d+) delivered in ([\d.]+) s \((\d+) bytes, (\d+) chunks sent for (\d+)\)"
)


STEADY_S = 60.0
REPORT_PERIOD_S = 0.5


@dataclasses.dataclass
class Steady:
    report_latency_s: list[float]
    transfers_s: list[float]
    chunks_per_picture: float  # chunks sent per picture delivered (with resends and polls)
    picture_chunks: int  # chunks in one picture
    overflow: int


def _steady(jpegs: list[bytes], seconds: float) -> Steady:
    """Reports every REPORT_PERIOD_S through the rover and the radio, with pictures
    flowing all the time when ``jpegs`` is not empty."""
    with (
        tempfile.TemporaryDirectory(prefix="bench-pictures-") as tmp,
        SimRover(preset("light"), ["udpin:127.0.0.1:0", "udpin:127.0.0.1:0"], seed=3) as rover,
        Radio(rover.local_address(1), baud=BAUD, loss=LOSS, seed=11) as radio,
    ):
        hq_db = Path(tmp) / "hq.sqlite"
        hq = subprocess.Popen(
            [sys.executable, "-m", "hq.cli", "--listen", radio.ground_url, "--db", str(hq_db),
             "--no-table", "--no-web", "--sbs", "off"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        robot = SimRobot(1, rover.local_address(0), tunnel=True)
        m = robot.codec.module
        outbox = Outbox(robot.send, initial_s=1.0, max_s=30.0)
        started: dict[int, float] = {}
        done: list[float] = []

        def finished(_victim: int, picture_id: int, _result: int) -> None:
            done.append(time.monotonic() - started[picture_id])

        sender = PictureSender(
            PicturesConfig(), lambda c: robot.send(c.to_msg(m)), finished, clock=time.monotonic
        )
        n = 0
        next_report = next_beat = time.monotonic() + 3.0  # rescue-hq starts meanwhile
        end = next_report + seconds
        try:
            while (now := time.monotonic()) < end:
                if now >= next_beat:
                    robot.heartbeat()
                    next_beat = now + 1.0
                if now >= next_report:
                    n += 1
                    outbox.submit(robot.report_msg(robot.victim(n, 0.1 * n, 1.0)))
                    next_report = now + REPORT_PERIOD_S
                if jpegs and sender.pending == 0:
                    pid = 1_000_000 + len(started)
                    started[pid] = now
                    sender.offer(
                        StoredPicture(pid, pid, 1.0, 0.0, jpegs[len(started) % len(jpegs)])
                    )
                for rx in robot.receive(0.0):
                    if rx.msg.get_type() == "RESCUE_ACK":
                        outbox.on_ack(rx.msg)
                    elif rx.msg.get_type() == "RESCUE_PICTURE_ACK":
                        sender.on_ack(picture.Ack.from_msg(rx.msg))
                outbox.poll()
                if outbox.seconds_until_due() != 0.0:  # the reporter's rule: reports first
                    sender.poll()
                waits = [next_report - now, next_beat - now, outbox.seconds_until_due(),
                         sender.seconds_until_due()]  # fmt: skip
                select.select(
                    [robot.sock], [], [], max(0.001, min(w for w in waits if w is not None))
                )
            time.sleep(2.0)  # the last reports cross the radio
        finally:
            robot.close()
            hq.send_signal(signal.SIGTERM)
            hq.wait(timeout=30)
        db = sqlite3.connect(hq_db)
        latency = [
            float(t) - u / 1e6
            for t, u in db.execute("SELECT received_unix_s, report_time_usec FROM reports")
        ]
        db.close()
        return Steady(
            latency,
            done,
            sender.counters.chunks / max(1, len(done)),
            picture.chunk_count(len(jpegs[0])) if jpegs else 0,
            radio.to_ground.counters.overflow + radio.to_rover.counters.overflow,
        )


@dataclasses.dataclass
class Run:
    report_latency_s: list[tuple[float, float]]  # (arrival unix s, latency s)
    pictures: list[dict[str, Any]]
    jpegs: list[bytes]
    transfers: list[tuple[float, int, int, int]]  # (seconds, bytes, chunks sent, chunks)
    up_bytes_s: float
    overflow: int
    lost_up: int


def _companion_core() -> int:
    """A core this process is not pinned to (python -m bench pins itself to one)."""
    mine = os.sched_getaffinity(0)
    cores = list(range(os.cpu_count() or 1))
    return next((c for c in cores if c not in mine), cores[-1])


def _mission(pictures: bool, mission_s: float) -> Run:
    world = preset("mixed")
    world = dataclasses.replace(world, route_ne_m=lawnmower(world) * 3)
    with (
        tempfile.TemporaryDirectory(prefix="bench-pictures-") as tmp,
        LiveSim(world, speed_m_s=0.5, seed=3) as sim,
        Radio(sim.rover.local_address(1), baud=BAUD, loss=LOSS, seed=7) as radio,
    ):
        out = Path(tmp)
        hq_db = out / "hq.sqlite"
        hq = subprocess.Popen(
            [sys.executable, "-m", "hq.cli", "--listen", radio.ground_url, "--db", str(hq_db),
             "--no-table", "--no-web", "--sbs", "off"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        cfg = out / "companion.toml"
        cfg.write_text(
            f'[vehicle]\nurl = "{sim.vehicle_url}"\n[hq]\nurl = ""\ntunnel = true\n'
            f'[camera]\nsource = "{sim.camera_source}"\n[paths]\nstate_dir = "{out / "state"}"\n'
            f"[video]\nenabled = false\n[pictures]\nenabled = {str(pictures).lower()}\n"
            "[reporting]\nupdate_min_interval_s = 1.0\n"
        )
        log = out / "companion.log"
        with log.open("wb") as f:
            proc = subprocess.Popen(
                [sys.executable, "-m", "companion.commands.cli", "run", "--config", str(cfg)],
                stdout=f,
                stderr=subprocess.STDOUT,
                preexec_fn=lambda: os.sched_setaffinity(0, {_companion_core()}),
            )
        start = time.monotonic()
        try:
            while time.monotonic() - start < mission_s and proc.poll() is None:
                time.sleep(1.0)  # the mission runs; nothing to poll
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
            time.sleep(1.0)  # the last datagrams cross the radio
            hq.send_signal(signal.SIGTERM)
            hq.wait(timeout=30)
        elapsed = time.monotonic() - start
        db = sqlite3.connect(hq_db)
        reports = [
            (float(t), float(t) - u / 1e6)
            for t, u in db.execute("SELECT received_unix_s, report_time_usec FROM reports")
        ]
        stored = {}
        jpegs = []
        for v, p, t, j in db.execute(
            "SELECT victim_id, picture_id, received_unix_s, jpeg FROM pictures"
        ):
            stored[(int(v), int(p))] = (float(t), len(j))
            jpegs.append(bytes(j))
        db.close()
        kept = {}
        state_db = out / "state" / "companion.sqlite"
        if state_db.exists():
            db = sqlite3.connect(state_db)
            kept = {
                (int(v), int(p)): float(t)
                for v, p, t in db.execute(
                    "SELECT victim_id, picture_id, taken_unix_s FROM pictures"
                )
            }
            db.close()
        shown = [
            {"bytes": n, "taken": kept[key], "stored": t}
            for key, (t, n) in stored.items()
            if key in kept
        ]
        transfers = [
            (float(m[3]), int(m[4]), int(m[5]), int(m[6]))
            for m in _DELIVERED.finditer(log.read_text())
        ]
        return Run(
            reports,
            shown,
            jpegs,
            transfers,
            radio.to_ground.counters.delivered_bytes / elapsed,
            radio.to_ground.counters.overflow + radio.to_rover.counters.overflow,
            radio.to_ground.counters.lost,
        )


def _stats(values: list[float]) -> str:
    if not values:
        return "n/a"
    ms = [1000.0 * v for v in values]
    return (
        f"median {statistics.median(ms):.0f}, p95 {float(np.percentile(ms, 95)):.0f}, "
        f"max {max(ms):.0f} (n={len(ms)})"
    )


def _synthetic_jpeg() -> bytes:
    """A textured 240x180 JPEG of about 6 kB, if the mission stored none."""
    rng = np.random.default_rng(5)
    img = cv2.resize((rng.random((45, 60, 3)) * 255).astype(np.uint8), (240, 180))
    return bytes(cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 30])[1])


def run(mission_s: float = MISSION_S) -> dict[str, object]:
    off = _mission(False, mission_s)
    on = _mission(True, mission_s)
    runs: dict[bool, list[Steady]] = {False: [], True: []}
    for flowing_pictures in (False, True, False, True):  # alternated: the machine is shared
        jpegs = (on.jpegs or [_synthetic_jpeg()]) if flowing_pictures else []
        runs[flowing_pictures].append(_steady(jpegs, STEADY_S))
    quiet, busy = (
        Steady(
            [x for r in rs for x in r.report_latency_s],
            [x for r in rs for x in r.transfers_s],
            statistics.mean(r.chunks_per_picture for r in rs),
            rs[0].picture_chunks,
            sum(r.overflow for r in rs),
        )
        for rs in (runs[False], runs[True])
    )
    steady = {
        "steady: reports (every 0.5 s) latency, pictures off, ms": _stats(quiet.report_latency_s),
        "steady: reports latency, pictures flowing all the time, ms": _stats(busy.report_latency_s),
        "steady: pictures delivered in the run / transfer time median (max), s": (
            f"{len(busy.transfers_s)} / {statistics.median(busy.transfers_s):.1f} "
            f"({max(busy.transfers_s):.1f})"
            if busy.transfers_s
            else "0"
        ),
        "steady: chunks sent per picture / chunks in it": (
            f"{busy.chunks_per_picture:.0f} / {busy.picture_chunks}"
        ),
        "steady: radio buffer overflows, off / on": f"{quiet.overflow} / {busy.overflow}",
    }
    flowing = [
        lat
        for t, lat in on.report_latency_s
        if any(p["taken"] <= t <= p["stored"] for p in on.pictures)
    ]
    sizes = [p["bytes"] for p in on.pictures]
    radio_bytes = [b for _, _, sent, _ in on.transfers for b in [sent * 132]]
    return {
        "mission length each run, s": round(mission_s),
        "radio": f"{BAUD} baud (5760 B/s each way), {LOSS:.0%} datagram loss each way, 4 kB buffer",
        "pictures stored at the HQ": len(on.pictures),
        "picture JPEG bytes, median (min-max)": (
            f"{statistics.median(sizes):.0f} ({min(sizes)}-{max(sizes)})" if sizes else "n/a"
        ),
        "chunks sent per picture / chunks in it, median": (
            f"{statistics.median(s for _, _, s, _ in on.transfers):.0f} / "
            f"{statistics.median(c for _, _, _, c in on.transfers):.0f}"
            if on.transfers
            else "n/a"
        ),
        "radio bytes per picture (chunks sent x 132), median": (
            round(statistics.median(radio_bytes)) if radio_bytes else "n/a"
        ),
        "transfer time first chunk to STORED, s, median (max)": (
            f"{statistics.median(s for s, *_ in on.transfers):.1f} "
            f"({max(s for s, *_ in on.transfers):.1f})"
            if on.transfers
            else "n/a"
        ),
        "view taken to stored at the HQ, s, median (max)": (
            f"{statistics.median(p['stored'] - p['taken'] for p in on.pictures):.1f} "
            f"({max(p['stored'] - p['taken'] for p in on.pictures):.1f})"
            if on.pictures
            else "n/a"
        ),
        "report latency, pictures off, ms": _stats([lat for _, lat in off.report_latency_s]),
        "report latency, pictures on, ms": _stats([lat for _, lat in on.report_latency_s]),
        "report latency while a picture was in flight, ms": _stats(flowing),
        "robot-to-HQ radio use, pictures off / on, B/s": (
            f"{off.up_bytes_s:.0f} / {on.up_bytes_s:.0f}"
        ),
        "radio buffer overflows, off / on": f"{off.overflow} / {on.overflow}",
        **steady,
    }


if __name__ == "__main__":
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else MISSION_S
    for key, value in run(seconds).items():
        print(f"{key}: {value}")
