"""A minimal simulated robot for exercising rescue-hq over UDP (tests, bench, demos).

It speaks the dialect through the project's codec from an ephemeral UDP port on
its own: victim reports (direct or inside TUNNEL), RESCUE_STATUS, HEARTBEAT; it
reads RESCUE_ACKs and RESCUE_OPERATOR_ACTIONs addressed to it and can answer an
action with its RESCUE_ACK. It is not the companion: no tracker, no resend policy
(the caller decides when to resend).
"""

from __future__ import annotations

import select
import socket
import time
from dataclasses import dataclass
from typing import Any

from fusion.types import NO_CUES, Cue, TrackState, Urgency, VictimReport
from hq import wire
from mavlink_io.codec import Codec
from mavlink_io.dialect import RESCUE_OPERATOR_ACTION_ID
from mavlink_io.signing import Signing

COMPANION_COMPONENT_ID = 191  # MAV_COMP_ID_ONBOARD_COMPUTER


@dataclass(frozen=True)
class Received:
    msg: Any
    tunnelled: bool


class SimRobot:
    def __init__(
        self,
        sysid: int,
        hq_address: tuple[str, int],
        *,
        tunnel: bool = False,
        signing: Signing | None = None,
    ) -> None:
        self.sysid = sysid
        self.hq_address = hq_address
        self.tunnel = tunnel
        self.codec = Codec(sysid, COMPANION_COMPONENT_ID, signing)
        self.m = self.codec.module
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.seq = 0

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.sock.getsockname()[:2]
        return (str(host), int(port))

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> SimRobot:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def send(self, msg: Any, *, tunnel: bool | None = None) -> None:
        if self.tunnel if tunnel is None else tunnel:
            msg = wire.wrap_tunnel(self.codec, msg, 0, 0)  # to whoever is the ground
        self.sock.sendto(self.codec.encode(msg), self.hq_address)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.hq_address)

    def heartbeat(self) -> None:
        m = self.m
        self.send(
            m.MAVLink_heartbeat_message(
                m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3
            ),
            tunnel=False,
        )

    def position(self, north_m: float, east_m: float) -> None:
        """LOCAL_POSITION_NED as the robot's autopilot streams it (sent direct, not tunnelled)."""
        boot_ms = int(time.monotonic() * 1000) & 0xFFFFFFFF
        self.send(
            self.m.MAVLink_local_position_ned_message(boot_ms, north_m, east_m, 0.0, 0.0, 0.0, 0.0),
            tunnel=False,
        )

    def status(self, *, confirmed: int = 0, flags: int = 0b111) -> None:
        self.send(self.m.MAVLink_rescue_status_message(10, 9.5, 0.0, 40.0, flags, confirmed, 0, 0))

    def victim(
        self,
        victim_id: int,
        north_m: float,
        east_m: float,
        *,
        urgency: Urgency = Urgency.MEDIUM,
        visibility_pct: float = 30.0,
        sigma_m: float = 0.5,
        seen_unix_s: float | None = None,
        geo: tuple[float, float, float] | None = None,
        state: TrackState = TrackState.CONFIRMED,
        cues: Cue = NO_CUES,
    ) -> VictimReport:
        t = time.time() if seen_unix_s is None else seen_unix_s
        return VictimReport(
            victim_id=victim_id,
            robot_sysid=self.sysid,
            state=state,
            urgency=urgency,
            visibility_pct=visibility_pct,
            north_m=north_m,
            east_m=east_m,
            down_m=0.0,
            cov_ne_m2=((sigma_m**2, 0.0), (0.0, sigma_m**2)),
            observations=5,
            first_seen_unix_s=t - 2.0,
            last_seen_unix_s=t,
            lat_deg=None if geo is None else geo[0],
            lon_deg=None if geo is None else geo[1],
            alt_m=None if geo is None else geo[2],
            cues=cues,
        )

    def report_msg(
        self, report: VictimReport, *, seq: int | None = None, time_unix_s: float | None = None
    ) -> Any:
        if seq is None:
            self.seq += 1
            seq = self.seq
        t = time.time() if time_unix_s is None else time_unix_s
        return wire.report_to_msg(self.codec, report, seq, t)

    def receive(self, timeout_s: float, *, any_target: bool = False) -> list[Received]:
        """Messages for this robot (or all, ``any_target``) arriving within ``timeout_s``."""
        readable, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        if not readable:
            return []
        data, _addr = self.sock.recvfrom(65536)
        out = []
        for msg in self.codec.feed(data):
            tunnelled = msg.get_type() == "TUNNEL"
            if tunnelled:
                msg = wire.unwrap_tunnel(self.codec, msg)
                if msg is None:
                    continue
            if any_target or getattr(msg, "target_system", self.sysid) in (0, self.sysid):
                out.append(Received(msg, tunnelled))
        return out

    def wait_for(
        self, msg_type: str, timeout_s: float, *, any_target: bool = False, **fields: int
    ) -> Received:
        """The next message of ``msg_type`` with the given field values; TimeoutError if none."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"robot {self.sysid}: no {msg_type} {fields} in {timeout_s} s")
            for rx in self.receive(left, any_target=any_target):
                if rx.msg.get_type() == msg_type and all(
                    getattr(rx.msg, k) == v for k, v in fields.items()
                ):
                    return rx

    def ack_action(self, action: Any, *, tunnel: bool | None = None) -> None:
        self.send(
            self.m.MAVLink_rescue_ack_message(
                action.get_srcSystem(),
                action.get_srcComponent(),
                RESCUE_OPERATOR_ACTION_ID,
                action.action_seq,
                0,
            ),
            tunnel=tunnel,
        )
