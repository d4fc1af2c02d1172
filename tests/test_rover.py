"""The simulated rover's MAVLink behaviour, checked with pymavlink's mavutil as an
independent client over real UDP sockets on 127.0.0.1 (ephemeral ports) and a pty."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from scenarios.rover import SimRover
from scenarios.world import preset

WAIT_S = 5.0  # generous: several test runs share this 2-core machine


_OPEN: list[Any] = []


@pytest.fixture(autouse=True)
def _close_connections() -> Iterator[None]:
    yield
    while _OPEN:
        _OPEN.pop().close()


def _conn(url: str, **kw: Any) -> Any:
    conn = mavutil.mavlink_connection(url, **kw)
    _OPEN.append(conn)
    return conn


def _client(port: int, comp: int = 191) -> Any:
    conn = _conn(
        f"udpout:127.0.0.1:{port}", source_system=1, source_component=comp, dialect="common"
    )
    conn.mav.heartbeat_send(18, 8, 0, 0, 4)  # MAV_TYPE_ONBOARD_CONTROLLER, INVALID
    return conn


def _recv(conn: Any, kind: str | list[str], timeout_s: float = WAIT_S, **cond: Any) -> Any:
    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        msg = conn.recv_match(type=kind, blocking=True, timeout=left)
        if msg is not None and all(getattr(msg, k) == v for k, v in cond.items()):
            return msg
    raise AssertionError(f"no {kind} {cond} within {timeout_s} s")


@pytest.fixture
def rover() -> Iterator[SimRover]:
    # Twice real time: the checks use the autopilot's own clock, so they do not change.
    r = SimRover(preset("light"), ["udpin:127.0.0.1:0", "udpin:127.0.0.1:0"], time_scale=2.0)
    r.start()
    yield r
    r.close()


def test_heartbeat_says_ardupilot_ground_rover(rover: SimRover) -> None:
    conn = _client(rover.local_address(0)[1])
    hb = _recv(conn, "HEARTBEAT")
    assert hb.type == mavutil.mavlink.MAV_TYPE_GROUND_ROVER
    assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    pos = _recv(conn, "GLOBAL_POSITION_INT")
    assert abs(pos.lat / 1e7 - 40.071) < 0.001  # the world's origin is set at boot


def test_set_message_interval_is_acked_and_honoured(rover: SimRover) -> None:
    conn = _client(rover.local_address(0)[1])
    _recv(conn, "HEARTBEAT")
    conn.mav.command_long_send(1, 1, 511, 0, 30, 50_000, 0, 0, 0, 0, 0)  # ATTITUDE at 20 Hz
    ack = _recv(conn, "COMMAND_ACK", command=511)
    assert ack.result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (1, 191)
    first = _recv(conn, "ATTITUDE")
    last = first
    count = 0
    while last.time_boot_ms - first.time_boot_ms < 2000:
        last = _recv(conn, "ATTITUDE")
        count += 1
    # 20 Hz over 2 s of the autopilot's own clock: 40 (+-2 for the window's ends).
    assert 38 <= count <= 42
    conn.mav.command_long_send(1, 1, 511, 0, 43100, 100_000, 0, 0, 0, 0, 0)
    assert _recv(conn, "COMMAND_ACK", command=511).result == mavutil.mavlink.MAV_RESULT_DENIED
    conn.mav.command_long_send(1, 1, 31000, 0, 0, 0, 0, 0, 0, 0, 0)  # not a command it knows
    assert (
        _recv(conn, "COMMAND_ACK", command=31000).result == mavutil.mavlink.MAV_RESULT_UNSUPPORTED
    )


def test_request_data_stream_stops_and_starts_streams(rover: SimRover) -> None:
    conn = _client(rover.local_address(0)[1])
    _recv(conn, "ATTITUDE")
    conn.mav.request_data_stream_send(1, 1, 0, 0, 0)  # all streams off
    conn.mav.timesync_send(0, 4242)  # a marker: its reply comes after the request is done
    _recv(conn, "TIMESYNC", ts1=4242)
    seen = set()
    hb = 0
    while hb < 2:  # two heartbeats = at least 1 s of silence on the streams
        msg = _recv(conn, ["HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT"])
        seen.add(msg.get_type())
        hb += msg.get_type() == "HEARTBEAT"
    assert seen == {"HEARTBEAT"}
    conn.mav.request_data_stream_send(1, 1, 6, 10, 1)  # POSITION at 10 Hz
    assert _recv(conn, "LOCAL_POSITION_NED") is not None


def test_timesync_is_answered_with_the_boot_clock(rover: SimRover) -> None:
    conn = _client(rover.local_address(0)[1])
    conn.mav.timesync_send(0, 123456789)
    reply = _recv(conn, "TIMESYNC", ts1=123456789)
    assert reply.tc1 > 0


def test_routes_known_messages_to_a_heard_ground_station_but_not_unknown_ids(
    rover: SimRover,
) -> None:
    from mavlink_io import dialect

    companion = _client(rover.local_address(0)[1])
    gcs = _conn(
        f"udpout:127.0.0.1:{rover.local_address(1)[1]}", source_system=255, source_component=190
    )
    gcs.mav.heartbeat_send(6, 8, 0, 0, 4)  # the GCS speaks: the rover learns its route
    _recv(gcs, "HEARTBEAT")  # ...and talks back to it
    # Our dialect's RESCUE_STATUS (43103) from the companion: the autopilot cannot check
    # it, so it must not reach the GCS. Then a STATUSTEXT marker on the same path.
    m = dialect.load()
    enc = m.MAVLink(None, 1, 191)
    status = m.MAVLink_rescue_status_message(*[0] * len(m.MAVLink_rescue_status_message.fieldnames))
    companion.write(status.pack(enc))
    companion.mav.tunnel_send(255, 190, 32768, 3, [1, 2, 3] + [0] * 125)
    companion.mav.statustext_send(6, b"#victim 1 found")
    tunnel = _recv(gcs, "TUNNEL")
    assert tunnel.payload_type == 32768 and list(tunnel.payload[:3]) == [1, 2, 3]
    text = _recv(gcs, "STATUSTEXT")
    assert text.text == "#victim 1 found"
    assert (text.get_srcSystem(), text.get_srcComponent()) == (1, 191)  # forwarded as sent
    assert rover.autopilot.counters.not_routed_unknown >= 1
    assert "RESCUE_STATUS" not in gcs.messages and "UNKNOWN_43103" not in gcs.messages


def test_nothing_is_forwarded_to_a_ground_station_before_it_speaks() -> None:
    gcs = _conn("udpin:127.0.0.1:0", source_system=255)
    gcs_port = gcs.port.getsockname()[1]
    with SimRover(
        preset("empty"), ["udpin:127.0.0.1:0", f"udpout:127.0.0.1:{gcs_port}"], time_scale=4.0
    ) as r:
        companion = _client(r.local_address(0)[1])
        _recv(companion, "HEARTBEAT")
        _recv(gcs, "HEARTBEAT")  # the rover's own streams reach it anyway
        companion.mav.statustext_send(6, b"before")
        _recv(companion, "HEARTBEAT")  # the rover has had time to handle it
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        _recv(gcs, "HEARTBEAT")
        # Once the GCS has spoken, the rover learns the route (its next heartbeat proves the
        # GCS packet was read on the same loop); then "after" must arrive, "before" never.
        _recv(companion, "HEARTBEAT")
        companion.mav.statustext_send(6, b"after")
        texts = []
        while "after" not in texts:
            texts.append(_recv(gcs, "STATUSTEXT").text)
        assert texts == ["after"]


def test_reboot_restarts_boot_time_and_forgets_intervals() -> None:
    with SimRover(preset("empty"), ["udpin:127.0.0.1:0"], time_scale=2.0) as r:
        conn = _client(r.local_address(0)[1])
        conn.mav.command_long_send(1, 1, 511, 0, 30, 20_000, 0, 0, 0, 0, 0)  # 50 Hz
        _recv(conn, "COMMAND_ACK", command=511)
        before = _recv(conn, "SYSTEM_TIME")
        while before.time_boot_ms < 3000:
            before = _recv(conn, "SYSTEM_TIME")
        r.reboot()
        after = _recv(conn, "SYSTEM_TIME", timeout_s=WAIT_S)
        while after.time_boot_ms >= before.time_boot_ms:
            after = _recv(conn, "SYSTEM_TIME")
        assert after.time_boot_ms < 3000
        assert r.autopilot.counters.reboots == 1
        # Back to the default 4 Hz ATTITUDE: about 8 per 2 s of boot time, not 100.
        first = _recv(conn, "ATTITUDE")
        n, last = 0, first
        while last.time_boot_ms - first.time_boot_ms < 2000:
            last = _recv(conn, "ATTITUDE")
            n += 1
        assert 7 <= n <= 9


def test_reboot_command_is_acked_then_reboots(rover: SimRover) -> None:
    conn = _client(rover.local_address(0)[1])
    conn.mav.command_long_send(1, 1, 246, 0, 1, 0, 0, 0, 0, 0, 0)
    assert _recv(conn, "COMMAND_ACK", command=246).result == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert rover.autopilot.counters.reboots == 1


def test_serial_link_over_a_pty() -> None:
    with SimRover(preset("empty"), ["pty"], time_scale=4.0) as r:
        conn = _conn(r.pty_path(0), baud=57600, dialect="common")
        hb = _recv(conn, "HEARTBEAT")
        assert hb.type == mavutil.mavlink.MAV_TYPE_GROUND_ROVER
        conn.mav.command_long_send(1, 1, 512, 0, 242, 0, 0, 0, 0, 0, 0)  # HOME_POSITION
        home = _recv(conn, "HOME_POSITION")
        assert abs(home.latitude / 1e7 - 40.071) < 0.001


def test_dropped_link_goes_silent_then_resumes(rover: SimRover) -> None:
    conn = _client(rover.local_address(0)[1])
    _recv(conn, "HEARTBEAT")
    rover.drop_link(1.5, link=0)
    prev = _recv(conn, "SYSTEM_TIME")
    gap = 0
    while gap < 1000:
        msg = _recv(conn, "SYSTEM_TIME")
        gap = max(gap, msg.time_boot_ms - prev.time_boot_ms)
        prev = msg
    assert 1000 <= gap <= 2500  # 1 Hz normally; the drop leaves a hole of about 1.5 s
