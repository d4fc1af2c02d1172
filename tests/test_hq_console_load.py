"""The console under load: what it costs the HQ, and what happens when too many connect.

A real `rescue-hq` process (UDP and HTTP on 127.0.0.1, SQLite registry) fed by
hq.simrobot robots; connections are plain sockets held open the way a flood of
browsers (or a broken proxy) would hold them.
"""

from __future__ import annotations

import contextlib
import json
import os
import resource
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bench.hq_console import HqConsoleProcess, Mission
from fusion.types import Urgency

FD_LIMIT = 1024  # a laptop's default soft limit of open files
ORIGIN = "47.397742,8.545594,488"  # victims on QGC's map need a place on Earth


def _status(url: str, timeout_s: float = 3.0) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as resp:
            return resp.status, resp.read(200)
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def _hold(address: tuple[str, int], count: int, request: bytes | None) -> list[socket.socket]:
    """``count`` connections held open; each sends ``request`` (None: sends nothing)."""
    held = []
    for _ in range(count):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.settimeout(5.0)
        s.connect(address)
        if request is not None:
            s.sendall(request)
        held.append(s)
    return held


@pytest.fixture
def room_for_sockets() -> Iterator[None]:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = 3000
    if hard != resource.RLIM_INFINITY and hard < want:
        pytest.skip(f"this test holds {want} sockets; the hard limit of open files is {hard}")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, want), hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


@pytest.mark.usefixtures("room_for_sockets")
def test_a_flood_of_console_connections_is_capped_and_said_once(tmp_path: Path) -> None:
    hq = HqConsoleProcess(tmp_path, "--sbs", "127.0.0.1:0", "--origin", ORIGIN, fd_limit=FD_LIMIT)
    mission = Mission(hq.address, (1,))
    held: list[socket.socket] = []
    try:
        mission.report(1, 1, 2.0, 3.0)
        assert hq.sbs is not None
        web = ("127.0.0.1", int(hq.url.rstrip("/").rsplit(":", 1)[1]))
        # 1200 connections, more than rescue-hq has file descriptors: pages that
        # keep their event stream open, then sockets that never send a request
        held += _hold(web, 600, b"GET /api/events HTTP/1.1\r\nHost: x\r\n\r\n")
        held += _hold(web, 600, None)
        time.sleep(1.0)
        # the radio side goes on: a new report is acknowledged (Mission waits for it)
        mission.report(1, 2, 6.0, 3.0)
        # a QGC connecting now gets the SBS-1 feed
        with socket.create_connection(hq.sbs, timeout=3.0) as qgc:
            assert qgc.recv(4096).startswith(b"MSG,")
        # a new browser is answered at once, and told why it is not served
        status, body = _status(hq.url)
        assert status == 503 and b"connections open" in body
        open_fds = len(os.listdir(f"/proc/{hq.proc.pid}/fd"))
        assert open_fds < FD_LIMIT // 2, f"{open_fds} descriptors open"
        for s in held:
            s.close()
        held = []
        deadline = time.monotonic() + 10.0
        while _status(hq.url)[0] != 200:  # room again: the page loads, its stream opens
            assert time.monotonic() < deadline, "the console did not serve pages again"
            time.sleep(0.2)
        with urllib.request.urlopen(hq.url + "api/events", timeout=5.0) as stream:
            assert stream.status == 200
            while not stream.readline().startswith(b"data: "):
                pass
    finally:
        for s in held:
            with contextlib.suppress(OSError):
                s.close()
        mission.close()
        code = hq.stop()
    log = "".join(hq.stderr)
    assert code == 0, log[-2000:]
    assert "Traceback" not in log and "Too many open files" not in log, log[-2000:]
    assert log.count("connections open, the most it serves") == 1, log[-2000:]
    assert log.count("live pages open, the most it serves") == 1, log[-2000:]


def _next_state(stream: Any) -> dict[str, Any]:
    while True:
        line = stream.readline()
        assert line, "the event stream ended"
        if line.startswith(b"data: "):
            return dict(json.loads(line[6:]))


def test_the_state_is_built_only_for_a_watcher_and_once_per_change(tmp_path: Path) -> None:
    hq = HqConsoleProcess(tmp_path, "--link-timeout-s", "60")
    mission = Mission(hq.address, (1, 2))
    try:
        # no page open: two seconds of reports build nothing...
        for i in range(10):
            mission.report(1 + i % 2, 10 + i, 3.0 * i, 1.0)
            time.sleep(0.2)
        with urllib.request.urlopen(hq.url + "api/state", timeout=5.0) as resp:
            asked = json.loads(resp.read())
        assert asked["builds"] == 1 and len(asked["victims"]) == 10  # ...until one is asked for
        with urllib.request.urlopen(hq.url + "api/state", timeout=5.0) as resp:
            assert json.loads(resp.read())["builds"] == 1  # nothing changed since
        # a page watches: it gets that state, then one build per change
        with urllib.request.urlopen(hq.url + "api/events", timeout=1.5) as stream:
            assert _next_state(stream)["builds"] == 1
            mission.report(2, 40, 30.0, 5.0, Urgency.CRITICAL)
            state = _next_state(stream)
            assert state["builds"] == 2 and state["victims"][0]["urgency"] == "CRITICAL"
            mission.report(1, 41, 33.0, 5.0)
            assert _next_state(stream)["builds"] == 3
            with pytest.raises(TimeoutError):  # nothing changes: nothing is built or sent
                _next_state(stream)
        # the page reloads: at once the state it had, with nothing built again
        with urllib.request.urlopen(hq.url + "api/events", timeout=1.5) as stream:
            assert _next_state(stream)["builds"] == 3
    finally:
        mission.close()
        assert hq.stop() == 0, "".join(hq.stderr)
