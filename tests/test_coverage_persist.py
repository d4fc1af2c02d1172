"""The coverage grid is saved with the victims and survives a restart (companion/storage/ledger.py).

The state directory, store, tracker and ledger are the real ones on a SQLite file;
the vehicle is absent hardware (an object with no EKF origin)."""

from __future__ import annotations

import json
import logging
import math
import sqlite3
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import test_companion_service as service

from companion.config import PicturesConfig
from companion.coverage import CoverageMapper
from companion.reporting.announcements import Announcer
from companion.reporting.pictures import resume
from companion.reporting.policy import ReportPolicy
from companion.storage.ledger import COVERAGE_KEY, Ledger
from companion.storage.recovery import load_state
from fusion.params import GeolocationParams, TrackerParams
from fusion.types import PoseSample, Sensor
from mavlink_io import dialect
from mavlink_io.reliable import Outbox
from scenarios.camera import default_camera
from scenarios.live import LiveSim
from scenarios.world import preset

M = dialect.load()


class _NoAutopilot:
    origin = None


def _start(state_dir: Path) -> Ledger:
    policy = ReportPolicy(2.0)
    state = load_state(state_dir, TrackerParams(), policy)
    chooser, sender = resume(PicturesConfig(), state.store, lambda _c: None, signed=False)
    wake = threading.Event()
    return Ledger(
        store=state.store,
        tracker=state.tracker,
        policy=policy,
        outbox=Outbox(lambda _msg: None, store=state.store),
        chooser=chooser,
        picture_sender=sender,
        announcer=Announcer(enabled=False, announce_severity=4, robot_sysid=lambda: 1, wake=wake),
        vehicle=_NoAutopilot(),  # type: ignore[arg-type]
        robot_sysid=lambda: 1,
        report_seq=state.report_seq,
        floor_down_m=0.0,
        wake_reporter=wake,
        m=M,
    )


def _drive(ledger: Ledger, steps: int) -> None:
    mapper = CoverageMapper(ledger.coverage, GeolocationParams(), default_camera())
    for k in range(steps):
        pose = PoseSample(0.0, 0.0, 0.3 * k, 1.0, -0.1, 0.0, 0.0, 0.4 * math.sin(k))
        mapper.add(pose, Sensor.COLOUR)


def test_grid_survives_a_restart(tmp_path: Path) -> None:
    ledger = _start(tmp_path)
    assert ledger.coverage.looks == 0
    _drive(ledger, 20)
    ledger.commit([])  # the periodic save
    saved = ledger.coverage.snapshot()
    p = ledger.coverage.probabilities()
    assert p.max() > 0.9
    ledger._store.close()

    again = _start(tmp_path)
    assert again.coverage.snapshot() == saved
    assert np.allclose(again.coverage.probabilities(), p, atol=2e-5)  # kept to 1/65535
    # Looks after the restart add to what was there.
    before = again.coverage.summary().looked_at_m2
    _drive(again, 40)
    again.commit([])
    again._store.close()
    third = _start(tmp_path)
    assert third.coverage.summary().looked_at_m2 > before
    third._store.close()


def test_unusable_saved_grid_is_said_and_the_victims_kept(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    ledger = _start(tmp_path)
    _drive(ledger, 5)
    ledger.commit([])
    snap = ledger.coverage.snapshot()
    ledger._store.set(COVERAGE_KEY, {**snap, "shape": [3]})
    ledger._store.set("report_seq", 41)
    ledger._store.close()
    with caplog.at_level(logging.WARNING):
        again = _start(tmp_path)
    lines = [r.getMessage() for r in caplog.records if COVERAGE_KEY in r.getMessage()]
    assert len(lines) == 1 and "shape" in lines[0] and "starts empty" in lines[0]
    assert again.coverage.looks == 0
    assert again.report_seq == 41
    again._store.close()


@pytest.mark.slow
def test_service_saves_the_grid_and_restores_it_after_a_restart(tmp_path: Path) -> None:
    """The real ``rescue-companion run`` against the simulated rover: its processing
    thread adds every frame's footprint; the grid is in the state file after a stop
    and the next run starts from it."""

    def saved_looks() -> int:
        path = tmp_path / "state" / "companion.sqlite"
        if not path.exists():  # not yet created by the starting service
            return 0
        db = sqlite3.connect(str(path))
        try:
            row = db.execute("SELECT value FROM kv WHERE key = ?", (COVERAGE_KEY,)).fetchone()
        finally:
            db.close()
        return 0 if row is None else int(json.loads(row[0])["looks"])

    log = tmp_path / "companion.log"
    with LiveSim(preset("light"), patrol_first_victim=True, speed_m_s=0.4) as sim:
        cfg = service._config(tmp_path, sim)
        proc = service._start(cfg, log)
        try:
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and saved_looks() < 5:  # the periodic save
                time.sleep(1.0)
        finally:
            assert service._stop(proc) == 0, log.read_text()[-3000:]
        first = saved_looks()
        assert first >= 5, log.read_text()[-3000:]
        proc = service._start(cfg, log)
        try:
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline and "coverage restored" not in log.read_text():
                time.sleep(0.5)
            time.sleep(8.0)
        finally:
            assert service._stop(proc) == 0, log.read_text()[-3000:]
    assert f"coverage restored: {first} looks" in log.read_text()
    assert saved_looks() > first
