"""rescue-hq on a full disk: keeps running, says so loudly, stores when space returns.

The end-to-end test puts the registry on a real, small tmpfs (mounting needs root;
without it the test is skipped and says why) and fills it with a file. The
in-process test reaches the same SQLITE_FULL with ``PRAGMA max_page_count`` so it
runs everywhere.
"""

from __future__ import annotations

import errno
import os
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hqproc import ACCEPTED, ACK_TIMEOUT_S, HqProcess, ack_for, acks_waiting, hq_starter

from fusion.types import TrackState, Urgency, VictimReport
from hq.records import IncomingReport, StoreResult
from hq.registry import Registry
from hq.registry_file import RegistryFull
from hq.simrobot import SimRobot

_FS_BYTES = 4 * 1024 * 1024


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


@pytest.fixture
def small_fs(tmp_path: Path) -> Iterator[Path]:
    """A 4 MB tmpfs of our own (needs root), unmounted afterwards."""
    mount_point = tmp_path / "small"
    mount_point.mkdir()
    if os.geteuid() != 0:
        pytest.skip("a real full disk needs root to mount a small tmpfs")
    result = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={_FS_BYTES}", "tmpfs", str(mount_point)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if result.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {result.stderr.strip()}")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=False)


def _fill(directory: Path) -> Path:
    """Fill the filesystem of ``directory`` to the last byte; the filler file."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        for size in (64 * 1024, 4096, 512, 1):
            try:
                while True:
                    os.write(fd, bytes(size))
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
    finally:
        os.close(fd)
    return filler


def test_full_disk_keeps_running_and_stores_when_space_returns(start_hq, small_fs: Path) -> None:
    hq = start_hq(db=small_fs / "hq.sqlite")
    with SimRobot(4, hq.address) as robot:
        first = robot.report_msg(robot.victim(1, 1.0, 1.0))
        robot.send(first)
        assert ack_for(robot, first.report_seq).result == ACCEPTED
        filler = _fill(small_fs)
        held = [robot.report_msg(robot.victim(v, float(v), 0.0)) for v in range(2, 12)]
        for msg in held:
            robot.send(msg)
        hq.wait_line("DISK FULL", 10.0, stderr=True)
        robot.status()  # other writes fail too, and must not take the HQ down
        text = robot.wait_for("STATUSTEXT", ACK_TIMEOUT_S, any_target=True).msg.text
        assert "disk full" in text
        assert hq.proc.poll() is None
        assert acks_waiting(robot) == []  # nothing acknowledged that is not on disk
        filler.unlink()
        # No resend needed: the HQ held them in memory and writes them now.
        for msg in held:
            assert ack_for(robot, msg.report_seq).result == ACCEPTED
        hq.wait_line("writable again", ACK_TIMEOUT_S, stderr=True)
    assert hq.stop() == 0
    assert not any("Traceback" in line for line in hq.stderr), "".join(hq.stderr)
    with Registry(hq.db) as reg:
        assert sorted(s.report.victim_id for s in reg.sources()) == list(range(1, 12))


def _incoming(victim: int, seq: int) -> IncomingReport:
    report = VictimReport(
        victim_id=victim, robot_sysid=1, state=TrackState.CONFIRMED, urgency=Urgency.MEDIUM,
        visibility_pct=30.0, north_m=float(victim), east_m=0.0, down_m=0.0,
        cov_ne_m2=((0.25, 0.0), (0.0, 0.25)), observations=3,
        first_seen_unix_s=1_700_000_000.0, last_seen_unix_s=1_700_000_001.0,
    )  # fmt: skip
    return IncomingReport(report, seq, 1_700_000_001_000_000 + seq, 0, 191, 1_700_000_001.0)


def test_registry_full_is_a_clean_error_and_the_next_write_works(tmp_path: Path) -> None:
    with Registry(tmp_path / "r.sqlite") as reg:
        assert reg.store_reports([_incoming(1, 1)]) == [StoreResult.ACCEPTED]
        pages = reg._db.execute("PRAGMA page_count").fetchone()[0]
        reg._db.execute(f"PRAGMA max_page_count={pages}")  # the file may not grow: "full"
        big = [_incoming(v, v) for v in range(2, 400)]
        with pytest.raises(RegistryFull, match="full"):
            reg.store_reports(big)
        reg._db.execute("PRAGMA max_page_count=1073741823")  # space is back
        assert reg.store_reports(big) == [StoreResult.ACCEPTED] * len(big)
        assert reg.report_count() == 399
