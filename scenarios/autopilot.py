"""The simulated autopilot's MAVLink behaviour, without any I/O: bytes in, bytes out.

It behaves as ArduPilot Rover does on its MAVLink ports ("links", numbered 0..n-1):
- sends HEARTBEAT (MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_ARDUPILOTMEGA) at 1 Hz and
  its streams per link: SYS_STATUS, SYSTEM_TIME, ATTITUDE, LOCAL_POSITION_NED,
  GLOBAL_POSITION_INT and SIM_STATE (the true pose) at default rates;
  GPS_GLOBAL_ORIGIN and HOME_POSITION once at boot, when the origin changes, and
  on request;
- drives as Rover does (scenarios/autopilot_drive.py): its mode in HEARTBEAT's
  custom_mode; SET_MODE and MAV_CMD_DO_SET_MODE to MANUAL, HOLD, AUTO or GUIDED
  (COMMAND_ACK; other modes MAV_RESULT_FAILED); SET_POSITION_TARGET_LOCAL_NED in
  GUIDED (no ack, as ArduPilot); MISSION_SET_CURRENT (answered by MISSION_CURRENT)
  and MAV_CMD_DO_SET_MISSION_CURRENT; MISSION_CURRENT on request or at a requested
  interval (none by default);
- honours COMMAND_LONG MAV_CMD_SET_MESSAGE_INTERVAL (per link, like ArduPilot),
  MAV_CMD_REQUEST_MESSAGE, MAV_CMD_GET_HOME_POSITION and
  MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, answering COMMAND_ACK (MAV_RESULT_UNSUPPORTED
  for other commands); REQUEST_DATA_STREAM (no ack, as ArduPilot); TIMESYNC
  requests; SET_GPS_GLOBAL_ORIGIN;
- routes: it learns which (system, component) spoke on which link, forwards a
  broadcast packet to every other link that has heard someone, and a targeted one
  to the links where its target was heard; it forwards the original bytes. Like
  ArduPilot it forwards only messages it can check: our dialect's message IDs
  (43100-43105) and unparseable packets are dropped, not routed.

Its reported pose is the truth plus a slow drift and white noise (scenarios.motion).
Times are simulation seconds; ``unix_of`` maps them to the wall clock of SYSTEM_TIME.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fusion.geodesy import ned_to_geodetic
from fusion.types import GlobalOrigin
from mavlink_io import dialect
from mavlink_io.convert import e7_from_deg
from mavlink_io.dialect import RESCUE_MESSAGE_IDS
from scenarios.autopilot_drive import MODE_NAMES, Drive
from scenarios.motion import PoseError, Trajectory, TruePose

log = logging.getLogger(__name__)

Out = list[tuple[int, bytes]]  # (link index, packet)

HEARTBEAT = 0
SYS_STATUS = 1
SYSTEM_TIME = 2
ATTITUDE = 30
LOCAL_POSITION_NED = 32
GLOBAL_POSITION_INT = 33
SIM_STATE = 108
MISSION_CURRENT = 42
GPS_GLOBAL_ORIGIN = 49
HOME_POSITION = 242

DEFAULT_RATES_HZ: dict[int, float] = {
    HEARTBEAT: 1.0,
    SYS_STATUS: 1.0,
    SYSTEM_TIME: 1.0,
    ATTITUDE: 4.0,
    LOCAL_POSITION_NED: 4.0,
    GLOBAL_POSITION_INT: 4.0,
    SIM_STATE: 4.0,
    GPS_GLOBAL_ORIGIN: 0.0,
    HOME_POSITION: 0.0,
    MISSION_CURRENT: 0.0,
}
STREAMABLE = frozenset(DEFAULT_RATES_HZ)

# REQUEST_DATA_STREAM stream ids (MAV_DATA_STREAM) -> our messages, as ArduPilot groups them.
DATA_STREAMS: dict[int, tuple[int, ...]] = {
    2: (SYS_STATUS, MISSION_CURRENT),  # EXTENDED_STATUS
    6: (GLOBAL_POSITION_INT, LOCAL_POSITION_NED),  # POSITION
    10: (ATTITUDE, SIM_STATE),  # EXTRA1
    12: (SYSTEM_TIME,),  # EXTRA3
}

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_GET_HOME_POSITION = 410
MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN = 246
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_SET_MISSION_CURRENT = 224
MSG_SET_MODE = 11  # ArduPilot acknowledges SET_MODE with COMMAND_ACK(command=11)
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3
MAV_RESULT_FAILED = 4
REBOOT_SILENCE_S = 2.0


@dataclass
class _LinkState:
    mav: Any  # encoder (own sequence numbers) and parser of this link
    intervals_s: dict[int, float] = field(default_factory=dict)  # 0 = off
    next_due_s: dict[int, float] = field(default_factory=dict)
    routes: set[tuple[int, int]] = field(default_factory=set)  # (sysid, compid) heard here
    dropped_until_s: float = -1.0
    pending_once: set[int] = field(default_factory=set)  # send once, at the next poll


@dataclass
class Counters:
    routed: int = 0
    not_routed_unknown: int = 0
    commands: int = 0
    reboots: int = 0


class Autopilot:
    """One simulated ArduPilot Rover's MAVLink endpoint (not thread-safe)."""

    def __init__(
        self,
        trajectory: Trajectory,
        origin: GlobalOrigin,
        *,
        n_links: int = 1,
        sysid: int = 1,
        compid: int = 1,
        seed: int = 0,
        unix_of: Callable[[float], float] = lambda t_s: t_s,
        origin_at_boot: bool = True,
        rates_hz: dict[int, float] | None = None,
        position_noise_m: float = 0.01,
        attitude_noise_rad: float = math.radians(0.2),
    ) -> None:
        self.m = dialect.load()
        self.trajectory = trajectory
        self.drive = Drive(trajectory)
        self.armed = True
        self.world_origin = origin
        self.sysid, self.compid = sysid, compid
        self.unix_of = unix_of
        self.origin_at_boot = origin_at_boot
        self.default_rates_hz = {**DEFAULT_RATES_HZ, **(rates_hz or {})}
        self.error = PoseError(seed)
        self.position_noise_m = position_noise_m
        self.attitude_noise_rad = attitude_noise_rad
        self._rng = np.random.default_rng([seed, 0xA7])
        self.counters = Counters()
        self.links = [self._new_link() for _ in range(n_links)]
        self.boot_t0_s = 0.0
        self.silent_until_s = -1.0
        self.origin: GlobalOrigin | None = None
        self._boot(0.0, silence_s=0.0)

    # -- life cycle ----------------------------------------------------------------

    def _new_link(self) -> _LinkState:
        mav = self.m.MAVLink(None, self.sysid, self.compid)
        mav.robust_parsing = True
        return _LinkState(mav)

    def _boot(self, t_s: float, silence_s: float) -> None:
        self.boot_t0_s = t_s
        self.silent_until_s = t_s + silence_s
        self.origin = self.world_origin if self.origin_at_boot else None
        for i, link in enumerate(self.links):
            fresh = self._new_link()
            fresh.dropped_until_s = link.dropped_until_s
            self.links[i] = fresh
            for msgid, rate in self.default_rates_hz.items():
                self._set_interval(fresh, msgid, 1.0 / rate if rate > 0 else 0.0, t_s)
            if self.origin is not None:
                fresh.pending_once |= {GPS_GLOBAL_ORIGIN, HOME_POSITION}

    def reboot(self, t_s: float, silence_s: float = REBOOT_SILENCE_S) -> None:
        """Restart: boot time restarts at 0, streams and routes are forgotten."""
        log.info("autopilot reboots at t=%.2f s", t_s)
        self.counters.reboots += 1
        self._boot(t_s, silence_s)

    def drop_link(self, t_s: float, duration_s: float, link: int | None = None) -> None:
        """Nothing goes out or comes in on the link(s) for duration_s."""
        for i in range(len(self.links)) if link is None else (link,):
            self.links[i].dropped_until_s = t_s + duration_s

    def set_mode(self, mode: int, t_s: float) -> None:
        """Change the mode (a command, or a test's operator at the RC switch)."""
        log.info("autopilot mode %s at t=%.2f s", MODE_NAMES.get(mode, mode), t_s)
        self.drive.set_mode(mode, t_s)

    def block(self, north_m: float, east_m: float, radius_m: float) -> None:
        """A test's obstacle: from the next command on, the rover cannot enter it."""
        self.drive.blocked = (*self.drive.blocked, (north_m, east_m, radius_m))

    def boot_s(self, t_s: float) -> float:
        return max(0.0, t_s - self.boot_t0_s)

    def _down(self, link: _LinkState, t_s: float) -> bool:
        return t_s < self.silent_until_s or t_s < link.dropped_until_s

    # -- sending -------------------------------------------------------------------

    def _set_interval(self, link: _LinkState, msgid: int, interval_s: float, t_s: float) -> None:
        link.intervals_s[msgid] = interval_s
        link.next_due_s[msgid] = t_s + (interval_s if msgid != HEARTBEAT else 0.0)

    def next_due_s(self) -> float:
        """The simulation time at which poll() has something to send."""
        due = [
            t
            for link in self.links
            for msgid, t in link.next_due_s.items()
            if link.intervals_s.get(msgid, 0.0) > 0
        ]
        soonest = min(due) if due else math.inf
        if any(link.pending_once for link in self.links):
            soonest = -math.inf
        return max(soonest, self.silent_until_s)

    def poll(self, t_s: float) -> Out:
        """Packets due by t_s on every link."""
        out: Out = []
        for i, link in enumerate(self.links):
            if t_s < self.silent_until_s:
                continue
            due = sorted(
                msgid
                for msgid, interval in link.intervals_s.items()
                if interval > 0 and link.next_due_s[msgid] <= t_s
            )
            for msgid in due:
                interval = link.intervals_s[msgid]
                nxt = link.next_due_s[msgid] + interval
                link.next_due_s[msgid] = nxt if nxt > t_s else t_s + interval
            once = sorted(link.pending_once)
            link.pending_once.clear()
            if self._down(link, t_s):
                continue
            for msgid in due + [m for m in once if m not in due]:
                msg = self._build(msgid, t_s)
                if msg is not None:
                    out.append((i, msg.pack(link.mav)))
        return out

    def estimate(self, t_s: float) -> tuple[TruePose, TruePose]:
        """(truth, estimate) at t_s."""
        true = self.drive.pose_at(t_s)
        dn, de, dyaw = self.error.drift(t_s)
        pn, pa = self.position_noise_m, self.attitude_noise_rad
        r = self._rng.standard_normal(6)
        est = TruePose(
            t_s=t_s,
            north_m=true.north_m + dn + pn * r[0],
            east_m=true.east_m + de + pn * r[1],
            down_m=true.down_m + pn * r[2],
            roll_rad=true.roll_rad + pa * r[3],
            pitch_rad=true.pitch_rad + pa * r[4],
            yaw_rad=math.remainder(true.yaw_rad + dyaw + pa * r[5], 2 * math.pi),
            vn_m_s=true.vn_m_s,
            ve_m_s=true.ve_m_s,
            vd_m_s=true.vd_m_s,
            yaw_rate_rad_s=true.yaw_rate_rad_s,
        )
        return true, est

    def _geo(self, p: TruePose) -> tuple[int, int, int]:
        """degE7 latitude, longitude and mm altitude of a pose (0, 0 without origin)."""
        if self.origin is None:
            return 0, 0, 0
        lat, lon, alt = ned_to_geodetic(self.origin, p.north_m, p.east_m, p.down_m)
        return e7_from_deg(lat), e7_from_deg(lon), round(alt * 1000.0)

    def _build(self, msgid: int, t_s: float) -> Any:
        from scenarios import autopilot_msgs

        return autopilot_msgs.build(self, msgid, t_s)

    # -- receiving -----------------------------------------------------------------

    def handle(self, link_index: int, data: bytes, t_s: float) -> Out:
        """Feed received bytes; returns replies and forwarded packets."""
        link = self.links[link_index]
        if self._down(link, t_s):
            return []
        out: Out = []
        try:
            msgs = link.mav.parse_buffer(data) or []
        except self.m.MAVError as exc:  # robust_parsing makes this rare
            log.debug("link %d: unparseable bytes: %s", link_index, exc)
            return out
        for msg in msgs:
            out += self._handle_msg(link_index, msg, t_s)
        return out

    def _handle_msg(self, li: int, msg: Any, t_s: float) -> Out:
        msgid = msg.get_msgId()
        if msg.get_type() == "BAD_DATA" or msgid < 0:
            self.counters.not_routed_unknown += 1
            return []
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        self.links[li].routes.add(src)
        if msgid in RESCUE_MESSAGE_IDS:
            # ArduPilot cannot check the CRC of a message it does not know: dropped.
            self.counters.not_routed_unknown += 1
            return []
        target_sys = getattr(msg, "target_system", 0)
        target_comp = getattr(msg, "target_component", 0)
        out = self._forward(li, msg, target_sys, target_comp)
        for_us = target_sys in (0, self.sysid) and target_comp in (0, self.compid)
        if for_us:
            out += self._process(li, msg, t_s)
        return out

    def _forward(self, li: int, msg: Any, target_sys: int, target_comp: int) -> Out:
        if target_sys == self.sysid and target_comp == self.compid:
            return []  # for us alone
        raw = bytes(msg.get_msgbuf())
        out: Out = []
        for j, other in enumerate(self.links):
            if j == li or not other.routes:
                continue
            if target_sys == 0:
                ok = True
            elif target_comp == 0:
                ok = any(s == target_sys for s, _ in other.routes)
            else:
                ok = (target_sys, target_comp) in other.routes
            if ok:
                out.append((j, raw))
                self.counters.routed += 1
        return out

    def _process(self, li: int, msg: Any, t_s: float) -> Out:
        from scenarios import autopilot_msgs

        return autopilot_msgs.process(self, li, msg, t_s)
