"""Stream rates are requested again when the autopilot may have forgotten them: the
project's simulated ArduPilot rover reboots (boot time restarts, streams back to
its defaults) or its TCP link reconnects. Its default telemetry rates are 0 here,
as on an ArduPilot port whose SRx_ rates are 0: only what we request comes."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest

from mavlink_io.codec import MavMessage
from mavlink_io.linkspec import parse_link
from mavlink_io.netlinks import TcpInLink
from mavlink_io.reconnect import ReconnectingLink
from mavlink_io.vehicle import VehicleLink, VehicleSettings
from scenarios.autopilot import ATTITUDE, GLOBAL_POSITION_INT, LOCAL_POSITION_NED, SIM_STATE
from scenarios.rover import SimRover
from scenarios.world import preset

QUIET = {ATTITUDE: 0.0, LOCAL_POSITION_NED: 0.0, GLOBAL_POSITION_INT: 0.0, SIM_STATE: 0.0}


class Arrivals:
    """On the vehicle link's reader thread: when each message came, and when the
    first pose of a new boot (t_boot_s below ``new_boot_below_s``) was decoded."""

    def __init__(self) -> None:
        self.vehicle: VehicleLink | None = None
        self.times: list[float] = []
        self.new_boot_below_s: float | None = None
        self.new_pose_at: float | None = None
        self.lock = threading.Lock()

    def __call__(self, _msg: MavMessage) -> None:
        now = time.monotonic()
        with self.lock:
            self.times.append(now)
            pose = self.vehicle.poses.latest() if self.vehicle is not None else None
            limit = self.new_boot_below_s
            if (
                self.new_pose_at is None
                and limit is not None
                and pose is not None
                and pose.t_boot_s < limit
            ):
                self.new_pose_at = now


@pytest.fixture
def rover() -> Iterator[SimRover]:
    with SimRover(preset("light"), ["udpin:127.0.0.1:0"], rates_hz=QUIET) as r:
        yield r


def test_pose_is_back_within_1_s_of_the_first_message_after_a_reboot(rover: SimRover) -> None:
    arrivals = Arrivals()
    port = rover.local_address(0)[1]
    vehicle = VehicleLink(
        ReconnectingLink(parse_link(f"udpout:127.0.0.1:{port}")),
        VehicleSettings(heartbeat_timeout_s=3.0),
        on_message=arrivals,
    )
    arrivals.vehicle = vehicle
    try:
        vehicle.wait_for_state(lambda s: s.last_pose is not None, timeout_s=10.0)
        # Up for 5 s, so the new boot's times (from 2 s, after its silence) are lower.
        vehicle.wait_for_state(
            lambda s: s.last_pose is not None and s.last_pose.t_boot_s > 5.0, timeout_s=10.0
        )
        with arrivals.lock:
            arrivals.new_boot_below_s = 4.5
        rebooted_at = time.monotonic()
        rover.reboot()  # 2 s of silence, then heartbeats and no telemetry until asked
        end = time.monotonic() + 10.0
        while arrivals.new_pose_at is None and time.monotonic() < end:
            time.sleep(0.05)
        assert arrivals.new_pose_at is not None, f"no pose after the reboot: {vehicle.state()}"
        with arrivals.lock:
            first_after = min(t for t in arrivals.times if t > rebooted_at + 1.0)
        assert arrivals.new_pose_at - first_after <= 1.0
        assert vehicle.state().connected
    finally:
        vehicle.close()


def test_streams_are_requested_again_after_a_tcp_reconnect() -> None:
    with SimRover(preset("light"), ["tcpin:127.0.0.1:0"], rates_hz=QUIET) as rover:
        port = rover.local_address(0)[1]
        link = ReconnectingLink(parse_link(f"tcp:127.0.0.1:{port}"))
        vehicle = VehicleLink(link, VehicleSettings(heartbeat_timeout_s=3.0))
        try:
            vehicle.wait_for_state(lambda s: s.last_pose is not None, timeout_s=10.0)
            requests = vehicle.counters.stream_requests
            server = rover.link(0)
            assert isinstance(server, TcpInLink)
            peer = server._peer  # the rover's end of our connection
            assert peer is not None
            peer.shutdown(socket.SHUT_RDWR)  # the connection drops; we reconnect
            vehicle.wait_for_state(
                lambda s: s.counters["stream_requests"] > requests, timeout_s=10.0
            )
            assert link.counters.reconnects == 1
            poses = vehicle.counters.poses
            vehicle.wait_for_state(lambda s: s.counters["poses"] > poses + 5, timeout_s=5.0)
        finally:
            vehicle.close()
