"""Stopping the companion after a full disk: the reports it kept in memory are saved
with the rest, or said to be lost, never half saved.

Found by the chaos mission (bench/chaos.py): reports kept in memory while the disk
was full were left out of the shutdown save, which still saved the reporting policy
that counts them as told, so a stop soon after space returned (before the periodic
save) lost those victims for the HQ for good; and a stop on a full disk logged a
traceback.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.config_load import config_from_dict
from companion.reporting.policy import Decision
from companion.service.run import Service
from companion.service.sdnotify import Notifier
from companion.storage.store import Store, StoreError
from fusion.registry import Victim
from fusion.types import TrackState, Urgency
from mavlink_io import convert


@pytest.fixture
def service(tmp_path: Path) -> Service:
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "1700000000000000.jpg"), np.full((480, 640, 3), 90, np.uint8))
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


def _decision(victim_id: int) -> Decision:
    victim = Victim(
        victim_id=victim_id, state=TrackState.CONFIRMED, urgency=Urgency.MEDIUM,
        visibility_pct=30.0, north_m=1.0, east_m=2.0, cov_ne_m2=((0.04, 0.0), (0.0, 0.04)),
        observations=5, first_seen_unix_s=1.7e9, last_seen_unix_s=1.7e9 + 5, log_odds=3.0,
        merged_into=None,
    )  # fmt: skip
    return Decision(victim, convert.FLAG_NEW, announce=True)


def _fill(service: Service) -> None:
    """A disk with 4 pages left, then none (as recorded frames would fill it)."""
    db = service.store._conn()
    pages = db.execute("PRAGMA page_count").fetchone()[0]
    db.execute(f"PRAGMA max_page_count = {pages + 4}")
    n = 0
    with pytest.raises(StoreError, match="full"):
        while True:
            n += 1
            service.store.set(f"filler{n}", "x" * 2000)


def test_a_stop_right_after_space_returns_saves_the_kept_reports(service: Service) -> None:
    _fill(service)
    service.ledger.commit([_decision(1), _decision(2)])  # kept in memory
    service.store._conn().execute("PRAGMA max_page_count = 1000000")  # space returns
    path = service.store.path
    service.close()  # before the periodic save had its turn
    store = Store(path)
    try:
        assert sorted(seq for _, seq, _ in store.pending()) == [1, 2]
        assert store.get("report_seq") == 2
    finally:
        store.close()


def test_a_stop_on_a_full_disk_says_what_is_lost_without_a_traceback(
    service: Service, caplog: pytest.LogCaptureFixture
) -> None:
    _fill(service)
    with caplog.at_level(logging.ERROR):
        service.ledger.commit([_decision(3)])
        service.close()
    assert not any(r.exc_info for r in caplog.records), "a traceback was logged"
    assert any("not saved" in r.getMessage() and "[3]" in r.getMessage() for r in caplog.records)
