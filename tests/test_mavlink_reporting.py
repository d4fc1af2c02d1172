"""Signing, STATUSTEXT, TUNNEL, conversions, outbox/dedupe and tlogs."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest
from pymavlink import mavutil

from fusion.types import TrackState, Urgency, VictimReport
from mavlink_io import convert, tunnel
from mavlink_io.codec import Codec
from mavlink_io.errors import SigningError
from mavlink_io.reliable import Deduplicator, Outbox
from mavlink_io.signing import Signing, load_key, load_signing
from mavlink_io.tlog import TlogWriter, read_tlog

KEY = bytes(range(32))


def report(**kw: object) -> VictimReport:
    base: dict[str, object] = dict(
        victim_id=3,
        robot_sysid=7,
        state=TrackState.CONFIRMED,
        urgency=Urgency.CRITICAL,
        visibility_pct=8.0,
        north_m=12.34,
        east_m=4.5,
        down_m=0.1,
        cov_ne_m2=((0.04, 0.01), (0.01, 0.09)),
        observations=7,
        first_seen_unix_s=1.7e9,
        last_seen_unix_s=1.7e9 + 5,
    )
    base.update(kw)
    return VictimReport(**base)  # type: ignore[arg-type]


# ----------------------------------------------------------------- signing


def test_key_file_must_be_private_and_well_formed(tmp_path: Path) -> None:
    raw = tmp_path / "raw.key"
    raw.write_bytes(KEY)
    raw.chmod(0o600)
    assert load_key(raw) == KEY
    hexed = tmp_path / "hex.key"
    hexed.write_text(KEY.hex() + "\n")
    hexed.chmod(0o400)
    assert load_key(hexed) == KEY
    hexed.chmod(0o640)
    with pytest.raises(SigningError, match="chmod 600") as info:
        load_key(hexed)
    assert KEY.hex() not in str(info.value)
    bad = tmp_path / "bad.key"
    bad.write_text("not a key")
    bad.chmod(0o600)
    with pytest.raises(SigningError, match="32 raw bytes or 64 hex"):
        load_key(bad)
    with pytest.raises(SigningError, match="cannot read"):
        load_key(tmp_path / "missing.key")
    assert KEY.hex() not in repr(load_signing(raw))


def test_signed_state_changes_accepted_unsigned_and_forged_rejected() -> None:
    hq_signed = Codec(255, 190, Signing(KEY))
    hq_unsigned = Codec(255, 190)
    forger = Codec(255, 190, Signing(bytes(32)))
    robot = Codec(7, 191, Signing(KEY))
    m = robot.module
    ack = m.MAVLink_rescue_ack_message(7, 191, 43100, 1, 0)
    telemetry = m.MAVLink_attitude_message(1, 0, 0, 0, 0, 0, 0)
    got = robot.feed(hq_signed.encode(ack))
    assert [x.get_type() for x in got] == ["RESCUE_ACK"]
    got = robot.feed(hq_unsigned.encode(ack) + forger.encode(ack))
    assert got == []
    assert robot.counters.signature_rejected == 2
    # Telemetry from an autopilot that does not sign still gets through.
    assert [x.get_type() for x in robot.feed(hq_unsigned.encode(telemetry))] == ["ATTITUDE"]
    # Our outgoing frames are signed (13 signature bytes) and verify at the HQ.
    frame = robot.encode(m.MAVLink_rescue_status_message(1, 10.0, 0.0, 20.0, 1, 1, 0, 0))
    assert frame[2] & 0x01
    assert [x.get_type() for x in hq_signed.feed(frame)] == ["RESCUE_STATUS"]


def test_victim_report_roundtrip_si_units() -> None:
    rep = report(lat_deg=48.1234567, lon_deg=-124.6543210, alt_m=12.345)
    msg = convert.victim_report_to_msg(rep, 42, convert.FLAG_NEW, 1.7e9 + 6, None)
    assert msg.flags == convert.FLAG_NEW | convert.FLAG_GLOBAL_VALID
    tx, rx = Codec(7, 191), Codec(255, 190)
    (back,) = rx.feed(tx.encode(msg))
    out = convert.msg_to_victim_report(back)
    assert back.report_seq == 42
    assert (out.lat_deg, out.lon_deg, out.alt_m) == pytest.approx((48.1234567, -124.654321, 12.345))
    assert out.first_seen_unix_s == rep.first_seen_unix_s
    assert out.north_m == pytest.approx(12.34, abs=1e-5)  # float32 on the wire
    no_global = convert.msg_to_victim_report(
        rx.feed(tx.encode(convert.victim_report_to_msg(report(), 1, 0, 1.7e9, None)))[0]
    )
    assert no_global.lat_deg is None
    bad = convert.victim_report_to_msg(report(), 1, 0, 1.7e9, None)
    bad.cov_nn = 0.0
    with pytest.raises(ValueError, match="victim 3"):
        convert.msg_to_victim_report(bad)


def test_origin_rejects_zero_zero_and_home_position_offsets() -> None:
    m = Codec(1, 1).module
    assert (
        convert.origin_from_gps_global_origin(m.MAVLink_gps_global_origin_message(0, 0, 0)) is None
    )
    home = m.MAVLink_home_position_message(
        481234567, -1241234567, 10000, 10.0, 0.0, 0.0, [1, 0, 0, 0], 0, 0, 0
    )
    origin = convert.origin_from_home_position(home)
    assert origin is not None
    # Home is 10 m north of the origin: the origin lies ~10 m (9e-5 deg) south of home.
    assert origin.lat_deg == pytest.approx(48.1234567 - 10.0 / 111_200, abs=2e-6)


# ----------------------------------------------------------------- TUNNEL


def test_tunnel_carries_a_signed_dialect_frame() -> None:
    robot = Codec(7, 191, Signing(KEY))
    hq = Codec(255, 190, Signing(KEY))
    rep = convert.victim_report_to_msg(report(), 9, 0, 1.7e9, None)
    outer = tunnel.wrap(robot, rep)
    assert outer.payload_type == tunnel.TUNNEL_PAYLOAD_TYPE >= 32768
    assert 80 < outer.payload_length <= 107  # signed report; MAVLink 2 trims trailing zeros
    (got,) = hq.feed(robot.encode(outer))
    inner = tunnel.unpack_tunnel(got, hq)
    assert inner is not None and inner.report_seq == 9
    other = Codec(1, 1).module.MAVLink_tunnel_message(0, 0, 5, 3, [1, 2, 3] + [0] * 125)
    assert tunnel.unpack_tunnel(other, hq) is None
    with pytest.raises(ValueError, match="does not fit"):
        tunnel.pack_tunnel(bytes(129))


# ----------------------------------------------------------------- outbox / dedupe


def test_outbox_resends_with_backoff_until_acked() -> None:
    now = [100.0]
    sent: list[int] = []
    outbox = Outbox(
        lambda m: sent.append(m.report_seq), initial_s=1.0, max_s=4.0, clock=lambda: now[0]
    )
    m = Codec(1, 1).module
    outbox.submit(convert.victim_report_to_msg(report(), 1, 0, 1.7e9, None))
    outbox.submit(convert.victim_report_to_msg(report(victim_id=4), 2, 0, 1.7e9, None))
    assert sent == [1, 2]
    resend_times = []
    for k in range(1, 201):  # 20 s in 0.1 s steps
        now[0] = 100.0 + k / 10
        if outbox.poll():
            resend_times.append(round(now[0] - 100.0, 1))
    # Due after 1, then 2, 4, 4, 4 ... seconds: 1, 3, 7, 11, 15, 19.
    assert resend_times == [1.0, 3.0, 7.0, 11.0, 15.0, 19.0]
    assert outbox.on_ack(m.MAVLink_rescue_ack_message(7, 191, 43100, 1, 0))
    assert not outbox.on_ack(m.MAVLink_rescue_ack_message(7, 191, 43100, 1, 0))  # late duplicate
    assert outbox.pending_count == 1 and outbox.attempts(43100, 2) == 7
    assert outbox.counters.unmatched_acks == 1


def test_outbox_store_survives_a_restart() -> None:
    from mavlink_io.reliable import MemoryOutboxStore

    store = MemoryOutboxStore()
    first = Outbox(lambda m: None, store)
    first.submit(convert.victim_report_to_msg(report(), 5, 0, 1.7e9, None))
    sent: list[int] = []
    second = Outbox(lambda m: sent.append(m.report_seq), store)
    assert second.pending_count == 1 and second.poll() == 1 and sent == [5]


def test_deduplicator_by_robot_and_seq() -> None:
    dedupe = Deduplicator(capacity=2)
    msg = convert.victim_report_to_msg(report(), 5, 0, 1.7e9, None)
    assert not dedupe.check(msg)
    assert dedupe.check(msg)
    assert not dedupe.is_duplicate(8, 5, 43100)  # another robot, same seq
    assert not dedupe.is_duplicate(7, 6, 43100)
    assert not dedupe.check(msg)  # capacity 2: the oldest key was forgotten
    assert dedupe.duplicates == 1


# ----------------------------------------------------------------- tlog


def test_tlog_roundtrip_with_mavutil_and_rotation(tmp_path: Path) -> None:
    codec = Codec(7, 191)
    m = codec.module
    writer = TlogWriter(tmp_path, max_bytes=2048)
    for i in range(100):
        writer.write(codec.encode(m.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)), 1.7e9 + i)
        writer.write(
            codec.encode(m.MAVLink_statustext_message(4, b"hello %d" % i, 0, 0)), 1.7e9 + i
        )
    writer.close()
    writer.close()
    assert len(writer.files) > 2 and all(f.stat().st_size <= 2048 for f in writer.files)
    ours = [(t, msg.get_type()) for f in writer.files for t, msg in read_tlog(f)]
    assert len(ours) == 200 and ours[0] == (1.7e9, "HEARTBEAT")
    conn = mavutil.mavlink_connection(str(writer.files[0]))
    first = conn.recv_match(type="STATUSTEXT")
    assert first.text == "hello 0" and first._timestamp == pytest.approx(1.7e9)
    conn.close()
    dump = Path(sys.executable).with_name("mavlogdump.py")
    out = subprocess.run(
        [sys.executable, str(dump), "--types", "STATUSTEXT", str(writer.files[0])],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    ).stdout
    assert "hello 0" in out


def test_tlog_reader_survives_corruption(tmp_path: Path) -> None:
    codec = Codec(7, 191)
    m = codec.module
    path = tmp_path / "x.tlog"
    writer = TlogWriter(tmp_path, max_bytes=1 << 20)
    for i in range(50):
        writer.write(codec.encode(m.MAVLink_attitude_message(i, 0, 0, 0, 0, 0, 0)), 1.7e9 + i)
    writer.close()
    data = bytearray(writer.files[0].read_bytes())
    data[100:110] = b"\xfd" * 10  # smash one record
    path.write_bytes(bytes(data) + b"\xfd\x09")  # and a truncated tail
    got = [msg.time_boot_ms for _, msg in read_tlog(path) if msg.get_type() == "ATTITUDE"]
    assert 47 <= len(got) < 50 and got == sorted(got)


def test_full_disk_stops_recording_once(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    if not Path("/dev/full").exists():
        pytest.skip("/dev/full not available")
    (tmp_path / "d").mkdir()
    writer = TlogWriter(tmp_path / "d", max_bytes=1 << 20)
    writer.write(b"\xfd" + bytes(20))
    assert writer.path is not None
    # Swap the open file for /dev/full, which fails every write with ENOSPC.
    assert writer._file is not None
    writer._file.close()
    writer._file = open("/dev/full", "wb", buffering=0)  # noqa: SIM115
    for _ in range(5):
        writer.write(b"\xfd" + bytes(20))
    assert not writer.recording and writer.error is not None
    assert os.strerror(errno.ENOSPC) in writer.error
    warnings = [r for r in caplog.records if "recording stopped" in r.getMessage()]
    assert len(warnings) == 1
    writer.close()


def _dialect_without_cues(tmp_path: Path) -> object:
    """The dialect as a robot or HQ from before the cues field has it."""
    from mavlink_io import dialect

    xml = dialect.DIALECT_XML.read_text()
    start = xml.index("      <extensions/>\n")
    end = xml.index("</field>\n", start) + len("</field>\n")
    old = tmp_path / "rescue.xml"
    old.write_text(xml[:start] + xml[end:])
    return dialect.load(tmp_path / "cache", old)


def test_cues_round_trip_and_old_peers_parse_the_report(tmp_path: Path) -> None:
    from fusion.types import Cue

    for cues in (Cue.WARM, Cue.COLOUR_BODY | Cue.WARM, Cue.COLOUR_PART, Cue(0)):
        msg = convert.victim_report_to_msg(report(cues=cues), 5, 0, 1.7e9, None)
        (back,) = Codec(255, 190).feed(Codec(7, 191).encode(msg))
        assert convert.msg_to_victim_report(back).cues == cues
    old = _dialect_without_cues(tmp_path)
    # A new robot's report with cues: an old HQ checks its CRC and reads every old field.
    new_frame = Codec(7, 191).encode(
        convert.victim_report_to_msg(report(cues=Cue.WARM), 6, 0, 1.7e9, None)
    )
    (at_old,) = Codec(255, 190, module=old).feed(new_frame)
    assert at_old.get_type() == "RESCUE_VICTIM_REPORT" and at_old.report_seq == 6
    assert at_old.victim_id == 3 and at_old.urgency == int(Urgency.CRITICAL)
    # An old robot's report reaches a new HQ with cues 0: not known.
    old_msg = old.MAVLink_rescue_victim_report_message(  # type: ignore[attr-defined]
        *[getattr(at_old, n) for n in at_old.get_fieldnames()]
    )
    (at_new,) = Codec(255, 190).feed(Codec(7, 191, module=old).encode(old_msg))
    assert convert.msg_to_victim_report(at_new).cues == Cue(0)
