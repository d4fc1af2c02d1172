"""Fuzz the companion's real vehicle link with valid-CRC messages of random fields.

A seeded, bounded run over real UDP on 127.0.0.1: FUZZ_SECONDS (default 3) of
random messages, mostly of the types the vehicle link acts on, from the autopilot's
own identity. Whatever the link accepts (every origin and pose) must be usable
downstream as the processing thread uses it: a victim beside the vehicle becomes a
report and a map marker that encode. Afterwards the reader thread is alive, no
handler or loop error was caught, and a clean autopilot's pose is decoded again. ``make fuzz-companion`` runs
it for 60 s with a fresh seed (FUZZ_SEED, printed on failure).
"""

from __future__ import annotations

import math
import os
import random
import time
import traceback

from fusion.registry import Victim
from fusion.types import TrackState, Urgency
from mavlink_io import convert
from mavlink_io.codec import Codec, MavMessage
from mavlink_io.netlinks import UdpInLink, UdpOutLink
from mavlink_io.vehicle import VehicleLink, VehicleSettings
from tests.fieldfuzz import random_message

SYSID = 7
SEED = int(os.environ.get("FUZZ_SEED", "16"))
SECONDS = float(os.environ.get("FUZZ_SECONDS", "3"))
# What the vehicle link acts on: HEARTBEAT, ATTITUDE, LOCAL_POSITION_NED,
# GLOBAL_POSITION_INT, GPS_GLOBAL_ORIGIN, COMMAND_ACK, HOME_POSITION, TUNNEL, and
# the dialect's RESCUE_ACK and RESCUE_OPERATOR_ACTION.
_TARGETED = [0, 30, 32, 33, 49, 77, 242, 385, 43100, 43101]


def _clean_telemetry(codec: Codec, out: UdpOutLink, boot_s: float) -> None:
    m = codec.module
    ms = int(boot_s * 1000)
    out.write(codec.encode(m.MAVLink_heartbeat_message(10, 3, 0, 0, 4, 3)))
    out.write(codec.encode(m.MAVLink_attitude_message(ms, 0.01, -0.02, 1.5, 0, 0, 0)))
    out.write(codec.encode(m.MAVLink_local_position_ned_message(ms, 3.0, 2.0, -0.1, 0, 0, 0)))


class Downstream:
    """What the processing thread does with the link's origin and pose, checked on
    every message the link accepted; the first failures are kept."""

    def __init__(self) -> None:
        self.vehicle: VehicleLink | None = None
        self.codec = Codec(SYSID, 191)
        self.failures: list[str] = []
        self.checked = 0

    def __call__(self, _msg: MavMessage) -> None:
        vehicle = self.vehicle
        if vehicle is None:
            return
        try:
            self._check(vehicle)
        except Exception:  # collected, reported by the test
            if len(self.failures) < 3:
                self.failures.append(traceback.format_exc(limit=3))

    def _check(self, vehicle: VehicleLink) -> None:
        pose = vehicle.poses.latest()
        origin = vehicle.origin
        if pose is None:
            return
        fields = (pose.north_m, pose.east_m, pose.down_m, pose.roll_rad, pose.yaw_rad)
        assert all(math.isfinite(v) for v in fields), pose
        victim = Victim(
            victim_id=1,
            state=TrackState.CONFIRMED,
            urgency=Urgency.MEDIUM,
            visibility_pct=40.0,
            north_m=pose.north_m + 5.0,
            east_m=pose.east_m,
            cov_ne_m2=((0.1, 0.0), (0.0, 0.1)),
            observations=3,
            first_seen_unix_s=time.time(),
            last_seen_unix_s=time.time(),
            log_odds=3.0,
            merged_into=None,
        )
        report = victim.to_report(SYSID, pose.down_m + 0.1, origin)
        self.codec.encode(convert.victim_report_to_msg(report, 1, 0, time.time(), None))
        self.checked += 1


def test_random_valid_messages_crash_nothing_and_the_pose_comes_back() -> None:
    rng = random.Random(SEED)
    link = UdpInLink("127.0.0.1", 0)
    downstream = Downstream()
    vehicle = VehicleLink(
        link,
        VehicleSettings(system_id=SYSID, heartbeat_timeout_s=30.0),
        on_message=downstream,
    )
    downstream.vehicle = vehicle
    out = UdpOutLink("127.0.0.1", link.local_address[1])
    ap = Codec(SYSID, 1)
    all_ids = sorted(ap.module.mavlink_map)
    sent = 0
    try:
        t0 = time.monotonic()
        _clean_telemetry(ap, out, 100.0)
        while time.monotonic() - t0 < SECONDS:
            ids = _TARGETED if rng.random() < 0.8 else all_ids
            msg = random_message(ap.module, rng, ids)
            try:
                frame = ap.encode(msg)
            except Exception:  # a field pymavlink cannot pack: not sent
                continue
            out.write(frame)
            sent += 1
            if sent % 200 == 0:
                # Let the reader keep up (on a loaded machine it reads slower than this
                # loop sends, and the socket drops the rest): loss would hide nothing.
                # Paced by what it has read, at most 1 s a batch, so a reader that
                # stops reading still fails the test below.
                deadline = time.monotonic() + 1.0
                while vehicle.counters.messages_in < 0.6 * sent and time.monotonic() < deadline:
                    time.sleep(0.002)
        received = vehicle.counters.messages_in
        # A clean autopilot afterwards: pose decoded again, on whichever timeline the
        # fuzz left (a new one is confirmed after three agreeing samples).
        boot_s = 5000.0
        end = time.monotonic() + 5.0
        poses_before = vehicle.counters.poses
        while vehicle.counters.poses <= poses_before + 5 and time.monotonic() < end:
            boot_s += 0.02
            _clean_telemetry(ap, out, boot_s)
            time.sleep(0.02)
        counters = vehicle.state().counters
        context = f"seed {SEED}, {sent} sent, {received} received, counters {counters}"
        assert not downstream.failures, f"{context}\n" + "\n".join(downstream.failures)
        assert downstream.checked > 0, context
        assert vehicle.alive, context
        assert counters["handler_errors"] == 0 and counters["loop_errors"] == 0, context
        assert received > sent // 2, context
        # Random boot times are refused, not taken for reboots (each would clear the
        # pose history and send a burst of stream requests); the clean autopilot's
        # timeline at the end is one confirmed change.
        assert counters["reboots"] <= 2, context
        assert vehicle.counters.poses > poses_before + 5, context
        pose = vehicle.poses.latest()
        assert pose is not None and (pose.north_m, pose.east_m) == (3.0, 2.0), context
    finally:
        out.close()
        vehicle.close()
