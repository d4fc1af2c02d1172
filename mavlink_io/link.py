"""The byte-transport interface every link implements, and what the transports share.

    Link (Protocol)        read(timeout_s) -> bytes, write(data), close(), name
    ├── SerialLink         pyserial, poll() on the file descriptor               (seriallink.py)
    ├── UdpInLink          bound socket; replies to the address that spoke last    (netlinks.py)
    ├── UdpOutLink         sends to a fixed address, receives its replies          (netlinks.py)
    ├── TcpLink            TCP client                                              (netlinks.py)
    └── TcpInLink          TCP server, one peer at a time (a new peer replaces the old)
                                                                                   (netlinks.py)
    open_link              opens the transport a LinkSpec names                   (reconnect.py)
    ReconnectingLink       wraps a LinkSpec; reopens a broken link with exponential backoff
                                                                                  (reconnect.py)

A link never parses MAVLink: it moves bytes. ``read`` waits on the transport with
poll() up to ``timeout_s`` and returns ``b""`` on timeout; it raises ``LinkError``
only when the transport itself is broken (device gone, TCP peer of a client link
closed). Connectionless links (UDP) and servers (TCP in) are never "broken" by a
peer: data with nowhere to go is dropped and counted in ``counters.writes_dropped``.
"""

from __future__ import annotations

import select
import socket
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from mavlink_io.errors import LinkError

READ_CHUNK_BYTES = 65536


@runtime_checkable
class Link(Protocol):
    """A bidirectional byte transport."""

    name: str

    def read(self, timeout_s: float) -> bytes:
        """Bytes received, waiting up to ``timeout_s``; b"" on timeout. LinkError if broken."""
        ...

    def write(self, data: bytes) -> None:
        """Send ``data``; LinkError if broken. May drop (and count) when there is no peer."""
        ...

    def close(self) -> None:
        """Release the transport; safe to call twice."""
        ...


@dataclass
class LinkCounters:
    """Traffic counters of one link (plain ints: read them from any thread)."""

    bytes_read: int = 0
    bytes_written: int = 0
    writes_dropped: int = 0  # writes with no peer, or stalled, or while disconnected
    reconnects: int = 0  # ReconnectingLink: successful reopenings after a break
    open_failures: int = 0  # ReconnectingLink: failed opening attempts
    breaks: int = 0  # ReconnectingLink: times the transport broke


def wait_readable(fileno: int | list[int], timeout_s: float) -> list[int]:
    """The file descriptors readable within ``timeout_s``; LinkError if one is closed.

    poll(), not select(): select() fails on a descriptor above 1023, which a process
    with many open files (rescue-hq with hundreds of console connections) hands out."""
    fds = [fileno] if isinstance(fileno, int) else fileno
    poller = select.poll()
    try:
        for fd in fds:
            poller.register(fd, select.POLLIN | select.POLLPRI)
        events = poller.poll(max(0.0, timeout_s) * 1000.0)
    except (OSError, ValueError, TypeError) as exc:  # a closed or negative fd
        raise LinkError(f"poll failed: {exc}") from exc
    if any(ev & select.POLLNVAL for _, ev in events):
        raise LinkError("poll failed: a descriptor is closed")
    # A hung-up or failed descriptor counts as readable: its read says what happened.
    return [fd for fd, _ in events]


def bound_address(sock: socket.socket | None, name: str) -> tuple[str, int]:
    """The (host, port) a listening socket is bound to: the port the OS chose when
    the spec said 0. LinkError once the link is closed (``sock`` is None)."""
    if sock is None:
        raise LinkError(f"{name}: closed")
    host, port = sock.getsockname()[:2]
    return (str(host), int(port))
