"""Shared fixtures. Fakes, where any are allowed, live here too."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

# ../shared/data beside the checkout (CI has it there; a user's clone may not).
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real test data folder; the test skips, naming the path, when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real test data not found at {SHARED_DATA}")
    return SHARED_DATA


LIGHT_PATROL_START_UNIX_S = 1_767_000_000.0


@pytest.fixture(scope="session")
def light_patrol(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 25 s recording of the rover patrolling across a fully visible victim (preset
    "light"), the thermal camera beside the colour one: recorded once per test
    process for the replay tests that read it (it takes 15-40 s to render)."""
    from scenarios.live import _patrol
    from scenarios.record import record
    from scenarios.world import preset

    out = tmp_path_factory.mktemp("light-patrol")
    record(_patrol(preset("light")), out, duration_s=25.0, start_unix_s=LIGHT_PATROL_START_UNIX_S)
    return out


# The checkout must stay clean: a telemetry log belongs where the config (or the
# test's tmp_path) says. MAVProxy writes mav.tlog and mav.tlog.raw into its working
# directory unless told otherwise, and such files were once committed at the root.
CHECKOUT = Path(__file__).resolve().parents[1]


def _stray_logs() -> set[str]:
    return {p.name for p in CHECKOUT.iterdir() if p.name.startswith("mav.") or p.suffix == ".tlog"}


@pytest.fixture(scope="session", autouse=True)
def no_logs_in_the_checkout() -> Iterator[None]:
    before = _stray_logs()
    yield
    new = sorted(_stray_logs() - before)
    assert not new, f"a test or the program wrote {new} into {CHECKOUT}; use tmp_path"


# -- live mission helpers: a systemd notify socket -------------------------------------------


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
