"""Forged frames with signing on: no state change, no denial of service.

Only a frame whose signature verifies may advance a stream's signing timestamp:
one forged frame with a timestamp far in the future must not make every later
genuine frame look like a replay. With signing on, rescue-hq refuses (and counts)
every unsigned message that would change its state, GPS_GLOBAL_ORIGIN included.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hqproc import ACCEPTED, HqProcess, ack_for, hq_starter

from hq.registry import Registry
from hq.simrobot import SimRobot
from mavlink_io.codec import Codec
from mavlink_io.signing import Signing, load_signing

KEY = bytes(range(32))
FAR_FUTURE = 2**47  # 10 us units: about 44 years after 2015


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


def _forger(sysid: int, compid: int) -> Codec:
    """A sender without the key that claims another's identity and a huge timestamp."""
    forger = Codec(sysid, compid, Signing(bytes(32)))
    forger.mav.signing.timestamp = FAR_FUTURE
    return forger


def test_a_forged_future_timestamp_does_not_block_genuine_frames() -> None:
    hq = Codec(245, 190, Signing(KEY))
    robot = Codec(7, 191, Signing(KEY))
    m = robot.module
    ack = m.MAVLink_rescue_ack_message(7, 191, 43100, 1, 0)
    assert [x.seq for x in robot.feed(hq.encode(ack))] == [1]  # the stream is known
    forged = _forger(245, 190).encode(m.MAVLink_rescue_ack_message(7, 191, 43100, 2, 0))
    assert robot.feed(forged) == []
    assert robot.counters.signature_rejected == 1
    ack3 = m.MAVLink_rescue_ack_message(7, 191, 43100, 3, 0)
    assert [x.seq for x in robot.feed(hq.encode(ack3))] == [3]  # not taken for a replay
    replay = hq.encode(m.MAVLink_rescue_ack_message(7, 191, 43100, 4, 0))
    assert [x.seq for x in robot.feed(replay)] == [4]
    assert robot.feed(replay) == []  # a genuine replay is still refused
    # Our own outgoing timestamp does not jump with a forged frame either.
    assert robot.mav.signing.timestamp < FAR_FUTURE


def test_hq_refuses_unsigned_origin_and_forged_reports(start_hq, tmp_path: Path) -> None:
    key = tmp_path / "hq.key"
    key.write_text(KEY.hex() + "\n")
    key.chmod(0o600)
    hq = start_hq("--signing-key", str(key))
    with (
        SimRobot(9, hq.address) as unsigned,
        SimRobot(10, hq.address, signing=load_signing(key)) as signed,
    ):
        m = signed.m
        unsigned.send(m.MAVLink_gps_global_origin_message(473977420, 85455940, 488000, 0))
        hq.wait_line("refused", 3.0, stderr=True)
        # One forged report from the robot's own address, with a far-future timestamp...
        forged = _forger(10, 191).encode(signed.report_msg(signed.victim(1, 0.0, 0.0)))
        signed.send_raw(forged)
        # ...and the robot's genuine reports still go through.
        good = signed.report_msg(signed.victim(2, 1.0, 1.0))
        signed.send(good)
        assert ack_for(signed, good.report_seq).result == ACCEPTED
        signed.send(m.MAVLink_gps_global_origin_message(473977420, 85455940, 488000, 0))
        signed.send(good)  # a resend: its ack says the origin before it was handled
        ack_for(signed, good.report_seq)
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        origins = {r.sysid: r.origin for r in reg.robots()}
        assert [s.report.victim_id for s in reg.sources()] == [2]
    assert 9 not in origins or origins[9] is None  # the unsigned origin changed nothing
    assert origins[10] is not None
    assert any("unsigned or with a bad signature" in line for line in hq.stderr)


def test_signed_report_inside_a_signed_tunnel_is_acked(start_hq, tmp_path: Path) -> None:
    # The robot signs the inner frame first and the TUNNEL around it next: the
    # envelope's timestamp is the later one and must not make the inner one a replay.
    key = tmp_path / "hq.key"
    key.write_text(KEY.hex() + "\n")
    key.chmod(0o600)
    hq = start_hq("--signing-key", str(key))
    with SimRobot(11, hq.address, tunnel=True, signing=load_signing(key)) as robot:
        for victim in (1, 2):
            msg = robot.report_msg(robot.victim(victim, float(victim), 0.0))
            robot.send(msg)
            assert ack_for(robot, msg.report_seq).result == ACCEPTED
    assert hq.stop() == 0
