"""Evidence pictures over a simulated 57,600-baud radio at 10 % loss: bytes, transfer time, report latency

The real ``rescue-companion run`` on the simulated rover (``mixed`` world, its
lawnmower route) sends everything to the HQ through the rover's ArduPilot-like
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
"""

from __future__ import annotations

import dataclasses
import os
import re
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from scenarios.live import LiveSim
from scenarios.motion import lawnmower
from scenarios.radio import Radio
from scenarios.world import preset

MISSION_S = 180.0
LOSS = 0.10
BAUD = 57_600
_DELIVERED = re.compile(
    r"picture (\d+) of victim (\d+) delivered in ([\d.]+) s \((\d+) bytes, (\d+) chunks sent for (\d+)\)"
)


@dataclasses.dataclass
class Run:
    report_latency_s: list[tuple[float, float]]  # (arrival unix s, latency s)
    pictures: list[dict[str, Any]]
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
                [sys.executable, "-m", "companion.cli", "run", "--config", str(cfg)],
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
        stored = {
            (int(v), int(p)): (float(t), int(n))
            for v, p, t, n in db.execute(
                "SELECT victim_id, picture_id, received_unix_s, length(jpeg) FROM pictures"
            )
        }
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
            transfers,
            radio.up.counters.delivered_bytes / elapsed,
            radio.up.counters.overflow + radio.down.counters.overflow,
            radio.up.counters.lost,
        )


def _stats(values: list[float]) -> str:
    if not values:
        return "n/a"
    ms = [1000.0 * v for v in values]
    return (
        f"median {statistics.median(ms):.0f}, p95 {float(np.percentile(ms, 95)):.0f}, "
        f"max {max(ms):.0f} (n={len(ms)})"
    )


def run(mission_s: float = MISSION_S) -> dict[str, object]:
    off = _mission(False, mission_s)
    on = _mission(True, mission_s)
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
    }


if __name__ == "__main__":
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else MISSION_S
    for key, value in run(seconds).items():
        print(f"{key}: {value}")
