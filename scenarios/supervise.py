"""A child process kept running as systemd keeps a service: restarted after a delay.

    companion = Supervised("rescue-companion", argv, log_path, restart_delay_s=2.0)
    companion.start()
    companion.signal(signal.SIGKILL)   # a planned fault: restarted after the delay
    companion.stop()                   # SIGTERM, no restart; its exit status

Like ``Restart=on-failure`` with ``RestartPreventExitStatus=2``: an exit that was
not asked for is restarted unless its status is 0 or 2 (a bad configuration); a
planned signal is always followed by a restart. Every run is recorded (start, end,
exit status, the planned signal if any), so a restart loop shows as several
unplanned exits soon after their starts. Each start writes a marker line into the
shared log first.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

QUICK_EXIT_S = 10.0  # an unplanned exit sooner than this after the start is a restart loop's
_STOP_TIMEOUT_S = 15.0  # the companion's unit gives 8 s; a loaded machine may need more
_NO_RESTART = (0, 2)  # clean exit, bad configuration (RestartPreventExitStatus=2)


@dataclass
class ProcessRun:
    started_mono_s: float
    ended_mono_s: float | None = None
    returncode: int | None = None
    planned: str | None = None  # the signal we sent ("SIGKILL", "SIGTERM"), or None

    @property
    def quick_unplanned_exit(self) -> bool:
        return (
            self.planned is None
            and self.ended_mono_s is not None
            and self.ended_mono_s - self.started_mono_s < QUICK_EXIT_S
        )


def _all_cores() -> None:
    """In the child: undo a parent's pinning (``python -m bench`` pins itself to one core)."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, range(os.cpu_count() or 1))


class Supervised:
    """One service (see the module docstring). Thread-safe."""

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        log_path: Path,
        *,
        restart_delay_s: float,
        env: dict[str, str] | None = None,
    ) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_path
        self.restart_delay_s = restart_delay_s
        self.env = env
        self.runs: list[ProcessRun] = []
        self._proc: subprocess.Popen[bytes] | None = None
        self._wanted = False
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._watcher: threading.Thread | None = None

    def start(self) -> Supervised:
        with self._lock:
            self._wanted = True
            self._spawn()
        self._watcher = threading.Thread(target=self._watch, name=f"watch-{self.name}", daemon=True)
        self._watcher.start()
        return self

    def _spawn(self) -> None:
        with self.log_path.open("ab") as log:  # the child keeps its own descriptor
            log.write(f"--- chaos: start {self.name} #{len(self.runs) + 1}\n".encode())
            log.flush()
            self._proc = subprocess.Popen(
                self.argv,
                stdout=log,
                stderr=subprocess.STDOUT,
                env=self.env,
                preexec_fn=_all_cores,
            )
        self.runs.append(ProcessRun(time.monotonic()))

    def _watch(self) -> None:
        while True:
            proc = self._proc
            assert proc is not None
            rc = proc.wait()
            with self._lock:
                run = self.runs[-1]
                run.ended_mono_s, run.returncode = time.monotonic(), rc
                restart = self._wanted and (run.planned is not None or rc not in _NO_RESTART)
            if not restart or self._stopping.wait(self.restart_delay_s):
                return
            with self._lock:
                if not self._wanted:
                    return
                self._spawn()

    def running(self) -> bool:
        with self._lock:
            return self._proc is not None and self._proc.poll() is None

    def signal(self, sig: signal.Signals) -> bool:
        """Send a planned signal (the process is restarted after the delay); False when
        it was not running at that moment (between a crash and its restart)."""
        with self._lock:
            proc = self._proc
            if proc is None or proc.poll() is not None:
                return False
            self.runs[-1].planned = sig.name
            proc.send_signal(sig)
            return True

    def stop(self) -> int | None:
        """SIGTERM without restart; the exit status (None if it was not running)."""
        with self._lock:
            self._wanted = False
            self._stopping.set()
            proc = self._proc
            was_running = proc is not None and proc.poll() is None
            if was_running and proc is not None:
                self.runs[-1].planned = "stop"
                proc.send_signal(signal.SIGTERM)
        rc: int | None = None
        if proc is not None:
            try:
                rc = proc.wait(timeout=_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                rc = proc.wait()
        if self._watcher is not None:
            self._watcher.join(timeout=5.0)
        return rc if was_running else None

    def unplanned_exits(self) -> list[ProcessRun]:
        with self._lock:
            return [r for r in self.runs if r.planned is None and r.returncode is not None]

    def quick_unplanned_exits(self) -> int:
        with self._lock:
            return sum(r.quick_unplanned_exit for r in self.runs)
