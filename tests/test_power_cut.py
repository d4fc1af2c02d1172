"""A power cut on the robot loses no report at the HQ.

The robot's state is the real companion state (companion.storage.recovery, ledger, SQLite in
WAL mode). The power cut is injected: the robot runs in a child process with a
small preloaded library that records, at every fsync/fdatasync, the size of the
file it made durable; the robot is then killed, and the disk after the cut is the
database file with its write-ahead log cut back to the size last made durable
(what is only in the page cache is gone). The HQ is its real registry.
"""

from __future__ import annotations

import os
import random
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest

from fusion.types import Observation
from hq import wire
from hq.pictures import PictureIntake
from hq.ratelog import RateLimitedLog
from hq.records import StoreResult
from hq.registry import Registry
from hq.view import hq_victims
from mavlink_io import dialect, picture

REPO = Path(__file__).resolve().parents[1]
M = dialect.load()
PLACES_M = ((0.0, 0.0), (10.0, 0.0), (20.0, 0.0), (30.0, 0.0))  # four people, far apart

_SHIM = r"""
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

static void durable(int fd) {
    const char *log = getenv("SYNC_LOG");
    char link[64], path[4096];
    struct stat st;
    if (!log) return;
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    ssize_t n = readlink(link, path, sizeof path - 1);
    if (n < 0 || fstat(fd, &st) != 0) return;
    path[n] = 0;
    FILE *f = fopen(log, "a");
    if (!f) return;
    fprintf(f, "%s %lld\n", path, (long long)st.st_size);
    fclose(f);
}

int fsync(int fd) {
    static int (*real)(int);
    if (!real) real = (int (*)(int))dlsym(RTLD_NEXT, "fsync");
    int r = real(fd);
    if (r == 0) durable(fd);
    return r;
}

int fdatasync(int fd) {
    static int (*real)(int);
    if (!real) real = (int (*)(int))dlsym(RTLD_NEXT, "fdatasync");
    int r = real(fd);
    if (r == 0) durable(fd);
    return r;
}
"""

# The robot's second run, in the child: two more people confirmed and reported (what
# its reporter would send is printed), then the power goes.
_CHILD = """
import os, sys
from pathlib import Path
from test_power_cut import confirm
from test_action_order import Robot
robot = Robot(Path(sys.argv[1]))
for north_m in (10.0, 20.0):
    for frame in confirm(robot, north_m, 0.0):
        print(frame.hex(), flush=True)
os._exit(0)
"""


def confirm(robot: Any, north_m: float, east_m: float) -> list[bytes]:
    """See a person at (north_m, east_m) until confirmed; the frames this adds to the
    outbox, which the reporter then sends to the HQ."""
    before = {seq for _, seq, _ in robot.store.pending()}
    now = time.time()
    cov = ((0.04, 0.0), (0.0, 0.04))
    events = []
    for k in range(6):
        t = now + k * 0.1
        obs = Observation(t, north_m, east_m, cov, 40.0, 1.0, 2.0)
        events += robot.tracker.update([obs], t, lambda n, e: True)
    robot.ledger.commit(robot.policy.decide(events, robot.tracker.victims(), now))
    return [frame for _, seq, frame in robot.store.pending() if seq not in before]


def _to_hq(registry: Registry, frames: list[bytes]) -> list[StoreResult]:
    codec = M.MAVLink(None, 0, 0)
    msgs = [m for f in frames for m in codec.parse_buffer(f) or []]
    return registry.store_reports([wire.incoming_report(m, time.time()) for m in msgs])


@pytest.fixture
def shim(tmp_path: Path) -> Path:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc) to build the fsync-recording library")
    src, lib = tmp_path / "durable.c", tmp_path / "durable.so"
    src.write_text(_SHIM)
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(lib), str(src), "-ldl"], check=True)
    return lib


def _disk_after_the_cut(state_dir: Path, sync_log: Path, into: Path) -> None:
    """The state directory as a power cut leaves it: the write-ahead log holds only
    what was last made durable (the database file itself is written only at a
    checkpoint, which makes it durable)."""
    into.mkdir()
    synced: dict[str, int] = {}
    for line in sync_log.read_text().splitlines() if sync_log.exists() else []:
        path, size = line.rsplit(" ", 1)
        synced[path] = int(size)
    for f in state_dir.iterdir():
        if f.name.endswith("-shm"):
            continue  # shared memory, rebuilt from the log at the next open
        if f.name.endswith("-wal"):
            keep = synced.get(str(f), 0)
            (into / f.name).write_bytes(f.read_bytes()[:keep])
        else:
            shutil.copy2(f, into / f.name)


def test_reports_sent_before_a_power_cut_are_never_reused(tmp_path: Path, shim: Path) -> None:
    from test_action_order import Robot

    state_dir = tmp_path / "robot"
    with Registry(tmp_path / "hq.sqlite") as hq:
        # First run: one person reported, a clean stop.
        robot = Robot(state_dir)
        assert _to_hq(hq, confirm(robot, *PLACES_M[0])) == [StoreResult.ACCEPTED]
        robot.store.close()
        # Second run: two more people reported, then the power goes.
        sync_log = tmp_path / "synced.txt"
        env = {
            **os.environ,
            "LD_PRELOAD": str(shim),
            "SYNC_LOG": str(sync_log),
            "PYTHONPATH": os.pathsep.join([str(REPO), str(REPO / "tests")]),
        }
        child = subprocess.run(
            [sys.executable, "-c", textwrap.dedent(_CHILD), str(state_dir)],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert child.returncode == 0, child.stderr
        sent = [bytes.fromhex(line) for line in child.stdout.split()]
        assert len(sent) == 2
        assert _to_hq(hq, sent) == [StoreResult.ACCEPTED] * 2
        after = tmp_path / "robot-after-cut"
        _disk_after_the_cut(state_dir, sync_log, after)
        # Power back: the robot starts from what its disk kept and finds a fourth person.
        robot = Robot(after)
        try:
            results = _to_hq(hq, confirm(robot, *PLACES_M[3]))
        finally:
            robot.store.close()
        assert results == [StoreResult.ACCEPTED]
        shown = sorted(round(v.north_m) for v in hq_victims(hq))
        assert shown == [round(n) for n, _ in PLACES_M]


def _jpeg(size: int, seed: int) -> bytes:
    return b"\xff\xd8" + random.Random(seed).randbytes(size - 4) + b"\xff\xd9"


def test_a_picture_number_given_out_again_is_stored_not_just_answered(tmp_path: Path) -> None:
    """After a cut that lost its last commits, a robot may number another picture of
    a victim as one the HQ holds: the HQ stores it (the robot's newest) instead of
    answering STORED for bytes it does not have; an older number is answered REJECTED."""
    answers: list[tuple[int, int]] = []
    with Registry(tmp_path / "hq.sqlite") as hq:
        intake = PictureIntake(hq, RateLimitedLog(60.0), lambda _line: None)

        def send(picture_id: int, jpeg: bytes) -> None:
            for chunk in picture.split(picture_id, 7, jpeg):
                msg = M.MAVLink(None, 3, 191).parse_buffer(
                    chunk.asking().to_msg(M).pack(M.MAVLink(None, 3, 191))
                )[0]
                intake.on_chunk(msg, lambda pid, result, _got: answers.append((pid, result)))

        first, again = _jpeg(400, 1), _jpeg(300, 2)
        send(40, first)
        assert answers[-1] == (40, picture.RESULT_STORED) and hq.picture(3, 7) == first
        send(40, again)  # the same number, another picture
        assert answers[-1] == (40, picture.RESULT_STORED) and hq.picture(3, 7) == again
        send(39, first)  # older than the one kept
        assert answers[-1] == (39, picture.RESULT_REJECTED) and hq.picture(3, 7) == again
