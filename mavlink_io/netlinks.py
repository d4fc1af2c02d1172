"""The network links: UDP in/out and TCP client/server (the interface is
mavlink_io.link.Link)."""

from __future__ import annotations

import logging
import socket
import threading
import time

from mavlink_io.errors import LinkError
from mavlink_io.link import READ_CHUNK_BYTES, LinkCounters, bound_address, wait_readable

log = logging.getLogger(__name__)

_TCP_CONNECT_TIMEOUT_S = 2.0
_TCP_WRITE_TIMEOUT_S = 2.0  # a TCP peer that stops reading this long counts as broken


class _UdpLink:
    """Shared part of the UDP links: a datagram socket and a peer address."""

    def __init__(self, kind: str) -> None:
        self.counters = LinkCounters()
        self._sock: socket.socket | None = None
        self._peer: tuple[str, int] | None = None
        self.name = kind

    @property
    def local_address(self) -> tuple[str, int]:
        """The bound (host, port): the port the OS chose when the spec said 0."""
        return bound_address(self._sock, self.name)

    def _receive(self, timeout_s: float, learn_peer: bool) -> bytes:
        sock = self._sock
        if sock is None:
            raise LinkError(f"{self.name}: closed")
        if not wait_readable(sock.fileno(), timeout_s):
            return b""
        try:
            data, addr = sock.recvfrom(READ_CHUNK_BYTES)
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
        if not wait_readable(sock.fileno(), timeout_s):
            return b""
        try:
            data = sock.recv(READ_CHUNK_BYTES)
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
            readable = wait_readable(fds, deadline - time.monotonic())
            if not readable:
                return b""
            if listener.fileno() in readable:
                self._accept(listener)
                continue
            if peer is not None:
                try:
                    data = peer.recv(READ_CHUNK_BYTES)
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
