"""A corrupt, malformed or 0-byte state file: moved aside with a time stamp, said
once, and a new ID epoch so no victim ID or report sequence number is reused."""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.reporting.policy import ReportPolicy
from companion.storage.recovery import EPOCH_SPAN, load_state
from companion.storage.store import Store
from fusion.params import TrackerParams
from fusion.types import Observation

PARAMS = TrackerParams()


def _policy() -> ReportPolicy:
    return ReportPolicy(1.0)


def _confirm_one(tracker: object, t0: float = 1.7e9) -> int:
    for k in range(5):
        obs = Observation(t0 + k, 1.0, 1.0, ((0.04, 0.0), (0.0, 0.04)), 50.0, 1.0, 3.0)
        for ev in tracker.update([obs], t0 + k, lambda n, e: True):  # type: ignore[attr-defined]
            if ev.kind.name == "CONFIRMED":
                return int(ev.victim.victim_id)
    raise AssertionError("never confirmed")


def _save(state: object) -> None:
    store = state.store  # type: ignore[attr-defined]
    with store.transaction():
        store.set("tracker", state.tracker.snapshot())  # type: ignore[attr-defined]
        store.set("report_seq", state.report_seq + 5)  # type: ignore[attr-defined]
    store.close()


def test_first_run_good_restart_then_a_0_byte_file(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    first = load_state(tmp_path, PARAMS, _policy())
    assert (first.epoch, first.report_seq) == (0, 0)
    assert _confirm_one(first.tracker) == 1
    _save(first)
    again = load_state(tmp_path, PARAMS, _policy())
    assert again.epoch == 0 and again.report_seq == 5 and again.problem is None
    assert [v.victim_id for v in again.tracker.victims()] == [1]
    again.store.close()

    (tmp_path / "companion.sqlite").write_bytes(b"")  # e.g. a full disk at creation
    with caplog.at_level(logging.ERROR):
        fresh = load_state(tmp_path, PARAMS, _policy())
    assert fresh.epoch == 1 and fresh.problem is not None and "0 bytes" in fresh.problem
    assert fresh.moved_aside is not None and fresh.moved_aside.exists()
    assert fresh.moved_aside.name.startswith("companion.sqlite.corrupt-")
    assert fresh.report_seq == EPOCH_SPAN  # the next report is EPOCH_SPAN + 1
    assert _confirm_one(fresh.tracker) == EPOCH_SPAN + 1  # victim 1 is never reused
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "moved aside" in errors[0].getMessage()
    fresh.store.close()


@pytest.mark.parametrize(
    "damage",
    ["garbage", "bad_json", "bad_snapshot"],
)
def test_malformed_state_is_moved_aside_in_a_new_epoch_each_time(
    tmp_path: Path, damage: str
) -> None:
    path = tmp_path / "companion.sqlite"
    load_state(tmp_path, PARAMS, _policy()).store.close()
    for expected_epoch in (1, 2):
        if damage == "garbage":
            path.write_bytes(b"not a database at all" * 200)
        else:
            store = Store(path)
            if damage == "bad_json":
                store._conn().execute("UPDATE kv SET value = '{oops' WHERE key = 'report_seq'")
            else:
                store.set("tracker", {"format": "something else"})
            store.close()
        state = load_state(tmp_path, PARAMS, _policy())
        assert state.epoch == expected_epoch, state.problem
        assert state.report_seq == expected_epoch * EPOCH_SPAN
        state.store.close()
    assert len(list(tmp_path.glob("companion.sqlite.corrupt-*"))) >= 2


def test_run_with_a_corrupt_state_file_keeps_running(tmp_path: Path) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "1700000000000000.jpg"), np.full((480, 640, 3), 90, np.uint8))
    state = tmp_path / "state"
    state.mkdir()
    (state / "companion.sqlite").write_bytes(b"\x00garbage" * 500)
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        f"""
[vehicle]
url = "udpin:127.0.0.1:0"
[camera]
source = "frames:{frames}"
[detector]
backend = "classic"
[paths]
state_dir = "{state}"
"""
    )
    log = tmp_path / "log.txt"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion.commands.cli", "run", "--config", str(cfg)],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        end = time.monotonic() + 20.0
        while "running:" not in log.read_text() and time.monotonic() < end:
            assert proc.poll() is None, log.read_text()
            time.sleep(0.1)
        assert proc.poll() is None, log.read_text()
    finally:
        proc.send_signal(signal.SIGTERM)
        status = proc.wait(timeout=20)
    text = log.read_text()
    assert status == 0, text
    assert text.count("moved aside") == 1, text
    assert "Traceback" not in text
    assert (state / "id_epoch").read_text().strip() == "1"
