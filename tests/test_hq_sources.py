"""rescue-hq keeps state per source address only for a bounded number of live sources.

Every UDP source (address, port) gets a decoder (its partial frame, its signing
replay window). Sources that fall silent are forgotten after ``source_idle_s``, and
at most ``MAX_SOURCES`` are kept, so a sender that hops ports (or a spoofed flood)
cannot grow the HQ's memory without bound. The HQ runs in process here on a real
UDP socket and a real registry file.
"""

from __future__ import annotations

import io
import socket
import threading
import time
from pathlib import Path

from hq import app as hq_app
from hq.app import HqApp, HqOptions
from hq.registry import Registry
from hq.simrobot import SimRobot
from mavlink_io.codec import Codec
from mavlink_io.hub import UdpHubLink


def _wait_until(condition, timeout_s: float) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def test_per_source_state_is_bounded_and_expires(tmp_path: Path) -> None:
    link = UdpHubLink("127.0.0.1", 0)
    stop = threading.Event()
    started: list[HqApp] = []

    def run() -> None:  # the registry belongs to the thread that runs the HQ
        with Registry(tmp_path / "hq.sqlite") as registry:
            app = HqApp(registry, [link], HqOptions(source_idle_s=1.0), io.StringIO())
            started.append(app)
            app.run(stop)

    runner = threading.Thread(target=run, daemon=True)
    runner.start()
    assert _wait_until(lambda: bool(started), 5.0)
    app = started[0]
    sender = Codec(3, 191)
    heartbeat = sender.encode(
        sender.module.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)  # an onboard controller
    )
    try:
        flood = hq_app.MAX_SOURCES + 200
        for _ in range(flood):  # each from its own port, like a sender that hops ports
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                s.sendto(heartbeat, link.local_address)
        assert _wait_until(lambda: app.counters.sources_forgotten >= 200, 10.0)
        assert app.tracked_sources <= hq_app.MAX_SOURCES
        assert len(link.live_peers()) <= 64
        # Silent sources are forgotten; a robot that speaks now is served as before.
        time.sleep(1.5)
        with SimRobot(5, link.local_address) as robot:
            msg = robot.report_msg(robot.victim(1, 1.0, 1.0))
            robot.send(msg)
            ack = robot.wait_for("RESCUE_ACK", 3.0, seq=msg.report_seq).msg
            assert ack.result == 0
            assert _wait_until(lambda: app.tracked_sources == 1, 3.0), app.tracked_sources
    finally:
        stop.set()
        runner.join(timeout=5)
        link.close()


def test_a_decoder_keeps_a_bounded_number_of_senders() -> None:
    from mavlink_io import codec as codec_mod

    receiver = Codec(245, 190)
    m = receiver.module
    for n in range(codec_mod.MAX_SENDERS + 500):  # valid frames from ever new senders
        sender = Codec(1 + n % 255, n // 255, None, m)
        receiver.feed(sender.encode(m.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)))
    assert receiver.tracked_senders == codec_mod.MAX_SENDERS
