"""A pair of telemetry radios between the rover and a ground peer, on loopback UDP.

    with Radio(("127.0.0.1", rover_ground_port), baud=57_600, loss=0.10, seed=1) as radio:
        radio.ground_url  # "udpout:127.0.0.1:P" -> rescue-hq --listen

Stands in for a SiK-style radio pair on the autopilot's telemetry port. Each
datagram (one MAVLink frame: the rover and rescue-hq send one per datagram) is lost
with probability ``loss``, seeded, each direction with its own draw. With a
``baud``, each direction also carries at most ``baud / 10`` bytes a second (8N1
serial: 5,760 B/s at 57,600 baud), in the order they came (a datagram waits for the
ones before it: queueing delay), through the radio's buffer of ``buffer_bytes`` (a
datagram that does not fit is dropped, as a full radio or ArduPilot's full port
buffer drops it). ``baud=None``: loss only, no rate. Full duplex: a
simplification, SiK radios share the air time between the two directions.

The rover sees one peer, the radio's air socket, however often the ground side
restarts; the ground side is whoever last sent to ``ground_url``'s port (a
restarted rescue-hq comes from a new source port: the radio answers the latest).

``log_reports=True`` also decodes every datagram (TUNNEL unwrapped) and keeps what
concerns the victim reports with its time and fate: reports going to the ground,
their acknowledgements and operator actions coming back (``snapshot()``).
"""

from __future__ import annotations

import dataclasses
import heapq
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

_READ_S = 0.05


@dataclass
class DirectionCounters:
    datagrams: int = 0
    bytes: int = 0  # offered
    lost: int = 0  # lost on the air (the ``loss`` draw)
    overflow: int = 0  # dropped: the radio's buffer was full
    delivered_bytes: int = 0

    @property
    def dropped(self) -> int:
        return self.lost + self.overflow

    @property
    def loss_pct(self) -> float:
        return 100.0 * self.dropped / self.datagrams if self.datagrams else 0.0


@dataclass(frozen=True)
class SeenReport:
    """A RESCUE_VICTIM_REPORT the rover sent towards the ground."""

    t_unix_s: float
    report_seq: int
    victim_id: int
    time_usec: int
    flags: int
    state: int
    delivered: bool


@dataclass(frozen=True)
class SeenAck:
    """A RESCUE_ACK of a victim report the ground sent towards the rover."""

    t_unix_s: float
    seq: int
    result: int
    delivered: bool


@dataclass
class RadioLog:
    to_ground: DirectionCounters = field(default_factory=DirectionCounters)
    to_rover: DirectionCounters = field(default_factory=DirectionCounters)
    reports: list[SeenReport] = field(default_factory=list)
    acks: list[SeenAck] = field(default_factory=list)
    actions: int = 0  # RESCUE_OPERATOR_ACTIONs (RESEND after an HQ restart included)


class _Direction:
    """One direction: a serial-rate queue (when there is a rate), then the loss draw."""

    def __init__(
        self, bytes_per_s: float | None, loss: float, buffer_bytes: int, rng: random.Random
    ) -> None:
        self.bytes_per_s = bytes_per_s
        self.loss = loss
        self.buffer_bytes = buffer_bytes
        self.rng = rng
        self.free_at_s = 0.0  # when the serial line has sent what is queued
        self.counters = DirectionCounters()

    def admit(self, size: int, now_s: float) -> float | None:
        """The time this datagram has left the radio, or None when dropped."""
        self.counters.datagrams += 1
        self.counters.bytes += size
        leaves_s = now_s
        if self.bytes_per_s is not None:
            queued_bytes = max(0.0, self.free_at_s - now_s) * self.bytes_per_s
            if queued_bytes + size > self.buffer_bytes:
                self.counters.overflow += 1
                return None
            self.free_at_s = max(self.free_at_s, now_s) + size / self.bytes_per_s
            leaves_s = self.free_at_s
        if self.rng.random() < self.loss:
            self.counters.lost += 1
            return None
        self.counters.delivered_bytes += size
        return leaves_s


class _ReportTap:
    """Decodes each direction's datagrams and keeps what concerns the reports."""

    def __init__(self) -> None:
        self.codecs = {True: Codec(255, 0), False: Codec(255, 0)}  # keyed by to_ground
        self.reports: list[SeenReport] = []
        self.acks: list[SeenAck] = []
        self.actions = 0

    def note(self, data: bytes, to_ground: bool, delivered: bool, t_unix_s: float) -> None:
        codec = self.codecs[to_ground]
        for msg in codec.feed(data):
            inner = tunnel.unpack_tunnel(msg, codec) if tunnel.is_ours(msg) else msg
            if inner is not None:
                self._keep(inner, t_unix_s, delivered)

    def _keep(self, msg: Any, t_unix_s: float, delivered: bool) -> None:
        kind = msg.get_type()
        if kind == "RESCUE_VICTIM_REPORT":
            self.reports.append(
                SeenReport(
                    t_unix_s,
                    int(msg.report_seq),
                    int(msg.victim_id),
                    int(msg.time_usec),
                    int(msg.flags),
                    int(msg.state),
                    delivered,
                )
            )
        elif kind == "RESCUE_ACK" and int(msg.acked_msgid) == RESCUE_VICTIM_REPORT_ID:
            self.acks.append(SeenAck(t_unix_s, int(msg.seq), int(msg.result), delivered))
        elif kind == "RESCUE_OPERATOR_ACTION":
            self.actions += 1


class Radio:
    """See the module docstring. ``close()`` is safe twice."""

    def __init__(
        self,
        rover: tuple[str, int],
        *,
        loss: float,
        seed: int = 1,
        baud: int | None = 57_600,
        buffer_bytes: int = 4096,
        log_reports: bool = False,
    ) -> None:
        if not 0.0 <= loss < 1.0:
            raise ValueError(f"loss = {loss}: must be in [0, 1)")
        rng = random.Random(seed)
        rate = None if baud is None else baud / 10.0
        self.rover = rover
        self.to_ground = _Direction(rate, loss, buffer_bytes, random.Random(rng.random()))
        self.to_rover = _Direction(rate, loss, buffer_bytes, random.Random(rng.random()))
        self._tap = _ReportTap() if log_reports else None
        self._air = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._air.bind(("127.0.0.1", 0))
        self._ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._ground.bind(("127.0.0.1", 0))
        self._ground_peer: tuple[str, int] | None = None
        self._due: list[tuple[float, int, socket.socket, bytes, bool]] = []  # heap
        self._n = 0
        self._lock = threading.Lock()  # the counters and the tap, for snapshot()
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._read, name="radio-rx", daemon=True),
            threading.Thread(target=self._write, name="radio-tx", daemon=True),
        ]

    @property
    def port(self) -> int:
        """The ground side's port: a ground station sends here."""
        return int(self._ground.getsockname()[1])

    @property
    def ground_url(self) -> str:
        return f"udpout:127.0.0.1:{self.port}"

    def start(self) -> Radio:
        for t in self._threads:
            t.start()
        return self

    def __enter__(self) -> Radio:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for t in self._threads:
            if t.is_alive():
                t.join(timeout=2.0)
        self._air.close()
        self._ground.close()

    def snapshot(self) -> RadioLog:
        """The counters so far and, with ``log_reports``, what concerned the reports."""
        with self._lock:
            tap = self._tap
            return RadioLog(
                dataclasses.replace(self.to_ground.counters),
                dataclasses.replace(self.to_rover.counters),
                list(tap.reports) if tap else [],
                list(tap.acks) if tap else [],
                tap.actions if tap else 0,
            )

    def _read(self) -> None:
        while not self._stop.is_set():
            readable, _, _ = select.select([self._air, self._ground], [], [], _READ_S)
            for sock in readable:
                try:
                    data, peer = sock.recvfrom(65536)
                except OSError:  # the peer's port refused (not up yet, or closed)
                    continue
                now = time.monotonic()
                to_ground = sock is self._air
                if not to_ground:
                    self._ground_peer = (str(peer[0]), int(peer[1]))
                elif self._ground_peer is None:
                    continue  # no ground station has spoken yet: nobody to hear it
                with self._lock:
                    direction = self.to_ground if to_ground else self.to_rover
                    at = direction.admit(len(data), now)
                    if self._tap is not None:
                        self._tap.note(data, to_ground, at is not None, time.time())
                if at is None:
                    continue
                out = self._ground if to_ground else self._air
                with self._cond:
                    self._n += 1
                    heapq.heappush(self._due, (at, self._n, out, data, to_ground))
                    self._cond.notify()

    def _write(self) -> None:
        while not self._stop.is_set():
            with self._cond:
                while not self._due and not self._stop.is_set():
                    self._cond.wait()
                if self._stop.is_set():
                    return
                at, _, sock, data, to_ground = self._due[0]
                wait = at - time.monotonic()
                if wait > 0:
                    self._cond.wait(wait)  # a datagram due sooner may come meanwhile
                    continue
                heapq.heappop(self._due)
            target = self._ground_peer if to_ground else self.rover
            if target is None:
                continue
            try:
                sock.sendto(data, target)
            except OSError:
                continue
