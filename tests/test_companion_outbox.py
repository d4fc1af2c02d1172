"""The companion's outbox on a real SQLite file: one pending report per victim, a
bound, the report and its outbox entry in one transaction, and acknowledgements
owned by the reporter thread, never written on a link reader thread."""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.config_load import config_from_dict
from companion.service.processing import FrameStats
from companion.service.run import Service
from companion.service.sdnotify import Notifier
from companion.storage.store import Store, StoreError
from fusion.types import TrackState, Urgency, VictimReport
from mavlink_io import convert, dialect
from mavlink_io.reliable import Outbox

M = dialect.load()
REPORT = dialect.RESCUE_VICTIM_REPORT_ID


def report_msg(victim_id: int, seq: int, flags: int = 0, north_m: float = 1.0) -> object:
    report = VictimReport(
        victim_id=victim_id,
        robot_sysid=7,
        state=TrackState.CONFIRMED,
        urgency=Urgency.MEDIUM,
        visibility_pct=30.0,
        north_m=north_m,
        east_m=2.0,
        down_m=0.1,
        cov_ne_m2=((0.04, 0.0), (0.0, 0.04)),
        observations=5,
        first_seen_unix_s=1.7e9,
        last_seen_unix_s=1.7e9 + 5,
    )
    return convert.victim_report_to_msg(report, seq, flags, 1.7e9 + 6, None, M)


def ack(seq: int) -> object:
    return M.MAVLink_rescue_ack_message(7, 191, REPORT, seq, 0)


def test_a_newer_report_replaces_the_pending_one_of_the_same_victim(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    sent: list[object] = []
    outbox = Outbox(sent.append, store=store)
    outbox.submit(report_msg(1, 1, flags=convert.FLAG_NEW), send=False)
    outbox.submit(report_msg(2, 2), send=False)
    outbox.submit(report_msg(1, 3, flags=convert.FLAG_MOVED, north_m=1.5), send=False)
    assert outbox.pending_keys() == [(REPORT, 2), (REPORT, 3)]
    assert [seq for _, seq, _ in store.pending()] == [2, 3]
    outbox.poll()
    newest = {m.report_seq: m for m in sent}[3]  # type: ignore[attr-defined]
    # The HQ still learns that victim 1 is new, from the report that replaced it.
    assert newest.flags & convert.FLAG_NEW and newest.flags & convert.FLAG_MOVED
    assert newest.north == pytest.approx(1.5)
    assert not outbox.on_ack(ack(1))  # the replaced report's late ack
    assert outbox.on_ack(ack(3)) and outbox.on_ack(ack(2))
    assert store.pending() == [] and outbox.pending_count == 0


def test_the_outbox_is_bounded_and_drops_the_oldest_loudly(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    store = Store(tmp_path / "s.sqlite")
    outbox = Outbox(lambda m: None, store=store, max_pending=3)
    for victim in range(1, 6):
        outbox.submit(report_msg(victim, victim), send=False)
    assert outbox.pending_keys() == [(REPORT, 3), (REPORT, 4), (REPORT, 5)]
    assert [seq for _, seq, _ in store.pending()] == [3, 4, 5]
    assert outbox.counters.dropped == 2
    assert "outbox full" in caplog.text


def test_a_restart_keeps_only_the_newest_report_of_each_victim(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    store = Store(path)
    frames = Outbox(lambda m: None)._frames  # the unsigned codec the store is written with
    for victim, seq in ((1, 1), (1, 2), (2, 3), (1, 4)):  # as an older version left it
        store.put(REPORT, seq, frames.encode(report_msg(victim, seq)))
    outbox = Outbox(lambda m: None, store=Store(path))
    assert outbox.pending_keys() == [(REPORT, 3), (REPORT, 4)]
    assert [seq for _, seq, _ in Store(path).pending()] == [3, 4]


def test_the_report_and_its_outbox_entry_commit_together(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    sent: list[object] = []
    outbox = Outbox(sent.append, store=store)
    with pytest.raises(RuntimeError), store.transaction():
        outbox.stage(report_msg(1, 1))
        assert outbox.poll() == 0  # not sent before it is on disk
        store.set("report_seq", 1)
        raise RuntimeError("disk full at commit")
    outbox.discard()
    assert store.pending() == [] and store.get("report_seq") is None
    assert outbox.poll() == 0 and outbox.pending_count == 0
    with store.transaction():
        outbox.stage(report_msg(1, 1))
        store.set("report_seq", 1)
    outbox.publish()
    assert outbox.poll() == 1 and [seq for _, seq, _ in store.pending()] == [1]


def test_frame_stats_are_read_while_processing_appends() -> None:
    stats = FrameStats()
    stop = threading.Event()

    def append() -> None:
        while not stop.is_set():
            stats.add(time.monotonic(), 12.0)

    writer = threading.Thread(target=append)
    writer.start()
    try:
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            fps, vision_ms = stats.summary(time.monotonic())
            assert fps >= 0 and vision_ms in (0.0, 12.0)
    finally:
        stop.set()
        writer.join()


@pytest.fixture
def service(tmp_path: Path) -> Service:
    frames = tmp_path / "frames"
    frames.mkdir()
    image = np.full((480, 640, 3), 90, np.uint8)
    cv2.imwrite(str(frames / "1700000000000000.jpg"), image)
    config = config_from_dict(
        {
            "vehicle": {"url": "udpin:127.0.0.1:0"},
            "hq": {"tunnel": False},
            "camera": {"source": f"frames:{frames}"},
            "detector": {"backend": "classic"},
            "paths": {"state_dir": str(tmp_path / "state")},
        }
    )
    return Service(config, Notifier())


def test_an_ack_never_blocks_the_link_thread_on_a_locked_database(service: Service) -> None:
    runner = threading.Thread(target=service.run)
    runner.start()
    try:
        with service.store.transaction():
            service.outbox.stage(report_msg(1, 1))
        service.outbox.publish()
        locker = sqlite3.connect(str(service.store.path), isolation_level=None)
        locker.execute("BEGIN IMMEDIATE")  # another writer holds the database
        try:
            # What a link reader thread does with an acknowledgement it decoded.
            reader = threading.Thread(target=service._on_dialect, args=(ack(1),))
            reader.start()
            reader.join(timeout=2.0)  # the database stays locked longer than this
            assert not reader.is_alive(), "the link thread waited for SQLite"
        finally:
            locker.execute("ROLLBACK")
            locker.close()
        end = time.monotonic() + 10.0
        while service.outbox.pending_count and time.monotonic() < end:
            time.sleep(0.05)
        assert service.outbox.pending_count == 0
        assert service.store.pending() == []
    finally:
        service.stop.set()
        runner.join(timeout=15)


def _decision(victim_id: int) -> object:
    from companion.reporting.policy import Decision
    from fusion.registry import Victim

    victim = Victim(
        victim_id=victim_id,
        state=TrackState.CONFIRMED,
        urgency=Urgency.MEDIUM,
        visibility_pct=30.0,
        north_m=1.0,
        east_m=2.0,
        cov_ne_m2=((0.04, 0.0), (0.0, 0.04)),
        observations=5,
        first_seen_unix_s=1.7e9,
        last_seen_unix_s=1.7e9 + 5,
        log_odds=3.0,
        merged_into=None,
    )
    return Decision(victim, convert.FLAG_NEW, announce=True)


def test_a_full_disk_keeps_the_reports_in_memory_and_writes_them_when_space_returns(
    service: Service, caplog: pytest.LogCaptureFixture
) -> None:
    db = service.store._conn()
    pages = db.execute("PRAGMA page_count").fetchone()[0]
    db.execute(f"PRAGMA max_page_count = {pages + 4}")  # a disk with 4 pages left
    filler = 0
    with pytest.raises(StoreError, match="full"):  # fill them, as recorded frames would
        while True:
            filler += 1
            service.store.set(f"filler{filler}", "x" * 2000)
    with caplog.at_level(logging.ERROR):
        service.ledger.commit([_decision(1)])  # must not raise: the processing thread lives on
        service.ledger.commit([_decision(2)])
    assert service.outbox.pending_count == 0  # nothing is sent that is not on disk
    assert service.store.pending() == []
    full = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(full) == 1 and "full" in full[0].getMessage()  # said once, loudly
    db.execute("PRAGMA max_page_count = 1000000")  # space returns
    service.ledger.commit([])  # the next save writes what was kept
    assert sorted(seq for _, seq, _ in service.store.pending()) == [1, 2]
    assert service.outbox.pending_count == 2
    assert service.store.get("report_seq") == 2
