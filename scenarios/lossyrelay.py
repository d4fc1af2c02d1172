"""A lossy radio between the rover's ground port and rescue-hq, on loopback UDP.

    relay = LossyRelay(("127.0.0.1", rover_ground_port), loss=0.3, seed=16).start()
    rescue-hq --listen udpout:127.0.0.1:<relay.port>   # the HQ speaks to the relay

The HQ connects to ``relay.port`` as a UDP client; the relay speaks to the rover
from one socket of its own, so the rover sees one ground peer however often the
HQ restarts (each restart comes from a new source port: the relay answers the
latest one). Each datagram, either way, is dropped with probability ``loss``
(one seeded ``random.Random``). Every datagram is also decoded (TUNNEL unwrapped)
and what concerns the reports is logged with its time and fate: reports going
down to the HQ, acknowledgements and operator actions coming up.
"""

from __future__ import annotations

import contextlib
import logging
import random
import select
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from mavlink_io import tunnel
from mavlink_io.codec import Codec
from mavlink_io.dialect import RESCUE_VICTIM_REPORT_ID

log = logging.getLogger(__name__)

_POLL_S = 0.2  # the thread looks at its stop flag this often
_MAX_DATAGRAM = 65535


@dataclass(frozen=True)
class SeenReport:
    """A RESCUE_VICTIM_REPORT the rover sent towards the HQ."""

    t_unix_s: float
    report_seq: int
    victim_id: int
    time_usec: int
    flags: int
    state: int
    delivered: bool


@dataclass(frozen=True)
class SeenAck:
    """A RESCUE_ACK of a victim report the HQ sent towards the rover."""

    t_unix_s: float
    seq: int
    result: int
    delivered: bool


@dataclass
class Direction:
    datagrams: int = 0
    dropped: int = 0

    @property
    def loss_pct(self) -> float:
        return 100.0 * self.dropped / self.datagrams if self.datagrams else 0.0


@dataclass
class RelayLog:
    down: Direction = field(default_factory=Direction)  # rover -> HQ
    up: Direction = field(default_factory=Direction)  # HQ -> rover
    reports: list[SeenReport] = field(default_factory=list)
    acks: list[SeenAck] = field(default_factory=list)
    actions: int = 0  # RESCUE_OPERATOR_ACTIONs (RESEND after an HQ restart included)


class LossyRelay:
    """See the module docstring. ``close()`` is safe twice."""

    def __init__(self, rover: tuple[str, int], *, loss: float, seed: int) -> None:
        if not 0.0 <= loss < 1.0:
            raise ValueError(f"loss = {loss}: must be in [0, 1)")
        self.loss = loss
        self._rng = random.Random(seed)
        self._hq_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._hq_sock.bind(("127.0.0.1", 0))
        self._rover_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._rover_sock.bind(("127.0.0.1", 0))
        self._rover_sock.connect(rover)
        self._hq_peer: tuple[str, int] | None = None
        self._down_codec = Codec(255, 0)
        self._up_codec = Codec(255, 0)
        self._lock = threading.Lock()
        self._log = RelayLog()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lossy-relay", daemon=True)

    @property
    def port(self) -> int:
        return int(self._hq_sock.getsockname()[1])

    def start(self) -> LossyRelay:
        self._thread.start()
        return self

    def snapshot(self) -> RelayLog:
        with self._lock:
            return RelayLog(
                Direction(self._log.down.datagrams, self._log.down.dropped),
                Direction(self._log.up.datagrams, self._log.up.dropped),
                list(self._log.reports),
                list(self._log.acks),
                self._log.actions,
            )

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for sock in (self._hq_sock, self._rover_sock):
            sock.close()

    def __enter__(self) -> LossyRelay:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._hq_sock, self._rover_sock], [], [], _POLL_S)
            for sock in ready:
                try:
                    data, addr = sock.recvfrom(_MAX_DATAGRAM)
                except OSError as exc:  # the rover's port refused (not up, or closed)
                    log.debug("relay: receive failed: %s", exc)
                    continue
                if sock is self._hq_sock:
                    self._hq_peer = (str(addr[0]), int(addr[1]))
                    self._forward(data, up=True)
                elif self._hq_peer is not None:
                    self._forward(data, up=False)

    def _forward(self, data: bytes, *, up: bool) -> None:
        delivered = self._rng.random() >= self.loss
        now = time.time()
        codec = self._up_codec if up else self._down_codec
        with self._lock:
            direction = self._log.up if up else self._log.down
            direction.datagrams += 1
            direction.dropped += not delivered
            for msg in codec.feed(data):
                inner = tunnel.unpack_tunnel(msg, codec) if tunnel.is_ours(msg) else msg
                self._note(inner, now, delivered)
        if not delivered:
            return
        with contextlib.suppress(OSError):  # the peer's port may be closed for a moment
            if up:
                self._rover_sock.send(data)
            elif self._hq_peer is not None:
                self._hq_sock.sendto(data, self._hq_peer)

    def _note(self, msg: Any, now: float, delivered: bool) -> None:
        if msg is None:
            return
        kind = msg.get_type()
        if kind == "RESCUE_VICTIM_REPORT":
            self._log.reports.append(
                SeenReport(
                    now,
                    int(msg.report_seq),
                    int(msg.victim_id),
                    int(msg.time_usec),
                    int(msg.flags),
                    int(msg.state),
                    delivered,
                )
            )
        elif kind == "RESCUE_ACK" and int(msg.acked_msgid) == RESCUE_VICTIM_REPORT_ID:
            self._log.acks.append(SeenAck(now, int(msg.seq), int(msg.result), delivered))
        elif kind == "RESCUE_OPERATOR_ACTION":
            self._log.actions += 1
