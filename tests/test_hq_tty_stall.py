"""A terminal nobody reads never stops rescue-hq's acknowledgements.

The operator pauses the terminal (Ctrl-S), the ssh session stalls, or the output
goes to a ``| less`` nobody scrolls: the terminal stops reading. rescue-hq's main
thread, which acknowledges the robots' reports, used to write the live table and
the event lines itself and blocked once the terminal's buffer was full. Here the
real `rescue-hq` runs on a real pty whose other end the test stops reading, and on
a pipe nobody reads; a simulated robot (hq.simrobot) reports and waits for its
acknowledgements over loopback UDP, as a robot would.
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hqproc import ACCEPTED, ACK_TIMEOUT_S, REPO, ack_for

from hq.simrobot import SimRobot

_HQ_ARGS = ("--listen", "udpin:127.0.0.1:0", "--sbs", "off", "--no-web", "--duration-s", "60")


@pytest.fixture
def on_pty(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], int]]:
    """rescue-hq with a pty as its terminal; yields it and the pty's master side."""
    master, slave = pty.openpty()
    with open(tmp_path / "hq.err", "wb") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hq.cli", *_HQ_ARGS, "--db", str(tmp_path / "hq.sqlite")],
            cwd=REPO, stdin=slave, stdout=slave, stderr=err, close_fds=True,
        )  # fmt: skip
    os.close(slave)
    try:
        yield proc, master
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=15)
        os.close(master)


def _read_until(master: int, pattern: bytes, timeout_s: float) -> re.Match[bytes]:
    seen = b""
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        readable, _, _ = select.select([master], [], [], left)
        if readable:
            seen += os.read(master, 65536)
            if match := re.search(pattern, seen):
                return match
    raise TimeoutError(f"no {pattern!r} on the terminal; last: {seen[-300:]!r}")


def _wait_acks(robot: SimRobot, seqs: set[int]) -> None:
    """Every report in ``seqs`` acknowledged ACCEPTED within ACK_TIMEOUT_S."""
    waiting = set(seqs)
    deadline = time.monotonic() + ACK_TIMEOUT_S
    while waiting and (left := deadline - time.monotonic()) > 0:
        for rx in robot.receive(left):
            if rx.msg.get_type() == "RESCUE_ACK" and rx.msg.seq in waiting:
                assert rx.msg.result == ACCEPTED
                waiting.discard(rx.msg.seq)
    assert not waiting, f"{len(waiting)} of {len(seqs)} reports not acknowledged"


def test_acks_go_on_while_the_terminal_is_paused(
    on_pty: tuple[subprocess.Popen[bytes], int],
) -> None:
    proc, master = on_pty
    port = int(_read_until(master, rb"listening on udpin:127\.0\.0\.1:(\d+)", 15.0)[1])
    # From here on nobody reads the terminal: its buffer fills with live tables.
    with SimRobot(3, ("127.0.0.1", port)) as robot:
        for victim_id in range(1, 101):  # a long table: ~11 kB a redraw, 2 a second
            msg = robot.report_msg(robot.victim(victim_id, victim_id * 2.0, 1.0))
            robot.send(msg)
            assert ack_for(robot, msg.report_seq).result == ACCEPTED
        end = time.monotonic() + 8.0  # the old main thread blocked within ~2 s of this
        victim_id = 100
        while time.monotonic() < end:
            victim_id += 1
            msg = robot.report_msg(robot.victim(victim_id, victim_id * 2.0, 1.0))
            robot.send(msg)
            assert ack_for(robot, msg.report_seq).result == ACCEPTED, f"victim {victim_id}"
            time.sleep(0.5)
    # The terminal reads again: it shows the newest table.
    _read_until(master, rf"victims {victim_id} ".encode(), 10.0)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=15) == 0


def test_acks_go_on_while_a_pipe_is_not_read_and_the_drop_is_said_once(
    tmp_path: Path,
) -> None:
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)  # a page: full after ~50 event lines
    err_path = tmp_path / "hq.err"
    with open(err_path, "wb") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hq.cli", *_HQ_ARGS, "--db", str(tmp_path / "hq.sqlite")],
            cwd=REPO, stdout=write_end, stderr=err, stdin=subprocess.DEVNULL,
        )  # fmt: skip
    os.close(write_end)
    try:
        first = b""
        while b"listening on" not in first:  # the one line read before nobody reads
            first += os.read(read_end, 1)
        port = int(os.read(read_end, 64).split(b"\n")[0].rsplit(b":", 1)[1])
        reports = 1200  # more event lines than rescue-hq keeps waiting (1000)
        with SimRobot(4, ("127.0.0.1", port)) as robot:
            for burst in range(0, reports, 100):
                msgs = [
                    robot.report_msg(robot.victim(v, v * 0.5, 1.0))
                    for v in range(burst + 1, burst + 101)
                ]
                for msg in msgs:
                    robot.send(msg)
                _wait_acks(robot, {msg.report_seq for msg in msgs})
        said = err_path.read_text().count("the terminal does not read")
        assert said == 1
        # The pipe is read again: the oldest lines, a line saying how many were
        # dropped, then the newest report.
        proc.send_signal(signal.SIGTERM)
        out = b""
        while chunk := os.read(read_end, 65536):
            out += chunk
        assert proc.wait(timeout=15) == 0
        text = out.decode()
        assert re.search(r"rescue-hq: \d+ line\(s\) of output dropped", text)
        assert f"victim {reports}" in text.splitlines()[-2] + text.splitlines()[-1]
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=15)
        os.close(read_end)
