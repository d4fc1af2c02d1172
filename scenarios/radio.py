"""A pair of telemetry radios between two UDP peers: a bounded byte rate and loss.

    with Radio(("127.0.0.1", rover_ground_port), baud=57_600, loss=0.10, seed=1) as radio:
        radio.ground_url  # "udpout:127.0.0.1:P" -> rescue-hq --listen

Stands in for a SiK-style radio pair on the autopilot's telemetry port: each
direction carries at most ``baud / 10`` bytes a second (8N1 serial: 5,760 B/s at
57,600 baud), in the order they came (a datagram waits for the ones before it:
queueing delay), with the radio's buffer of ``buffer_bytes`` (a datagram that does
not fit is dropped, as a full radio or ArduPilot's full port buffer drops it), and
loses each datagram (one MAVLink frame: the rover and rescue-hq send one per
datagram) with probability ``loss``, seeded. Full duplex: a simplification, SiK
radios share the air time between the two directions.

The air side peer (``rover``) gets datagrams from a socket of its own; the ground
side peer is whoever first sends to ``ground_url``'s port.
"""

from __future__ import annotations

import heapq
import random
import select
import socket
import threading
import time
from dataclasses import dataclass

_READ_S = 0.05


@dataclass
class DirectionCounters:
    datagrams: int = 0
    bytes: int = 0  # offered
    lost: int = 0  # lost on the air (the ``loss`` draw)
    overflow: int = 0  # dropped: the radio's buffer was full
    delivered_bytes: int = 0


class _Direction:
    """One direction: a serial-rate queue, then the loss draw."""

    def __init__(
        self, bytes_per_s: float, loss: float, buffer_bytes: int, rng: random.Random
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
        queued_bytes = max(0.0, self.free_at_s - now_s) * self.bytes_per_s
        if queued_bytes + size > self.buffer_bytes:
            self.counters.overflow += 1
            return None
        self.free_at_s = max(self.free_at_s, now_s) + size / self.bytes_per_s
        if self.rng.random() < self.loss:
            self.counters.lost += 1
            return None
        self.counters.delivered_bytes += size
        return self.free_at_s


class Radio:
    """A UDP relay with a radio's rate and loss between a rover port and a ground peer."""

    def __init__(
        self,
        rover: tuple[str, int],
        *,
        baud: int = 57_600,
        loss: float = 0.10,
        buffer_bytes: int = 4096,
        seed: int = 1,
    ) -> None:
        rng = random.Random(seed)
        self.rover = rover
        self.up = _Direction(baud / 10.0, loss, buffer_bytes, random.Random(rng.random()))
        self.down = _Direction(baud / 10.0, loss, buffer_bytes, random.Random(rng.random()))
        self._air = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._air.bind(("127.0.0.1", 0))
        self._ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._ground.bind(("127.0.0.1", 0))
        self._ground_peer: tuple[str, int] | None = None
        self._due: list[tuple[float, int, socket.socket, bytes, bool]] = []  # heap
        self._n = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._read, name="radio-rx", daemon=True),
            threading.Thread(target=self._write, name="radio-tx", daemon=True),
        ]

    @property
    def ground_url(self) -> str:
        return f"udpout:127.0.0.1:{self._ground.getsockname()[1]}"

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

    def _read(self) -> None:
        while not self._stop.is_set():
            readable, _, _ = select.select([self._air, self._ground], [], [], _READ_S)
            for sock in readable:
                try:
                    data, peer = sock.recvfrom(65536)
                except OSError:
                    continue
                now = time.monotonic()
                if sock is self._ground:
                    self._ground_peer = peer
                    at = self.down.admit(len(data), now)
                    out, to_ground = self._air, False
                else:
                    at = self.up.admit(len(data), now)
                    out, to_ground = self._ground, True
                if at is None:
                    continue
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
                continue  # no ground station has spoken yet: nobody to hear it
            try:
                sock.sendto(data, target)
            except OSError:
                continue
