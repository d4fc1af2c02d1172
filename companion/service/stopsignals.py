"""SIGTERM and SIGINT, turned into a stop request the main loop polls.

The handler only records the signal. A Python signal handler runs in the main
thread between two of its bytecodes, and the main thread spends its life in
``threading.Event.wait``, which holds the event's (non-reentrant) lock for a few
bytecodes before it sleeps. A handler that called ``Event.set`` there would wait
for a lock its own thread holds: the process would hang until systemd's SIGKILL.
That happened when systemd stopped the service just after READY.
"""

from __future__ import annotations

import signal
from types import FrameType

HANDLED = (signal.SIGTERM, signal.SIGINT)


class StopSignals:
    """Install with ``install()``; ``reason()`` is None until a signal came."""

    def __init__(self) -> None:
        self._signum: int | None = None

    def install(self) -> None:
        for signum in HANDLED:
            signal.signal(signum, self._on_signal)

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self._signum = signum  # no lock, no logging, no I/O: see the module docstring

    def reason(self) -> str | None:
        """'signal SIGTERM' (or SIGINT) once one was received, else None."""
        if self._signum is None:
            return None
        return f"signal {signal.Signals(self._signum).name}"
