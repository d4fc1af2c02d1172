"""Links over real sockets on 127.0.0.1 and a real pseudo-terminal pair."""

from __future__ import annotations

import os
import pty
import socket
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from mavlink_io.errors import LinkError
from mavlink_io.link import Link
from mavlink_io.linkspec import LinkSpec, parse_link
from mavlink_io.netlinks import TcpInLink, TcpLink, UdpInLink, UdpOutLink
from mavlink_io.reconnect import ReconnectingLink, open_link
from mavlink_io.seriallink import SerialLink


@dataclass
class Pty:
    """A pseudo-terminal whose slave is reachable through a stable symlink."""

    master: int
    slave: int
    link_path: Path

    closed: bool = False

    def close(self) -> None:
        if not self.closed:  # never close a number twice: the OS reuses fd numbers
            self.closed = True
            os.close(self.master)
            os.close(self.slave)


def make_pty(link_path: Path) -> Pty:
    master, slave = pty.openpty()
    tty.setraw(slave)
    staging = link_path.with_suffix(".new")
    staging.unlink(missing_ok=True)
    os.symlink(os.ttyname(slave), staging)
    os.replace(staging, link_path)  # atomic: the path always names a live pty or none
    return Pty(master, slave, link_path)


@pytest.fixture
def serial_pty(tmp_path: Path) -> Iterator[Pty]:
    p = make_pty(tmp_path / "ttyAUTOPILOT")
    yield p
    p.close()


def read_until(link: Link, wanted: bytes, deadline_s: float) -> bytes:
    got = b""
    end = time.monotonic() + deadline_s
    while wanted not in got and time.monotonic() < end:
        got += link.read(0.05)
    return got


def test_open_link_chooses_transport_from_spec() -> None:
    udp = open_link(parse_link("udpin:127.0.0.1:0"))
    try:
        assert isinstance(udp, UdpInLink)
        assert udp.local_address[0] == "127.0.0.1" and udp.local_address[1] > 0
        assert udp.name == f"udpin:127.0.0.1:{udp.local_address[1]}"
        assert isinstance(udp, Link)
    finally:
        udp.close()
        udp.close()  # safe twice


def test_listening_links_name_the_os_chosen_port_and_refuse_it_once_closed() -> None:
    """Tests and the sim bind port 0; the chosen port is what a peer must be told."""
    from mavlink_io.hub import UdpHubLink

    links = [UdpInLink("127.0.0.1", 0), TcpInLink("127.0.0.1", 0), UdpHubLink("127.0.0.1", 0)]
    for link in links:
        host, port = link.local_address
        assert host == "127.0.0.1" and port > 0
        assert link.name.endswith(f":127.0.0.1:{port}")
        link.close()
        with pytest.raises(LinkError, match="closed"):
            link.local_address  # noqa: B018 (the property is the call under test)


def test_udpin_replies_to_last_speaker_and_drops_before_anyone_spoke() -> None:
    server = UdpInLink("127.0.0.1", 0)
    a = UdpOutLink("127.0.0.1", server.local_address[1])
    b = UdpOutLink("127.0.0.1", server.local_address[1])
    try:
        server.write(b"nobody")
        assert server.counters.writes_dropped == 1
        assert server.read(0.05) == b""  # timeout, not an error
        a.write(b"from-a")
        assert server.read(2.0) == b"from-a"
        server.write(b"to-a")
        assert a.read(2.0) == b"to-a"
        b.write(b"from-b")
        assert server.read(2.0) == b"from-b"
        server.write(b"to-b")
        assert b.read(2.0) == b"to-b"
        assert a.read(0.1) == b""
        assert server.counters.bytes_read == 12
    finally:
        for link in (server, a, b):
            link.close()


def test_udpout_survives_an_absent_listener() -> None:
    # A port nobody listens on: ICMP unreachable must not break the link.
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    out = UdpOutLink("127.0.0.1", port)
    try:
        out.write(b"x")
        out.write(b"y")
        assert out.read(0.1) == b""
    finally:
        out.close()


def test_tcp_client_and_server_exchange_and_detect_close() -> None:
    server = TcpInLink("127.0.0.1", 0)
    try:
        server.write(b"no-peer")
        assert server.counters.writes_dropped == 1
        client = TcpLink("127.0.0.1", server.local_address[1])
        client.write(b"hello")
        assert read_until(server, b"hello", 2.0) == b"hello"
        server.write(b"back")
        assert read_until(client, b"back", 2.0) == b"back"
        server.close()
        with pytest.raises(LinkError, match="closed by peer"):
            read_until(client, b"never", 2.0)
        client.close()
    finally:
        server.close()


def test_tcpin_takes_one_peer_at_a_time_newest_wins() -> None:
    server = TcpInLink("127.0.0.1", 0)
    first = TcpLink("127.0.0.1", server.local_address[1])
    links: list[Link] = [server, first]
    try:
        first.write(b"1")
        assert read_until(server, b"1", 2.0) == b"1"
        second = TcpLink("127.0.0.1", server.local_address[1])
        links.append(second)
        second.write(b"2")
        assert read_until(server, b"2", 2.0) == b"2"
        server.write(b"reply")
        assert read_until(second, b"reply", 2.0) == b"reply"
        with pytest.raises(LinkError):  # the replaced peer sees its connection closed
            read_until(first, b"never", 2.0)
    finally:
        for link in links:
            link.close()


def test_tcp_connect_refused_raises_link_error() -> None:
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    with pytest.raises(LinkError, match="cannot connect"):
        TcpLink("127.0.0.1", port)


def test_serial_pty_roundtrip(serial_pty: Pty) -> None:
    link = SerialLink(str(serial_pty.link_path), 921600)
    try:
        os.write(serial_pty.master, b"\xfd\x09abc")
        assert read_until(link, b"abc", 2.0) == b"\xfd\x09abc"
        link.write(b"to-autopilot")
        assert os.read(serial_pty.master, 100) == b"to-autopilot"
    finally:
        link.close()
        link.close()


def test_serial_missing_device_raises_link_error(tmp_path: Path) -> None:
    with pytest.raises(LinkError, match="cannot open"):
        SerialLink(str(tmp_path / "ttyNOPE"), 115200)


def test_serial_unplug_raises_link_error(serial_pty: Pty) -> None:
    link = SerialLink(str(serial_pty.link_path), 115200)
    try:
        serial_pty.close()
        with pytest.raises(LinkError):
            read_until(link, b"never", 2.0)
    finally:
        link.close()


def test_reconnecting_serial_works_again_within_2s_of_replug(tmp_path: Path) -> None:
    path = tmp_path / "ttyACM0"
    first = make_pty(path)
    link = ReconnectingLink(LinkSpec("serial", device=str(path), baud=921600), max_backoff_s=1.0)
    second: Pty | None = None
    try:
        assert link.connected
        os.write(first.master, b"one")
        assert read_until(link, b"one", 2.0) == b"one"
        first.close()  # unplug
        # The break is noticed at the next read, which must not raise.
        end = time.monotonic() + 2.0
        while link.connected and time.monotonic() < end:
            assert link.read(0.05) == b""
        assert not link.connected
        link.write(b"lost")  # dropped and counted, no exception
        assert link.counters.writes_dropped >= 1
        # Some reopening attempts fail while the device is absent: backoff grows.
        end = time.monotonic() + 1.5
        while time.monotonic() < end:
            link.read(0.1)
        assert link.counters.open_failures >= 2
        second = make_pty(path)  # replug at the same path
        plugged = time.monotonic()
        got = b""
        while b"two" not in got and time.monotonic() - plugged < 2.0:
            os.write(second.master, b"two")  # an autopilot streams; the open flushes input
            got += link.read(0.05)
        assert b"two" in got, "link did not work again within 2 s of the device coming back"
        assert link.connected and link.counters.reconnects == 1
        link.write(b"back")
        assert os.read(second.master, 100).endswith(b"back")
    finally:
        link.close()
        link.close()
        first.close()
        if second is not None:
            second.close()


def test_reconnecting_link_never_raises_while_device_absent(tmp_path: Path) -> None:
    link = ReconnectingLink(
        LinkSpec("serial", device=str(tmp_path / "ttyNONE"), baud=57600),
        initial_backoff_s=0.05,
        max_backoff_s=0.2,
    )
    try:
        assert not link.connected
        start = time.monotonic()
        for _ in range(10):
            assert link.read(0.1) == b""
        elapsed = time.monotonic() - start
        # read waits (no busy loop): 10 reads of <= 0.1 s take about a second.
        assert 0.5 < elapsed < 3.0
        # With a 0.2 s cap, about 5-7 attempts fit in ~1 s (0.05, 0.1, 0.2, 0.2, ...).
        assert 3 <= link.counters.open_failures <= 12
    finally:
        link.close()
    with pytest.raises(LinkError):
        link.read(0.01)


def test_reconnecting_tcp_client_reconnects_to_restarted_server() -> None:
    server = TcpInLink("127.0.0.1", 0)
    port = server.local_address[1]
    link = ReconnectingLink(LinkSpec("tcp", host="127.0.0.1", port=port), max_backoff_s=0.2)
    try:
        link.write(b"a")
        assert read_until(server, b"a", 2.0) == b"a"
        server.close()
        end = time.monotonic() + 2.0
        while link.connected and time.monotonic() < end:
            link.read(0.05)
        assert not link.connected
        server = TcpInLink("127.0.0.1", port)
        end = time.monotonic() + 3.0
        while not link.connected and time.monotonic() < end:
            link.read(0.05)
        assert link.connected
        link.write(b"b")
        assert read_until(server, b"b", 2.0) == b"b"
    finally:
        link.close()
        server.close()


def test_reconnecting_link_rejects_bad_backoff() -> None:
    with pytest.raises(ValueError, match="backoff"):
        ReconnectingLink(LinkSpec("udpin", host="127.0.0.1"), initial_backoff_s=2, max_backoff_s=1)


def test_links_read_on_descriptors_above_1023() -> None:
    # A process with many files open (rescue-hq with hundreds of console connections)
    # hands a new link a descriptor above 1023, where select() fails.
    import resource

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < 1200:
        pytest.skip(f"the descriptor limit {hard} is below 1200")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, 1200), hard))
    fillers = [os.open(os.devnull, os.O_RDONLY) for _ in range(1100)]
    server = UdpInLink("127.0.0.1", 0)
    client = UdpOutLink("127.0.0.1", server.local_address[1])
    try:
        assert server._sock is not None and server._sock.fileno() > 1023
        client.write(b"hello")
        assert read_until(server, b"hello", time.monotonic() + 2.0) == b"hello"
        assert server.read(0.05) == b""  # a timeout, not an error
    finally:
        client.close()
        server.close()
        for fd in fillers:
            os.close(fd)
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
