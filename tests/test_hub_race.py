"""The UDP hub's peer table is shared by two threads of rescue-hq.

The reader thread records every robot it hears (a new peer, expiry, eviction at
64) while the main thread sends the 1 Hz HEARTBEAT to every live peer. A change
of the table during that iteration once raised RuntimeError in the main thread
and ended rescue-hq. Here the real hub on 127.0.0.1 hears datagrams from new
source ports all the time while the main thread broadcasts; the thread switch
interval is lowered so that the two threads interleave often enough to matter.
"""

from __future__ import annotations

import socket
import sys
import threading
import time
from collections.abc import Iterator

import pytest

from mavlink_io.hub import UdpHubLink

_RUN_S = 5.0  # the unguarded table failed within a second at this switch interval


@pytest.fixture
def fast_switching() -> Iterator[None]:
    before = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


def test_heartbeat_to_all_peers_while_new_robots_are_heard(fast_switching: None) -> None:
    hub = UdpHubLink("127.0.0.1", 0)
    address = hub.local_address
    stop = threading.Event()
    reader_errors: list[BaseException] = []

    def reader() -> None:  # as HqApp's reader thread
        try:
            while not stop.is_set():
                hub.receive(0.1)
        except BaseException as exc:  # the test reports it
            reader_errors.append(exc)

    def robots() -> None:  # every datagram from a new port: a new peer
        while not stop.is_set():
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(b"x", address)

    threads = [threading.Thread(target=f, daemon=True) for f in (reader, robots)]
    for t in threads:
        t.start()
    broadcasts = 0
    try:
        end = time.monotonic() + _RUN_S
        while time.monotonic() < end:
            hub.broadcast(b"heartbeat")  # raised RuntimeError when the table changed
            for _ in range(50):  # the same walk over the table, without the sends' syscalls
                assert len(hub.live_peers()) <= 64
            broadcasts += 1
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=2.0)
        hub.close()
    assert reader_errors == []
    assert broadcasts > 0
    assert hub.dropped_peers > 0  # the table was full and evicting: the busiest case
