"""The simulated autopilot's messages: what it sends, and what it does with commands.

Split from scenarios.autopilot to keep each module small. Scaled integers are made
with mavlink_io.convert where it has a helper; the rest are the plain unit factors
that the MAVLink message definitions state (cdeg, cm/s, ms).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from fusion.types import GlobalOrigin
from mavlink_io.convert import e7_from_deg, usec_from_unix_s
from scenarios import autopilot as ap
from scenarios import autopilot_drive as drive

if TYPE_CHECKING:
    from scenarios.autopilot import Autopilot, Out

_MS = 1000.0
_CM = 100.0


def _quat(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def build(a: Autopilot, msgid: int, t_s: float) -> Any:
    """The message msgid at simulation time t_s, or None if it cannot be made now."""
    m = a.m
    boot_ms = int(a.boot_s(t_s) * _MS) & 0xFFFFFFFF
    if msgid == ap.HEARTBEAT:
        base = (
            m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            | (m.MAV_MODE_FLAG_SAFETY_ARMED if a.armed else 0)
            | m.MAV_MODE_FLAG_AUTO_ENABLED
            | m.MAV_MODE_FLAG_STABILIZE_ENABLED
            | m.MAV_MODE_FLAG_GUIDED_ENABLED
        )
        return m.MAVLink_heartbeat_message(
            m.MAV_TYPE_GROUND_ROVER,
            m.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base,
            a.drive.mode,
            m.MAV_STATE_ACTIVE,
            3,
        )
    if msgid == ap.SYS_STATUS:
        return m.MAVLink_sys_status_message(0, 0, 0, 250, 12400, 150, 80, 0, 0, 0, 0, 0, 0)
    if msgid == ap.SYSTEM_TIME:
        return m.MAVLink_system_time_message(usec_from_unix_s(a.unix_of(t_s)), boot_ms)
    if msgid == ap.SIM_STATE:
        return _sim_state(a, t_s)
    if msgid == ap.GPS_GLOBAL_ORIGIN:
        o = a.origin
        if o is None:
            return None
        return m.MAVLink_gps_global_origin_message(
            e7_from_deg(o.lat_deg), e7_from_deg(o.lon_deg), round(o.alt_m * _MS), 0
        )
    if msgid == ap.HOME_POSITION:
        return _home(a, t_s)
    if msgid == ap.MISSION_CURRENT:
        # mission_state 3: MISSION_STATE_ACTIVE (4: PAUSED, outside AUTO)
        active = 3 if a.drive.mode == drive.MODE_AUTO else 4
        return m.MAVLink_mission_current_message(
            a.drive.mission_seq(t_s), a.drive.mission_items, active
        )
    _true, est = a.estimate(t_s)
    if msgid == ap.ATTITUDE:
        return m.MAVLink_attitude_message(
            boot_ms, est.roll_rad, est.pitch_rad, est.yaw_rad, 0.0, 0.0, est.yaw_rate_rad_s
        )
    if msgid == ap.LOCAL_POSITION_NED:
        return m.MAVLink_local_position_ned_message(
            boot_ms, est.north_m, est.east_m, est.down_m, est.vn_m_s, est.ve_m_s, est.vd_m_s
        )
    if msgid == ap.GLOBAL_POSITION_INT:
        lat, lon, alt = a._geo(est)
        origin_alt_mm = round(a.origin.alt_m * _MS) if a.origin else 0
        hdg = round(math.degrees(est.yaw_rad) % 360.0 * _CM) % 36000
        return m.MAVLink_global_position_int_message(
            boot_ms,
            lat,
            lon,
            alt,
            alt - origin_alt_mm,
            round(est.vn_m_s * _CM),
            round(est.ve_m_s * _CM),
            round(est.vd_m_s * _CM),
            hdg,
        )
    return None


def _sim_state(a: Autopilot, t_s: float) -> Any:
    p = a.drive.pose_at(t_s)
    q = _quat(p.roll_rad, p.pitch_rad, p.yaw_rad)
    lat_i, lon_i, alt_mm = a._geo(p)
    return a.m.MAVLink_sim_state_message(
        *q,
        p.roll_rad,
        p.pitch_rad,
        p.yaw_rad,
        0.0,
        0.0,
        -9.81,
        0.0,
        0.0,
        p.yaw_rate_rad_s,
        lat_i / 1e7,
        lon_i / 1e7,
        alt_mm / _MS,
        0.0,
        0.0,
        p.vn_m_s,
        p.ve_m_s,
        p.vd_m_s,
        lat_i,
        lon_i,
    )


def _home(a: Autopilot, t_s: float) -> Any:
    o = a.origin
    if o is None:
        return None
    start = a.trajectory.pose_at(0.0)
    lat, lon, alt = a._geo(start)
    return a.m.MAVLink_home_position_message(
        lat,
        lon,
        alt,
        start.north_m,
        start.east_m,
        start.down_m,
        list(_quat(0.0, 0.0, start.yaw_rad)),
        0.0,
        0.0,
        0.0,
        usec_from_unix_s(a.unix_of(t_s)),
    )


def _ack(a: Autopilot, li: int, msg: Any, command: int, result: int) -> Out:
    ack = a.m.MAVLink_command_ack_message(
        command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
    )
    return [(li, ack.pack(a.links[li].mav))]


def process(a: Autopilot, li: int, msg: Any, t_s: float) -> Out:
    """Act on a message addressed to the autopilot (or broadcast)."""
    kind = msg.get_type()
    link = a.links[li]
    if kind == "COMMAND_LONG":
        a.counters.commands += 1
        return _command(a, li, msg, t_s)
    if kind == "REQUEST_DATA_STREAM":
        ids = (
            tuple(ap.STREAMABLE - {ap.HEARTBEAT, ap.GPS_GLOBAL_ORIGIN, ap.HOME_POSITION})
            if msg.req_stream_id == 0
            else ap.DATA_STREAMS.get(msg.req_stream_id, ())
        )
        on = msg.start_stop != 0 and msg.req_message_rate > 0
        for msgid in ids:
            a._set_interval(link, msgid, 1.0 / msg.req_message_rate if on else 0.0, t_s)
        return []
    if kind == "TIMESYNC" and msg.tc1 == 0:
        now_ns = int(a.boot_s(t_s) * 1e9)
        reply = a.m.MAVLink_timesync_message(now_ns, msg.ts1)
        return [(li, reply.pack(link.mav))]
    if kind == "SET_MODE":
        result = _set_mode(a, msg.custom_mode, t_s)
        return _ack(a, li, msg, ap.MSG_SET_MODE, result)
    if kind == "MISSION_SET_CURRENT":
        if a.drive.set_current(msg.seq, t_s):
            return [(li, build(a, ap.MISSION_CURRENT, t_s).pack(link.mav))]
        return []
    if kind == "SET_POSITION_TARGET_LOCAL_NED":
        _position_target(a, msg, t_s)
        return []
    if kind == "SET_GPS_GLOBAL_ORIGIN":
        try:
            a.origin = GlobalOrigin(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / _MS)
        except ValueError:
            return []
        for other in a.links:
            other.pending_once |= {ap.GPS_GLOBAL_ORIGIN, ap.HOME_POSITION}
        return []
    return []


def _command(a: Autopilot, li: int, msg: Any, t_s: float) -> Out:
    cmd = msg.command
    link = a.links[li]
    if cmd == ap.MAV_CMD_SET_MESSAGE_INTERVAL:
        msgid, interval_us = int(msg.param1), msg.param2
        if msgid not in ap.STREAMABLE:
            return _ack(a, li, msg, cmd, ap.MAV_RESULT_DENIED)
        if interval_us < 0:
            interval_s = 0.0
        elif interval_us == 0:
            rate = a.default_rates_hz.get(msgid, 0.0)
            interval_s = 1.0 / rate if rate > 0 else 0.0
        else:
            interval_s = interval_us / 1e6
        a._set_interval(link, msgid, interval_s, t_s)
        return _ack(a, li, msg, cmd, ap.MAV_RESULT_ACCEPTED)
    if cmd in (ap.MAV_CMD_REQUEST_MESSAGE, ap.MAV_CMD_GET_HOME_POSITION):
        msgid = ap.HOME_POSITION if cmd == ap.MAV_CMD_GET_HOME_POSITION else int(msg.param1)
        if msgid not in ap.STREAMABLE or build(a, msgid, t_s) is None:
            return _ack(a, li, msg, cmd, ap.MAV_RESULT_DENIED)
        out = _ack(a, li, msg, cmd, ap.MAV_RESULT_ACCEPTED)
        return [*out, (li, build(a, msgid, t_s).pack(link.mav))]
    if cmd == ap.MAV_CMD_DO_SET_MODE:
        return _ack(a, li, msg, cmd, _set_mode(a, int(msg.param2), t_s))
    if cmd == ap.MAV_CMD_DO_SET_MISSION_CURRENT:
        ok = a.drive.set_current(int(msg.param1), t_s)
        return _ack(a, li, msg, cmd, ap.MAV_RESULT_ACCEPTED if ok else ap.MAV_RESULT_FAILED)
    if cmd == ap.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN and int(msg.param1) == 1:
        out = _ack(a, li, msg, cmd, ap.MAV_RESULT_ACCEPTED)
        a.reboot(t_s)
        return out
    return _ack(a, li, msg, cmd, ap.MAV_RESULT_UNSUPPORTED)


def _set_mode(a: Autopilot, mode: int, t_s: float) -> int:
    if mode not in drive.MODES:
        return ap.MAV_RESULT_FAILED  # a mode the simulator does not drive (RTL, ...)
    a.set_mode(mode, t_s)
    return ap.MAV_RESULT_ACCEPTED


_POS_IGNORE = 1 | 2 | 4  # POSITION_TARGET_TYPEMASK_X/Y/Z_IGNORE
_YAW_IGNORE = 1024  # POSITION_TARGET_TYPEMASK_YAW_IGNORE
_MAV_FRAME_LOCAL_NED = 1


def _position_target(a: Autopilot, msg: Any, t_s: float) -> None:
    """Rover in GUIDED: drive to (x, y) north/east, or turn to the yaw; ArduPilot
    sends no COMMAND_ACK for it (the companion sees the rover move)."""
    if msg.coordinate_frame != _MAV_FRAME_LOCAL_NED:
        return
    target = None
    if not msg.type_mask & _POS_IGNORE:
        if not (math.isfinite(msg.x) and math.isfinite(msg.y)):
            return
        target = (float(msg.x), float(msg.y))
    yaw = None
    if not msg.type_mask & _YAW_IGNORE and math.isfinite(msg.yaw):
        yaw = float(msg.yaw)
    a.drive.guided_target(t_s, target, yaw)
