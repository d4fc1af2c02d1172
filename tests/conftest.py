"""Shared fixtures. Fakes, where any are allowed, live here too."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

# ../shared/data beside the checkout (CI has it there; a user's clone may not).
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real test data folder; the test skips, naming the path, when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real test data not found at {SHARED_DATA}")
    return SHARED_DATA


# -- live mission helpers: a ground peer and a systemd notify socket ----------------------


class GroundPeer:
    """A minimal ground station on a real UDP socket: 1 Hz HEARTBEAT (so the rover
    routes to it), records everything that arrives (TUNNEL unwrapped), and
    acknowledges RESCUE_VICTIM_REPORTs while ``acking`` is set."""

    def __init__(self, url: str) -> None:
        from mavlink_io.codec import Codec
        from mavlink_io.link import open_link
        from mavlink_io.linkspec import parse_link

        self.link = open_link(parse_link(url))
        self.codec = Codec(245, 190)
        self.m = self.codec.module
        self.acking = threading.Event()
        self.messages: list[tuple[float, Any]] = []
        self._cond = threading.Condition(threading.RLock())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from mavlink_io import tunnel

        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 1.0
                self.link.write(
                    self.codec.encode(self.m.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3))
                )
            data = self.link.read(0.1)
            for msg in self.codec.feed(data) if data else ():
                if tunnel.is_ours(msg):
                    inner = tunnel.unpack_tunnel(msg, self.codec)
                    if inner is None:
                        continue
                    msg = inner
                if msg.get_type() == "RESCUE_VICTIM_REPORT" and self.acking.is_set():
                    ack = self.m.MAVLink_rescue_ack_message(
                        msg.get_srcSystem(), msg.get_srcComponent(), 43100, msg.report_seq, 0
                    )
                    self.link.write(
                        self.codec.encode(tunnel.wrap(self.codec, ack, msg.get_srcSystem()))
                    )
                with self._cond:
                    self.messages.append((time.monotonic(), msg))
                    self._cond.notify_all()

    def of_type(self, name: str, since_s: float = 0.0) -> list[Any]:
        with self._cond:  # re-entrant use from wait_until's condition is fine: RLock
            return [m for t, m in self.messages if m.get_type() == name and t >= since_s]

    def wait_for(self, pred: Callable[[Any], bool], timeout_s: float, since_s: float = 0.0) -> Any:
        end = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for t, m in self.messages:
                    if t >= since_s and pred(m):
                        return m
                remaining = end - time.monotonic()
                if remaining <= 0:
                    types = sorted({m.get_type() for _, m in self.messages})
                    raise AssertionError(f"no matching message within {timeout_s} s; got {types}")
                self._cond.wait(remaining)

    def wait_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Wait, re-checking as messages arrive, until ``condition()`` holds."""
        with self._cond:
            return self._cond.wait_for(condition, timeout_s)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.link.close()


class NotifySocket:
    """The receiving end of sd_notify: what systemd would read from NOTIFY_SOCKET."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.received: list[tuple[float, str]] = []
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            with self._cond:
                self.received.append((time.monotonic(), data.decode()))
                self._cond.notify_all()

    def times_of(self, line: str) -> list[float]:
        with self._cond:
            return [t for t, text in self.received if line in text.splitlines()]

    def wait_for(self, line: str, timeout_s: float) -> float:
        end = time.monotonic() + timeout_s
        with self._cond:
            while True:
                times = [t for t, text in self.received if line in text.splitlines()]
                if times:
                    return times[0]
                remaining = end - time.monotonic()
                if remaining <= 0:
                    raise AssertionError(f"no {line!r} within {timeout_s} s: {self.received[-5:]}")
                self._cond.wait(remaining)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.sock.close()


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[NotifySocket]:
    sock = NotifySocket(tmp_path / "notify.sock")
    yield sock
    sock.close()
