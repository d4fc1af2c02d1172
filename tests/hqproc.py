"""A real `rescue-hq` process for tests, and what a simulated robot waits for from it.

``HqProcess`` starts `python -m hq.cli` on 127.0.0.1 port 0 (the HQ prints the bound
port) with its stdout and stderr lines on queues; ``start_hq`` is the fixture that
starts them and cleans them up (each test file defines ``start_hq`` with ``hq_starter``).
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from hq.simrobot import SimRobot
from mavlink_io.dialect import RESCUE_OPERATOR_ACTION_ID

REPO = Path(__file__).resolve().parents[1]
ACCEPTED, DUPLICATE, REJECTED = 0, 1, 2
ACK_TIMEOUT_S = 3.0  # loopback round trip is ~1 ms; 3 s absorbs a loaded 2-core machine


class HqProcess:
    """A running `rescue-hq`, its stdout lines on a queue."""

    def __init__(self, tmp: Path, *extra: str, db: Path | None = None) -> None:
        self.db = db or tmp / "hq.sqlite"
        self.export_dir = tmp / "export"
        cmd = [
            sys.executable, "-m", "hq.cli",
            "--listen", "udpin:127.0.0.1:0",
            "--db", str(self.db),
            "--export-dir", str(self.export_dir),
            "--no-table", "--duration-s", "120", *extra,
        ]  # fmt: skip
        self.proc = subprocess.Popen(
            cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self.err_lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        self._pumps = [
            threading.Thread(target=self._pump, daemon=True),
            threading.Thread(target=self._pump_err, daemon=True),
        ]
        for pump in self._pumps:
            pump.start()
        line = self.wait_line("listening on", 15.0)
        self.port = int(line.rsplit(":", 1)[1])
        self.address = ("127.0.0.1", self.port)

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def _pump_err(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append(line)
            self.err_lines.put(line.rstrip("\n"))

    def wait_line(self, text: str, timeout_s: float, *, stderr: bool = False) -> str:
        lines = self.err_lines if stderr else self.lines
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(
                    f"rescue-hq printed no line with {text!r}; stderr: {self.stderr}"
                )
            try:
                line = lines.get(timeout=left)
            except queue.Empty:
                continue
            if text in line:
                return line

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=15)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=15)
        for pump in self._pumps:
            pump.join(timeout=5)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()

    def kill9(self) -> None:
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(timeout=15)


def hq_starter(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    """The body of a ``start_hq`` fixture: start HqProcesses, close them all at the end."""
    started: list[HqProcess] = []

    def start(*extra: str, db: Path | None = None) -> HqProcess:
        hq = HqProcess(tmp_path, *extra, db=db)
        started.append(hq)
        return hq

    yield start
    for hq in started:
        hq.close()


def acks_waiting(robot: SimRobot) -> list[object]:
    """RESCUE_ACKs already in the robot's socket (HEARTBEATs from the HQ are expected)."""
    out = []
    while batch := robot.receive(0.0):
        out += [rx.msg for rx in batch if rx.msg.get_type() == "RESCUE_ACK"]
    return out


def answer_action(robot: SimRobot, action: object, result: int) -> None:
    """The robot acknowledges an operator action it received, with ``result``."""
    robot.send(
        robot.m.MAVLink_rescue_ack_message(
            action.get_srcSystem(),  # type: ignore[attr-defined]
            action.get_srcComponent(),  # type: ignore[attr-defined]
            RESCUE_OPERATOR_ACTION_ID,
            action.action_seq,  # type: ignore[attr-defined]
            result,
        )
    )


def ack_for(robot: SimRobot, seq: int) -> object:
    return robot.wait_for("RESCUE_ACK", ACK_TIMEOUT_S, acked_msgid=43100, seq=seq).msg


def start_companion(
    tmp_path: Path, vehicle_url: str, camera_source: str, hq_port: int, extra_toml: str = ""
) -> tuple[subprocess.Popen[bytes], Path]:
    """`rescue-companion run` talking straight to the HQ at ``hq_port`` (no tunnel),
    its state in tmp_path/state; returns the process and its log file."""
    cfg = tmp_path / "companion.toml"
    cfg.write_text(
        f'[vehicle]\nurl = "{vehicle_url}"\n'
        f'[hq]\nurl = "udpout:127.0.0.1:{hq_port}"\ntunnel = false\nresend_initial_s = 0.5\n'
        f'[camera]\nsource = "{camera_source}"\n'
        f'[paths]\nstate_dir = "{tmp_path / "state"}"\n' + extra_toml
    )
    log = tmp_path / "companion.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion.commands.cli", "run", "--config", str(cfg)],
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    return proc, log


def mark(db: Path, robot: int, victim: int, action: str) -> None:
    """The operator's decision through `rescue-hq mark` (``action``: rescued, ...)."""
    done = subprocess.run(
        [
            sys.executable, "-m", "hq.cli", "mark", "--db", str(db),
            "--robot", str(robot), "--victim", str(victim), f"--{action}",
        ],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
