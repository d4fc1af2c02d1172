"""Byte transports behind one small interface: serial, UDP in/out, TCP client/server.

    Link (Protocol)        read(timeout_s) -> bytes, write(data), close(), name
    ├── SerialLink         pyserial, select() on the file descriptor
    ├── UdpInLink          bound socket; replies to the address that spoke last
    ├── UdpOutLink         sends to a fixed address, receives its replies
    ├── TcpLink            TCP client
    └── TcpInLink          TCP server, one peer at a time (a new peer replaces the old)
    ReconnectingLink       wraps a LinkSpec; reopens a broken link with exponential backoff

A link never parses MAVLink: it moves bytes. ``read`` waits on the transport with
select() up to ``timeout_s`` and returns ``b""`` on timeout; it raises ``LinkError``
only when the transport itself is broken (device gone, TCP peer of a client link
closed). Connectionless links (UDP) and servers (TCP in) are never "broken" by a
peer: data with nowhere to go is dropped and counted in ``counters.writes_dropped``.

``ReconnectingLink`` hides breakage from its user: while the transport is down,
``read`` waits (at most ``timeout_s``) for the next reopening attempt and returns
``b""``; writes are dropped and counted. Attempts back off from
``initial_backoff_s``, doubling, capped at ``max_backoff_s``; a serial device that
comes back is therefore used again within ``max_backoff_s`` plus its open time.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import serial

from mavlink_io.errors import LinkError
from mavlink_io.linkspec import LinkSpec

log = logging.getLogger(__name__)

_READ_CHUNK_BYTES = 65536
_SERIAL_WRITE_TIMEOUT_S = 0.5  # a stalled UART (no reader, flow control) drops, never blocks
_TCP_CONNECT_TIMEOUT_S = 2.0
_TCP_WRITE_TIMEOUT_S = 2.0  # a TCP peer that stops reading this long counts as broken


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


def _wait_readable(fileno: int | list[int], timeout_s: float) -> list[int]:
    fds = [fileno] if isinstance(fileno, int) else fileno
    try:
        readable, _, _ = select.select(fds, [], [], max(0.0, timeout_s))
    except (OSError, ValueError) as exc:  # closed fd
        raise LinkError(f"select failed: {exc}") from exc
    return readable


def bound_address(sock: socket.socket | None, name: str) -> tuple[str, int]:
    """The (host, port) a listening socket is bound to: the port the OS chose when
    the spec said 0. LinkError once the link is closed (``sock`` is None)."""
    if sock is None:
        raise LinkError(f"{name}: closed")
    host, port = sock.getsockname()[:2]
    return (str(host), int(port))


class SerialLink:
    """A serial port through pyserial; reads select() on its file descriptor."""

    def __init__(self, device: str, baud: int) -> None:
        self.name = f"serial:{device}:{baud}"
        self.counters = LinkCounters()
        self._write_lock = threading.Lock()
        try:
            self._port = serial.Serial(
                port=device,
                baudrate=baud,
                timeout=0,
                write_timeout=_SERIAL_WRITE_TIMEOUT_S,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"{self.name}: cannot open: {exc}") from exc
        fd = self._port.fileno()
        self._fd: int | None = fd

    def read(self, timeout_s: float) -> bytes:
        fd = self._fd
        if fd is None:
            raise LinkError(f"{self.name}: closed")
        if not _wait_readable(fd, timeout_s):
            return b""
        try:
            data = os.read(fd, _READ_CHUNK_BYTES)
        except BlockingIOError:
            return b""
        except OSError as exc:  # EIO/ENXIO: the device went away (unplugged, pty closed)
            raise LinkError(f"{self.name}: read failed: {exc}") from exc
        if not data:  # readable but empty: end of file, the device is gone
            raise LinkError(f"{self.name}: device disconnected")
        self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> None:
        if self._fd is None:
            raise LinkError(f"{self.name}: closed")
        with self._write_lock:
            try:
                self._port.write(data)
            except serial.SerialTimeoutException:
                self.counters.writes_dropped += 1
                log.debug("%s: write stalled, %d bytes dropped", self.name, len(data))
                return
            except (serial.SerialException, OSError, TypeError) as exc:
                raise LinkError(f"{self.name}: write failed: {exc}") from exc
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        if self._fd is None:
            return
        self._fd = None
        try:
            self._port.close()
        except (serial.SerialException, OSError) as exc:  # closing a vanished device
            log.debug("%s: close: %s", self.name, exc)


class _UdpLink:
    """Shared part of the UDP links: a datagram socket and a peer address."""

    def __init__(self, kind: str) -> None:
        self.counters = LinkCounters()
        self._sock: socket.socket | None = None
        self._peer: tuple[str, int] | None = None
        self._kind = kind
        self.name = kind

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port): the port the OS chose when the spec said 0."""
        return bound_address(self._sock, self.name)

    def _receive(self, timeout_s: float, learn_peer: bool) -> bytes:
        sock = self._sock
        if sock is None:
            raise LinkError(f"{self.name}: closed")
        if not _wait_readable(sock.fileno(), timeout_s):
            return b""
        try:
            data, addr = sock.recvfrom(_READ_CHUNK_BYTES)
        except (BlockingIOError, ConnectionRefusedError):
            # ICMP port-unreachable from an earlier send: the peer is not up yet.
            return b""
        except OSError as exc:
            raise LinkError(f"{self.name}: receive failed: {exc}") from exc
        if learn_peer:
            self._peer = (addr[0], addr[1])
        self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> None:
        sock = self._sock
        if sock is None:
            raise LinkError(f"{self.name}: closed")
        peer = self._peer
        if peer is None:
            self.counters.writes_dropped += 1
            return
        try:
            sock.sendto(data, peer)
        except OSError as exc:  # network unreachable, no buffer space: UDP just loses it
            self.counters.writes_dropped += 1
            log.debug("%s: send to %s failed: %s", self.name, peer, exc)
            return
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()


def _udp_socket(host: str) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    sock.setblocking(False)
    return sock


class UdpInLink(_UdpLink):
    """Listens on host:port and replies to the address that spoke last (like mavutil)."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__("udpin")
        sock = _udp_socket(host)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
        except OSError as exc:
            sock.close()
            raise LinkError(f"udpin:{host}:{port}: cannot bind: {exc}") from exc
        self._sock = sock
        self.name = f"udpin:{host}:{self.local_address[1]}"

    @property
    def peer(self) -> tuple[str, int] | None:
        """The address that spoke last (where writes go), or None before anyone spoke."""
        return self._peer

    def read(self, timeout_s: float) -> bytes:
        return self._receive(timeout_s, learn_peer=True)


class UdpOutLink(_UdpLink):
    """Sends to host:port from an ephemeral port and receives the replies."""

    def __init__(self, host: str, port: int) -> None:
        super().__init__("udpout")
        self.name = f"udpout:{host}:{port}"
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except OSError as exc:
            raise LinkError(f"{self.name}: cannot resolve {host!r}: {exc}") from exc
        addr = infos[0][4]
        sock = _udp_socket(str(addr[0]))
        try:
            sock.bind(("::" if sock.family == socket.AF_INET6 else "0.0.0.0", 0))
        except OSError as exc:
            sock.close()
            raise LinkError(f"{self.name}: cannot bind: {exc}") from exc
        self._sock = sock
        self._peer = (str(addr[0]), int(addr[1]))

    def read(self, timeout_s: float) -> bytes:
        return self._receive(timeout_s, learn_peer=False)


def _configure_tcp(sock: socket.socket) -> None:
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.settimeout(_TCP_WRITE_TIMEOUT_S)


class TcpLink:
    """A TCP client. The peer closing the connection breaks the link."""

    def __init__(self, host: str, port: int) -> None:
        self.name = f"tcp:{host}:{port}"
        self.counters = LinkCounters()
        self._write_lock = threading.Lock()
        try:
            sock = socket.create_connection((host, port), timeout=_TCP_CONNECT_TIMEOUT_S)
        except OSError as exc:
            raise LinkError(f"{self.name}: cannot connect: {exc}") from exc
        _configure_tcp(sock)
        self._sock: socket.socket | None = sock

    def read(self, timeout_s: float) -> bytes:
        sock = self._sock
        if sock is None:
            raise LinkError(f"{self.name}: closed")
        if not _wait_readable(sock.fileno(), timeout_s):
            return b""
        try:
            data = sock.recv(_READ_CHUNK_BYTES)
        except OSError as exc:
            raise LinkError(f"{self.name}: receive failed: {exc}") from exc
        if not data:
            raise LinkError(f"{self.name}: connection closed by peer")
        self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> None:
        sock = self._sock
        if sock is None:
            raise LinkError(f"{self.name}: closed")
        with self._write_lock:
            try:
                sock.sendall(data)
            except OSError as exc:  # includes the write timeout: a half-sent frame
                raise LinkError(f"{self.name}: send failed: {exc}") from exc
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()


class TcpInLink:
    """A TCP server for one peer at a time; a new connection replaces the current one.

    Replacing (rather than refusing) means a ground station that restarts after a
    half-open connection gets in at once. Without a peer, writes are dropped.
    """

    def __init__(self, host: str, port: int) -> None:
        self.counters = LinkCounters()
        self._write_lock = threading.Lock()
        self._peer: socket.socket | None = None
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
            family = infos[0][0]
            listener = socket.socket(family, socket.SOCK_STREAM)
        except OSError as exc:
            raise LinkError(f"tcpin:{host}:{port}: cannot resolve: {exc}") from exc
        try:
            listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            listener.bind(infos[0][4])
            listener.listen(1)
        except OSError as exc:
            listener.close()
            raise LinkError(f"tcpin:{host}:{port}: cannot listen: {exc}") from exc
        listener.setblocking(False)
        self._listener: socket.socket | None = listener
        self.name = f"tcpin:{host}:{listener.getsockname()[1]}"

    @property
    def local_address(self) -> tuple[str, int]:
        return bound_address(self._listener, self.name)

    @property
    def has_peer(self) -> bool:
        return self._peer is not None

    def _accept(self, listener: socket.socket) -> None:
        try:
            conn, addr = listener.accept()
        except (BlockingIOError, ConnectionAbortedError):
            return
        except OSError as exc:
            raise LinkError(f"{self.name}: accept failed: {exc}") from exc
        _configure_tcp(conn)
        with self._write_lock:
            old, self._peer = self._peer, conn
        if old is not None:
            log.info("%s: new peer %s replaces the previous one", self.name, addr)
            old.close()
        else:
            log.info("%s: peer %s connected", self.name, addr)

    def _drop_peer(self, peer: socket.socket, why: str) -> None:
        with self._write_lock:
            if self._peer is peer:
                self._peer = None
        peer.close()
        log.info("%s: peer left (%s)", self.name, why)

    def read(self, timeout_s: float) -> bytes:
        listener = self._listener
        if listener is None:
            raise LinkError(f"{self.name}: closed")
        deadline = time.monotonic() + timeout_s
        while True:
            peer = self._peer
            fds = [listener.fileno()] + ([peer.fileno()] if peer is not None else [])
            readable = _wait_readable(fds, deadline - time.monotonic())
            if not readable:
                return b""
            if listener.fileno() in readable:
                self._accept(listener)
                continue
            if peer is not None:
                try:
                    data = peer.recv(_READ_CHUNK_BYTES)
                except OSError as exc:
                    self._drop_peer(peer, str(exc))
                    continue
                if not data:
                    self._drop_peer(peer, "closed")
                    continue
                self.counters.bytes_read += len(data)
                return data

    def write(self, data: bytes) -> None:
        if self._listener is None:
            raise LinkError(f"{self.name}: closed")
        with self._write_lock:
            peer = self._peer
            if peer is None:
                self.counters.writes_dropped += 1
                return
            try:
                peer.sendall(data)
            except OSError as exc:
                self.counters.writes_dropped += 1
                log.info("%s: send to peer failed (%s); waiting for a new peer", self.name, exc)
                self._peer = None
                peer.close()
                return
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        listener, self._listener = self._listener, None
        with self._write_lock:
            peer, self._peer = self._peer, None
        if peer is not None:
            peer.close()
        if listener is not None:
            listener.close()


def open_link(spec: LinkSpec) -> SerialLink | UdpInLink | UdpOutLink | TcpLink | TcpInLink:
    """Open the transport a LinkSpec names; raises LinkError when it cannot."""
    if spec.kind == "serial":
        return SerialLink(spec.device, spec.baud)
    if spec.kind == "udpin":
        return UdpInLink(spec.host, spec.port)
    if spec.kind == "udpout":
        return UdpOutLink(spec.host, spec.port)
    if spec.kind == "tcp":
        return TcpLink(spec.host, spec.port)
    if spec.kind == "tcpin":
        return TcpInLink(spec.host, spec.port)
    raise LinkError(f"unknown link kind {spec.kind!r}")  # pragma: no cover - LinkKind is closed


class ReconnectingLink:
    """A link that survives its transport: reopens with exponential backoff.

    ``read`` returns b"" while disconnected (after waiting for the next attempt, at
    most ``timeout_s``); ``write`` drops and counts. ``connected`` says whether a
    transport is open. Opening happens in ``read``, i.e. in the reader's thread.
    """

    def __init__(
        self,
        spec: LinkSpec,
        *,
        max_backoff_s: float = 1.0,
        initial_backoff_s: float = 0.05,
        opener: Callable[[LinkSpec], Link] = open_link,
    ) -> None:
        if initial_backoff_s <= 0 or max_backoff_s < initial_backoff_s:
            raise ValueError(
                f"backoff: need 0 < initial_backoff_s ({initial_backoff_s}) "
                f"<= max_backoff_s ({max_backoff_s})"
            )
        self.spec = spec
        self.name = str(spec)
        self.counters = LinkCounters()
        self._opener = opener
        self._initial_backoff_s = initial_backoff_s
        self._max_backoff_s = max_backoff_s
        self._backoff_s = initial_backoff_s
        self._next_attempt_mono_s = 0.0
        self._lock = threading.Lock()
        self._inner: Link | None = None
        self._ever_connected = False
        self._closed = threading.Event()
        self._last_error = ""
        self._try_open()

    @property
    def connected(self) -> bool:
        return self._inner is not None

    @property
    def inner(self) -> Link | None:
        """The open transport, or None while disconnected."""
        return self._inner

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The inner link's bound address (udpin/tcpin), or None."""
        inner = self._inner
        address = getattr(inner, "local_address", None)
        return address if isinstance(address, tuple) else None

    def _try_open(self) -> None:
        if self._closed.is_set():
            return
        try:
            inner = self._opener(self.spec)
        except LinkError as exc:
            self.counters.open_failures += 1
            if str(exc) != self._last_error:
                log.warning("%s: %s; retrying every <= %.1f s", self.name, exc, self._max_backoff_s)
                self._last_error = str(exc)
            self._next_attempt_mono_s = time.monotonic() + self._backoff_s
            self._backoff_s = min(self._backoff_s * 2.0, self._max_backoff_s)
            return
        with self._lock:
            if self._closed.is_set():
                inner.close()
                return
            self._inner = inner
        if self._ever_connected:
            self.counters.reconnects += 1
            log.info("%s: reopened", self.name)
        self._ever_connected = True
        self._last_error = ""

    def _mark_broken(self, inner: Link, exc: LinkError) -> None:
        with self._lock:
            if self._inner is not inner:
                return
            self._inner = None
        inner.close()
        self.counters.breaks += 1
        log.warning("%s: link broken (%s); reopening", self.name, exc)
        self._last_error = str(exc)
        self._next_attempt_mono_s = time.monotonic() + self._backoff_s
        self._backoff_s = min(self._backoff_s * 2.0, self._max_backoff_s)

    def read(self, timeout_s: float) -> bytes:
        if self._closed.is_set():
            raise LinkError(f"{self.name}: closed")
        inner = self._inner
        if inner is None:
            wait_s = self._next_attempt_mono_s - time.monotonic()
            if wait_s > timeout_s:
                self._closed.wait(max(0.0, timeout_s))
                return b""
            if wait_s > 0:
                self._closed.wait(wait_s)
            self._try_open()
            return b""
        try:
            data = inner.read(timeout_s)
        except LinkError as exc:
            if self._closed.is_set():
                raise
            self._mark_broken(inner, exc)
            return b""
        if data:
            self._backoff_s = self._initial_backoff_s  # healthy again: fast retries next time
            self.counters.bytes_read += len(data)
        return data

    def write(self, data: bytes) -> None:
        if self._closed.is_set():
            raise LinkError(f"{self.name}: closed")
        inner = self._inner
        if inner is None:
            self.counters.writes_dropped += 1
            return
        try:
            inner.write(data)
        except LinkError as exc:
            self.counters.writes_dropped += 1
            self._mark_broken(inner, exc)
            return
        self.counters.bytes_written += len(data)

    def close(self) -> None:
        self._closed.set()
        with self._lock:
            inner, self._inner = self._inner, None
        if inner is not None:
            inner.close()
