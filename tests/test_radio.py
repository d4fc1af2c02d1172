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
            ground.sendto(i.to_bytes(2, "big") * 50, _port(radio))
        got = _receive(rover, 0.5)
        down = radio.to_rover.counters
        assert 200 < down.overflow < 270
        assert len(got) == down.datagrams - 1 - down.overflow  # all the others arrive
        # In order (a 2-byte number: under load the sender is slow enough for a few of
        # the last 44 to find room, which a 1-byte one would wrongly read as reordered).
        seqs = [int.from_bytes(d[:2], "big") for _, d in got]
        assert seqs == sorted(seqs)
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
        assert radio.to_rover.counters.overflow == 0
        assert radio.to_rover.counters.lost == 400 - len(got)
        assert 20 <= 400 - len(got) <= 65  # 10 % of 400, seeded


def test_the_report_log_sees_reports_in_a_tunnel_and_their_acknowledgements(
    ends: tuple[socket.socket, socket.socket],
) -> None:
    from fusion.types import TrackState, Urgency, VictimReport
    from mavlink_io import convert, tunnel
    from mavlink_io.codec import Codec

    rover_sock, ground_sock = ends
    rover, ground = Codec(7, 191), Codec(255, 190)
    report = VictimReport(
        victim_id=3, robot_sysid=7, state=TrackState.CONFIRMED, urgency=Urgency.CRITICAL,
        visibility_pct=8.0, north_m=1.0, east_m=2.0, down_m=0.0,
        cov_ne_m2=((0.04, 0.0), (0.0, 0.04)), observations=5,
        first_seen_unix_s=1.7e9, last_seen_unix_s=1.7e9 + 5,
    )  # fmt: skip
    frame = rover.encode(
        tunnel.wrap(rover, convert.victim_report_to_msg(report, 9, 0, 1.7e9, None))
    )
    ack = ground.encode(ground.module.MAVLink_rescue_ack_message(7, 191, 43100, 9, 0))
    with Radio(rover_sock.getsockname(), loss=0.0, baud=None, log_reports=True) as radio:
        ground_sock.sendto(ack, _port(radio))  # the ground speaks first
        assert [d for _, d in _receive(rover_sock, 0.5)] == [ack]
        rover_sock.sendto(frame, radio._air.getsockname())
        assert [d for _, d in _receive(ground_sock, 0.5)] == [frame]
        log = radio.snapshot()
    (seen,) = log.reports
    assert (seen.report_seq, seen.victim_id, seen.delivered) == (9, 3, True)
    assert [(a.seq, a.result, a.delivered) for a in log.acks] == [(9, 0, True)]
    assert log.to_ground.datagrams == log.to_rover.datagrams == 1
