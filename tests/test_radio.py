"""The simulated telemetry radio (scenarios/radio.py): its byte rate, its buffer and
its seeded loss, on real UDP sockets. 576,000 baud (57,600 B/s) keeps the tests
short; the arithmetic is the same at 57,600."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from scenarios.radio import Radio

BAUD = 576_000
BYTES_PER_S = BAUD / 10


@pytest.fixture
def ends() -> Iterator[tuple[socket.socket, socket.socket]]:
    rover = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rover.bind(("127.0.0.1", 0))
    ground = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ground.bind(("127.0.0.1", 0))
    yield rover, ground
    rover.close()
    ground.close()


def _receive(sock: socket.socket, quiet_s: float) -> list[tuple[float, bytes]]:
    sock.settimeout(quiet_s)
    out = []
    while True:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            return out
        out.append((time.monotonic(), data))


def _port(radio: Radio) -> tuple[str, int]:
    return ("127.0.0.1", int(radio.ground_url.rsplit(":", 1)[1]))


def test_both_ways_at_the_line_rate_and_a_full_buffer_drops(
    ends: tuple[socket.socket, socket.socket],
) -> None:
    rover, ground = ends
    with Radio(rover.getsockname(), baud=BAUD, loss=0.0, buffer_bytes=4096) as radio:
        ground.sendto(b"hello", _port(radio))  # the ground station speaks first
        (_, data), *_ = _receive(rover, 1.0)
        assert data == b"hello"
        rover.sendto(b"telemetry", radio._air.getsockname())  # the rover answers its peer
        assert [d for _, d in _receive(ground, 0.5)] == [b"telemetry"]
        sent_at = time.monotonic()
        for i in range(300):  # 30 kB at once: the 4 kB buffer takes about 40
            ground.sendto(bytes([i % 256]) * 100, _port(radio))
        got = _receive(rover, 0.5)
        down = radio.down.counters
        assert 200 < down.overflow < 270
        assert len(got) == down.datagrams - 1 - down.overflow  # all the others arrive
        assert [d[0] for _, d in got] == sorted(d[0] for _, d in got)  # in order
        # Not faster than the line: the last left after all its bytes were sent.
        assert got[-1][0] - sent_at >= len(got) * 100 / BYTES_PER_S * 0.9


def test_seeded_loss_without_overflow_when_paced(
    ends: tuple[socket.socket, socket.socket],
) -> None:
    rover, ground = ends
    with Radio(rover.getsockname(), baud=BAUD, loss=0.10, seed=3) as radio:
        got = []
        for _ in range(400):
            ground.sendto(b"x" * 100, _port(radio))
            got += _receive(rover, 0.004)  # about 25 kB/s offered, under the line's 57.6 kB/s
        got += _receive(rover, 0.5)
        assert radio.down.counters.overflow == 0
        assert radio.down.counters.lost == 400 - len(got)
        assert 20 <= 400 - len(got) <= 65  # 10 % of 400, seeded
