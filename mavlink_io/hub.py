"""Links for a ground station of many robots: a UDP hub that answers every robot,
and the standard links behind the same seam (rescue-hq uses these).

A plain ``udpin`` link (mavlink_io.netlinks.UdpInLink, like mavutil) replies to the
address that spoke last. That is right for one ground station behind one router,
but when several robots send straight to the HQ's port, an acknowledgement for
robot 1 would go to robot 2. ``UdpHubLink`` remembers every peer heard within
``peer_timeout_s`` and addresses replies to the peer a message came from;
``broadcast`` (the HQ's HEARTBEAT) goes to every live peer, like mavlink-router.
The peer table is written by the reader thread (``receive``) and read by the thread
that sends (``broadcast``), so it is guarded by a lock and read as a copy.

Every other kind of link (serial ground radio, udpout to a router, tcp) is a
mavlink_io ``ReconnectingLink``: one peer, reopened after a break.

    Endpoint (Protocol)  receive(timeout_s) -> (bytes, peer), send_to(data, peer), broadcast(data)
    ├── UdpHubLink       udpin with one address per peer
    └── SingleLink       any mavlink_io link (one peer: peer is always None)
"""

from __future__ import annotations

import logging
import selectors
import socket
import threading
import time
from typing import Protocol

from mavlink_io.errors import LinkError
from mavlink_io.link import bound_address
from mavlink_io.linkspec import LinkSpec
from mavlink_io.reconnect import ReconnectingLink

log = logging.getLogger(__name__)

Peer = tuple[str, int] | None
_READ_CHUNK_BYTES = 65536
_DEFAULT_PEER_TIMEOUT_S = 30.0
_MAX_PEERS = 64  # a hub for a fleet of robots, not a public server


class Endpoint(Protocol):
    name: str
    datagram: bool  # True: every read is whole frames (UDP); a partial frame at the end is garbage

    def receive(self, timeout_s: float) -> tuple[bytes, Peer]: ...

    def send_to(self, data: bytes, peer: Peer) -> None: ...

    def broadcast(self, data: bytes) -> None: ...

    def close(self) -> None: ...


class UdpHubLink:
    """A bound UDP socket that keeps one reply address per peer."""

    def __init__(
        self, host: str, port: int, *, peer_timeout_s: float = _DEFAULT_PEER_TIMEOUT_S
    ) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        sock.setblocking(False)
        try:
            sock.bind((host, port))
        except OSError as exc:
            sock.close()
            raise LinkError(f"udpin:{host}:{port}: cannot bind: {exc.strerror or exc}") from exc
        self._sock: socket.socket | None = sock
        self._selector = selectors.DefaultSelector()  # epoll: no 1024 limit on the fd
        self._selector.register(sock, selectors.EVENT_READ)
        self.datagram = True
        self._peers_lock = threading.Lock()  # the reader writes the table, senders read it
        self._peers: dict[tuple[str, int], float] = {}  # address -> last heard (monotonic)
        self._peer_timeout_s = peer_timeout_s
        self.dropped_peers = 0
        self.name = f"udpin:{host}:{sock.getsockname()[1]}"

    @property
    def local_address(self) -> tuple[str, int]:
        return bound_address(self._sock, self.name)

    def live_peers(self) -> list[tuple[str, int]]:
        now = time.monotonic()
        with self._peers_lock:
            return [a for a, t in self._peers.items() if now - t <= self._peer_timeout_s]

    def receive(self, timeout_s: float) -> tuple[bytes, Peer]:
        sock = self._sock
        if sock is None:
            raise LinkError(f"{self.name}: closed")
        try:
            readable = self._selector.select(max(0.0, timeout_s))
        except (OSError, ValueError) as exc:
            raise LinkError(f"{self.name}: select failed: {exc}") from exc
        if not readable:
            return b"", None
        try:
            data, addr = sock.recvfrom(_READ_CHUNK_BYTES)
        except (BlockingIOError, ConnectionRefusedError):
            return b"", None  # ICMP port-unreachable from an earlier send
        except OSError as exc:
            raise LinkError(f"{self.name}: receive failed: {exc}") from exc
        peer = (str(addr[0]), int(addr[1]))
        self._remember(peer)
        return data, peer

    def _remember(self, peer: tuple[str, int]) -> None:
        with self._peers_lock:
            new = self._remember_locked(peer)
        if new:
            log.info("%s: new peer %s:%d", self.name, *peer)

    def _remember_locked(self, peer: tuple[str, int]) -> bool:
        """Record ``peer`` as heard now; True when it is new. Holds the peers' lock."""
        now = time.monotonic()
        if peer not in self._peers:  # forget peers silent too long before counting
            for gone in [a for a, t in self._peers.items() if now - t > self._peer_timeout_s]:
                del self._peers[gone]
        if peer not in self._peers and len(self._peers) >= _MAX_PEERS:
            oldest = min(self._peers, key=self._peers.__getitem__)
            del self._peers[oldest]
            self.dropped_peers += 1
        new = peer not in self._peers
        self._peers[peer] = now
        return new

    def send_to(self, data: bytes, peer: Peer) -> None:
        if peer is None:
            self.broadcast(data)
            return
        sock = self._sock
        if sock is None:
            return
        try:
            sock.sendto(data, peer)
        except OSError as exc:  # unreachable, no buffer space: UDP loses it, resends recover
            log.debug("%s: send to %s failed: %s", self.name, peer, exc)

    def broadcast(self, data: bytes) -> None:
        for peer in self.live_peers():
            self.send_to(data, peer)

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            self._selector.close()
            sock.close()


class SingleLink:
    """Any one-peer mavlink_io link (serial, udpout, tcp, tcpin), reopened after a break."""

    def __init__(self, spec: LinkSpec) -> None:
        self._link = ReconnectingLink(spec)
        self.name = str(spec)
        self.datagram = spec.kind in ("udpin", "udpout")

    def receive(self, timeout_s: float) -> tuple[bytes, Peer]:
        return self._link.read(timeout_s), None

    def send_to(self, data: bytes, peer: Peer) -> None:
        self._link.write(data)

    def broadcast(self, data: bytes) -> None:
        self._link.write(data)

    def close(self) -> None:
        self._link.close()


def open_endpoint(spec: LinkSpec) -> UdpHubLink | SingleLink:
    """The HQ's endpoint for a link address; LinkError when a UDP port cannot be bound."""
    if spec.kind == "udpin":
        return UdpHubLink(spec.host, spec.port)
    return SingleLink(spec)
