"""SIGTERM/SIGINT handling of the service's main thread (companion/service/stopsignals.py)."""

from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Iterator

import pytest

from companion.service.stopsignals import HANDLED, StopSignals


@pytest.fixture
def stop_signals() -> Iterator[StopSignals]:
    previous = {s: signal.getsignal(s) for s in HANDLED}
    stop = StopSignals()
    stop.install()
    try:
        yield stop
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@pytest.mark.parametrize("signum", HANDLED, ids=lambda s: signal.Signals(s).name)
def test_a_signal_inside_event_wait_is_recorded_without_deadlock(
    stop_signals: StopSignals, signum: int
) -> None:
    """The service's main thread sits in Event.wait, which holds the event's lock for
    a few bytecodes before sleeping. systemd's SIGTERM right after READY once landed
    there, and a handler calling Event.set hung the process until SIGKILL. Here the
    signal is delivered while that lock is held, as it was then."""
    waiting = threading.Event()
    assert stop_signals.reason() is None
    with waiting._cond:  # the state Event.wait is in just before it sleeps
        os.kill(os.getpid(), signum)
        deadline = time.monotonic() + 5.0
        while stop_signals.reason() is None and time.monotonic() < deadline:
            pass  # the handler runs in this thread, between these bytecodes
        reason = stop_signals.reason()
    assert reason == f"signal {signal.Signals(signum).name}"
    assert not waiting.is_set()  # the main loop, not the handler, sets the stop event
