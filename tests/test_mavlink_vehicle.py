"""VehicleLink against an autopilot written with pymavlink's own mavutil, over UDP."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from pymavlink import mavutil

from mavlink_io.codec import Codec
from mavlink_io.netlinks import UdpInLink
from mavlink_io.tunnel import wrap
from mavlink_io.vehicle import VehicleLink, VehicleSettings

SYSID = 7


@dataclass
class FakeAutopilot:
    """A rover autopilot: heartbeat 2 Hz, ATTITUDE + LOCAL_POSITION_NED 50 Hz, origin."""

    port: int
    ack_intervals: bool = True
    received: list[Any] = field(default_factory=list)
    arrived: threading.Condition = field(default_factory=threading.Condition)
    heartbeat: threading.Event = field(default_factory=threading.Event)
    stop: threading.Event = field(default_factory=threading.Event)
    boot_mono_s: float = field(default_factory=lambda: time.monotonic() - 100.0)  # up 100 s

    def __post_init__(self) -> None:
        self.heartbeat.set()
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{self.port}", source_system=SYSID, source_component=1
        )
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        mav = self.conn.mav
        next_hb = next_fast = next_origin = 0.0
        while not self.stop.is_set():
            now = time.monotonic()
            boot_ms = int((now - self.boot_mono_s) * 1000)
            if now >= next_hb and self.heartbeat.is_set():
                next_hb = now + 0.5
                mav.heartbeat_send(10, 3, 0, 0, 4)  # GROUND_ROVER, ARDUPILOTMEGA
            if now >= next_fast:
                next_fast = now + 0.02
                mav.attitude_send(boot_ms, 0.01, -0.02, 1.5, 0, 0, 0)
                north_m = 1.0 + 0.5 * boot_ms / 1000.0  # driving north at 0.5 m/s
                mav.local_position_ned_send(boot_ms, north_m, 2.0, -0.1, 0.5, 0.0, 0.0)
            if now >= next_origin:
                next_origin = now + 0.5
                mav.gps_global_origin_send(481234567, -1241234567, 12000)
            msg = self.conn.recv_match(blocking=True, timeout=0.01)
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            with self.arrived:
                self.received.append(msg)
                self.arrived.notify_all()
            if msg.get_type() == "COMMAND_LONG" and self.ack_intervals:
                mav.command_ack_send(msg.command, 0)

    def wait_for(self, type_: str, timeout_s: float, pred: Any = None) -> Any:
        """The first matching message received since the last forget(); waits for it."""

        def found() -> Any:
            for msg in self.received:
                if msg.get_type() == type_ and (pred is None or pred(msg)):
                    return msg
            return None

        with self.arrived:
            msg = self.arrived.wait_for(found, timeout_s)
        if msg is None:
            raise AssertionError(f"no {type_} within {timeout_s} s")
        return msg

    def forget(self) -> None:
        with self.arrived:
            self.received.clear()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.conn.close()


@pytest.fixture
def rig() -> Iterator[tuple[VehicleLink, FakeAutopilot]]:
    link = UdpInLink("127.0.0.1", 0)
    vehicle = VehicleLink(link, VehicleSettings(heartbeat_timeout_s=0.6))
    ap = FakeAutopilot(link.local_address[1])
    yield vehicle, ap
    ap.close()
    vehicle.close()
    vehicle.close()


def test_identity_heartbeat_streams_pose_and_origin(
    rig: tuple[VehicleLink, FakeAutopilot],
) -> None:
    vehicle, ap = rig
    assert vehicle.wait_connected(3.0) == SYSID
    hb = ap.wait_for("HEARTBEAT", 3.0)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (SYSID, 191)
    assert hb.type == 18 and hb.autopilot == 8 and hb.system_status == 4
    for msg_id in (30, 32, 33, 49, 242):
        cmd = ap.wait_for(
            "COMMAND_LONG", 3.0, lambda m, i=msg_id: m.command == 511 and int(m.param1) == i
        )
        assert (cmd.target_system, cmd.target_component) == (SYSID, 1)
    # The origin is also asked for at once, not only in its slow stream.
    ap.wait_for("COMMAND_LONG", 3.0, lambda m: m.command == 512 and int(m.param1) == 49)
    state = vehicle.wait_for_state(
        lambda s: s.origin is not None and s.counters["poses"] >= 10, timeout_s=3.0
    )
    assert state.stream_method == "interval"
    assert state.origin is not None and state.origin.lat_deg == pytest.approx(48.1234567)
    pose = state.last_pose
    assert pose is not None
    # Positions are carried forward by velocity to the attitude's time: exact here.
    expected = (1.0 + 0.5 * pose.t_boot_s, 2.0, 1.5)
    assert (pose.north_m, pose.east_m, pose.yaw_rad) == pytest.approx(expected, abs=1e-3)
    # Mapped onto our clock: the sample is recent (loopback latency is well under 50 ms).
    assert 0 <= time.monotonic() - pose.t_mono_s < 0.5
    assert vehicle.clock.offset_s == pytest.approx(ap.boot_mono_s, abs=0.01)


def test_link_loss_after_silence_and_rerequest_on_return(
    rig: tuple[VehicleLink, FakeAutopilot],
) -> None:
    vehicle, ap = rig
    vehicle.wait_connected(3.0)
    ap.wait_for("COMMAND_LONG", 3.0)
    ap.wait_for("COMMAND_LONG", 3.0, lambda m: int(m.param1) == 242)  # the last of the burst
    ap.heartbeat.clear()
    silent_since = time.monotonic()
    vehicle.wait_for_state(lambda s: not s.connected, timeout_s=3.0)
    # Lost after the configured 0.6 s of silence (heartbeats came every 0.5 s).
    assert 0.1 < time.monotonic() - silent_since < 2.0
    assert vehicle.counters.link_losses == 1
    requests_before = vehicle.counters.stream_requests
    ap.forget()
    ap.heartbeat.set()
    vehicle.wait_connected(3.0)
    ap.wait_for("COMMAND_LONG", 3.0, lambda m: m.command == 511)
    assert vehicle.counters.stream_requests > requests_before


def test_falls_back_to_request_data_stream_without_ack() -> None:
    link = UdpInLink("127.0.0.1", 0)
    vehicle = VehicleLink(link, VehicleSettings(ack_timeout_s=0.3))
    ap = FakeAutopilot(link.local_address[1], ack_intervals=False)
    try:
        vehicle.wait_connected(3.0)
        rds = ap.wait_for("REQUEST_DATA_STREAM", 3.0)
        assert rds.start_stop == 1 and rds.target_system == SYSID
        assert vehicle.state().stream_method == "data_stream"
    finally:
        ap.close()
        vehicle.close()


def test_reboot_clears_history_and_rerequests(rig: tuple[VehicleLink, FakeAutopilot]) -> None:
    vehicle, ap = rig
    vehicle.wait_connected(3.0)
    vehicle.wait_for_state(lambda s: s.stream_method == "interval", timeout_s=3.0)
    ap.wait_for("COMMAND_LONG", 3.0, lambda m: int(m.param1) == 242)  # the last of the burst
    vehicle.wait_for_state(lambda s: s.last_pose is not None, timeout_s=3.0)
    ap.forget()
    ap.boot_mono_s = time.monotonic()  # reboot: time_boot_ms restarts from 0
    vehicle.wait_for_state(lambda s: s.counters["reboots"] == 1, timeout_s=3.0)
    ap.wait_for("COMMAND_LONG", 3.0, lambda m: m.command == 511)
    pose = vehicle.poses.latest()
    assert pose is None or pose.t_boot_s < 5.0  # nothing from the 100 s-old boot survives


def test_dialect_messages_for_us_direct_and_tunnelled(
    rig: tuple[VehicleLink, FakeAutopilot],
) -> None:
    vehicle, ap = rig
    vehicle.wait_connected(3.0)
    hq = Codec(255, 190)
    m = hq.module
    ours = m.MAVLink_rescue_ack_message(SYSID, 191, 43100, 5, 0)
    other = m.MAVLink_rescue_ack_message(SYSID, 55, 43100, 6, 0)
    tunnelled = m.MAVLink_rescue_operator_action_message(SYSID, 191, 3, 9, 1)
    ap.conn.write(hq.encode(other))
    ap.conn.write(hq.encode(ours))
    ap.conn.write(hq.encode(wrap(hq, tunnelled)))
    first = vehicle.inbox.get(timeout=3.0)
    second = vehicle.inbox.get(timeout=3.0)
    assert (first.get_type(), first.seq) == ("RESCUE_ACK", 5)
    assert (second.get_type(), second.action_seq) == ("RESCUE_OPERATOR_ACTION", 9)
    assert vehicle.inbox.empty()


def test_absurd_stream_rate_is_refused_before_the_link_starts() -> None:
    # REQUEST_DATA_STREAM carries the rate as uint16: 100000 Hz killed the reader thread.
    with pytest.raises(ValueError, match="attitude_rate_hz = 100000"):
        VehicleSettings(attitude_rate_hz=100000.0)
    with pytest.raises(ValueError, match="origin_rate_hz = nan"):
        VehicleSettings(origin_rate_hz=float("nan"))


def test_origin_with_absurd_altitude_is_refused_and_counted(
    rig: tuple[VehicleLink, FakeAutopilot],
) -> None:
    vehicle, ap = rig
    vehicle.wait_for_state(lambda s: s.origin is not None, timeout_s=3.0)
    good = vehicle.origin
    # INT32_MIN mm: a victim's altitude below it no longer fits the report's int32.
    ap.conn.mav.gps_global_origin_send(481234567, -1241234567, -(2**31))
    ap.conn.mav.home_position_send(481234567, -1241234567, -(2**31), 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    state = vehicle.wait_for_state(lambda s: s.counters["refused"] >= 2, timeout_s=3.0)
    assert state.origin == good
    assert vehicle.telemetry.refused["GPS_GLOBAL_ORIGIN"] == 1
    assert vehicle.alive


def test_one_absurd_boot_time_changes_nothing(rig: tuple[VehicleLink, FakeAutopilot]) -> None:
    vehicle, ap = rig
    vehicle.wait_for_state(lambda s: s.last_pose is not None, timeout_s=3.0)
    offset_s = vehicle.clock.offset_s
    poses_before = vehicle.counters.poses
    for boot_ms in (4_000_000_000, 0):  # far ahead of the clock, then back to zero
        refused = vehicle.telemetry.refused["ATTITUDE"]
        ap.conn.mav.attitude_send(boot_ms, 0.0, 0.0, 0.0, 0, 0, 0)
        vehicle.wait_for_state(
            lambda s, n=refused: s.counters["refused"] > n,
            timeout_s=3.0,
        )
    vehicle.wait_for_state(lambda s: s.counters["poses"] > poses_before + 10, timeout_s=3.0)
    assert vehicle.counters.reboots == 0
    assert vehicle.clock.offset_s == pytest.approx(offset_s, abs=0.01)
    assert vehicle.origin is not None
    pose = vehicle.poses.latest()
    assert pose is not None and 90.0 < pose.t_boot_s < 200.0
