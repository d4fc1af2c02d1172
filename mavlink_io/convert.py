"""The one place where MAVLink's scaled integers become SI units and back.

    degE7 (int32 degrees x 1e7)  <-> lat_deg / lon_deg
    mm (int32)                   <-> alt_m
    ms (time_boot_ms)            <-> t_boot_s
    us (Unix epoch)              <-> *_unix_s
    cm/s (GLOBAL_POSITION_INT)   <-> m/s

Nothing outside mavlink_io reads a MAVLink field. A latitude/longitude of exactly
0/0 is ArduPilot's "no position/origin yet" and never becomes a GlobalOrigin.

The autopilot's messages are validated here, once, as they become typed values:
``attitude``, ``local_position``, ``global_position`` and the ``parse_*`` origin
functions raise ``BadField`` (a ValueError naming the message, field and value) for
a value that is not finite or outside what a rover can report; the caller counts
and logs it and uses nothing from that message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from fusion.geodesy import ned_to_geodetic
from fusion.types import MAX_LOCAL_M, Cue, GlobalOrigin, TrackState, Urgency, VictimReport
from mavlink_io import dialect
from mavlink_io.errors import MavlinkIOError

MavMessage = Any

DEG_E7 = 1e7
MM_PER_M = 1000.0
US_PER_S = 1_000_000
MS_PER_S = 1000.0
CM_PER_M = 100.0

FLAG_GLOBAL_VALID = 1  # RESCUE_REPORT_FLAGS_GLOBAL_VALID
FLAG_NEW = 2
FLAG_URGENCY_CHANGED = 4
FLAG_MOVED = 8
FLAG_REQUESTED = 16

# What an autopilot on the ground can report; beyond is a corrupt or forged message.
MAX_ANGLE_RAD = 2.0 * math.pi
MAX_SPEED_M_S = 500.0
ALT_RANGE_M = (-1000.0, 20_000.0)  # AMSL: below the Dead Sea to above any mountain


class BadField(MavlinkIOError, ValueError):
    """A field of an autopilot message is not finite or out of range."""


def _check(msg_type: str, name: str, value: float, low: float, high: float) -> None:
    if not (math.isfinite(value) and low <= value <= high):
        raise BadField(f"{msg_type}.{name} = {value!r}: outside [{low:g}, {high:g}]")


def deg_from_e7(value: int) -> float:
    return value / DEG_E7


def e7_from_deg(value_deg: float) -> int:
    return round(value_deg * DEG_E7)


def usec_from_unix_s(t_unix_s: float) -> int:
    return max(0, round(t_unix_s * US_PER_S))


@dataclass(frozen=True)
class AttitudeFields:
    t_boot_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float


@dataclass(frozen=True)
class LocalPositionFields:
    t_boot_s: float
    north_m: float
    east_m: float
    down_m: float
    vn_m_s: float
    ve_m_s: float
    vd_m_s: float


@dataclass(frozen=True)
class GlobalPositionFields:
    t_boot_s: float
    lat_deg: float
    lon_deg: float
    alt_m: float  # AMSL
    relative_alt_m: float
    vn_m_s: float
    ve_m_s: float
    vd_m_s: float


def attitude(msg: MavMessage) -> AttitudeFields:
    """ATTITUDE in SI units; BadField for an angle that is not finite or beyond 2 pi."""
    values = (msg.roll, msg.pitch, msg.yaw)
    for name, value in zip(("roll", "pitch", "yaw"), values, strict=True):
        _check("ATTITUDE", name, value, -MAX_ANGLE_RAD, MAX_ANGLE_RAD)
    return AttitudeFields(msg.time_boot_ms / MS_PER_S, *values)


def local_position(msg: MavMessage) -> LocalPositionFields:
    """LOCAL_POSITION_NED in SI units; BadField for an absurd position or velocity."""
    values = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
    for name, value in zip(("x", "y", "z"), values[:3], strict=True):
        _check("LOCAL_POSITION_NED", name, value, -MAX_LOCAL_M, MAX_LOCAL_M)
    for name, value in zip(("vx", "vy", "vz"), values[3:], strict=True):
        _check("LOCAL_POSITION_NED", name, value, -MAX_SPEED_M_S, MAX_SPEED_M_S)
    return LocalPositionFields(msg.time_boot_ms / MS_PER_S, *values)


def global_position(msg: MavMessage) -> GlobalPositionFields | None:
    """GLOBAL_POSITION_INT in SI units; None when it is 0/0 (no position yet),
    BadField for a latitude, longitude or altitude out of range."""
    if msg.lat == 0 and msg.lon == 0:
        return None
    lat_deg, lon_deg, alt_m = _lat_lon_alt("GLOBAL_POSITION_INT", msg.lat, msg.lon, msg.alt)
    return GlobalPositionFields(
        t_boot_s=msg.time_boot_ms / MS_PER_S,
        lat_deg=lat_deg,
        lon_deg=lon_deg,
        alt_m=alt_m,
        relative_alt_m=msg.relative_alt / MM_PER_M,
        vn_m_s=msg.vx / CM_PER_M,
        ve_m_s=msg.vy / CM_PER_M,
        vd_m_s=msg.vz / CM_PER_M,
    )


def _lat_lon_alt(
    msg_type: str, lat_e7: int, lon_e7: int, alt_mm: int
) -> tuple[float, float, float]:
    lat_deg, lon_deg, alt_m = deg_from_e7(lat_e7), deg_from_e7(lon_e7), alt_mm / MM_PER_M
    _check(msg_type, "latitude_deg", lat_deg, -90.0, 90.0)
    _check(msg_type, "longitude_deg", lon_deg, -180.0, 180.0)
    _check(msg_type, "altitude_m", alt_m, *ALT_RANGE_M)
    return lat_deg, lon_deg, alt_m


def _origin(msg_type: str, lat_e7: int, lon_e7: int, alt_mm: int) -> GlobalOrigin | None:
    if lat_e7 == 0 and lon_e7 == 0:
        return None
    return GlobalOrigin(*_lat_lon_alt(msg_type, lat_e7, lon_e7, alt_mm))


def parse_gps_global_origin(msg: MavMessage) -> GlobalOrigin | None:
    """GPS_GLOBAL_ORIGIN (the EKF origin itself); None for 0/0, BadField when out of range."""
    return _origin("GPS_GLOBAL_ORIGIN", msg.latitude, msg.longitude, msg.altitude)


def parse_home_position(msg: MavMessage) -> GlobalOrigin | None:
    """The EKF origin implied by HOME_POSITION: home's lat/lon/alt minus its local
    x, y, z. None for 0/0, BadField when out of range."""
    home = _origin("HOME_POSITION", msg.latitude, msg.longitude, msg.altitude)
    if home is None:
        return None
    for name in ("x", "y", "z"):
        _check("HOME_POSITION", name, getattr(msg, name), -MAX_LOCAL_M, MAX_LOCAL_M)
    return _shift("HOME_POSITION", home, -msg.x, -msg.y, -msg.z)


def origin_from_gps_global_origin(msg: MavMessage) -> GlobalOrigin | None:
    """parse_gps_global_origin, with None for anything invalid too."""
    try:
        return parse_gps_global_origin(msg)
    except BadField:
        return None


def origin_from_home_position(msg: MavMessage) -> GlobalOrigin | None:
    """parse_home_position, with None for anything invalid too."""
    try:
        return parse_home_position(msg)
    except BadField:
        return None


def origin_from_global_and_local(
    glob: GlobalPositionFields, local: LocalPositionFields
) -> GlobalOrigin | None:
    """The EKF origin implied by the vehicle's global and local position at one
    instant (both already validated); BadField if it lands out of range."""
    at = GlobalOrigin(glob.lat_deg, glob.lon_deg, glob.alt_m)
    return _shift("GLOBAL_POSITION_INT", at, -local.north_m, -local.east_m, -local.down_m)


def _shift(
    msg_type: str, at: GlobalOrigin, north_m: float, east_m: float, down_m: float
) -> GlobalOrigin:
    lat_deg, lon_deg, alt_m = ned_to_geodetic(at, north_m, east_m, down_m)
    _check(msg_type, "derived origin lat", lat_deg, -90.0, 90.0)
    _check(msg_type, "derived origin lon", lon_deg, -180.0, 180.0)
    _check(msg_type, "derived origin alt", alt_m, *ALT_RANGE_M)
    try:
        return GlobalOrigin(lat_deg, lon_deg, alt_m)
    except ValueError as exc:  # exactly 0/0
        raise BadField(f"{msg_type}: {exc}") from None


def _module(module: ModuleType | None) -> ModuleType:
    return module if module is not None else dialect.load()


def victim_report_to_msg(
    report: VictimReport,
    report_seq: int,
    flags: int,
    time_unix_s: float,
    merged_into: int | None,
    module: ModuleType | None = None,
) -> MavMessage:
    """RESCUE_VICTIM_REPORT for a VictimReport. GLOBAL_VALID follows report.has_global."""
    m = _module(module)
    flags = (flags | FLAG_GLOBAL_VALID) if report.has_global else (flags & ~FLAG_GLOBAL_VALID)
    (cov_nn, cov_ne), (_, cov_ee) = report.cov_ne_m2
    lat = lon = alt = 0
    if report.lat_deg is not None and report.lon_deg is not None and report.alt_m is not None:
        lat, lon = e7_from_deg(report.lat_deg), e7_from_deg(report.lon_deg)
        alt = round(report.alt_m * MM_PER_M)
    return m.MAVLink_rescue_victim_report_message(
        time_usec=usec_from_unix_s(time_unix_s),
        first_seen_usec=usec_from_unix_s(report.first_seen_unix_s),
        last_seen_usec=usec_from_unix_s(report.last_seen_unix_s),
        report_seq=report_seq,
        victim_id=report.victim_id,
        merged_into_id=merged_into or 0,
        robot_sysid=report.robot_sysid,
        state=int(report.state),
        urgency=int(report.urgency),
        flags=flags & 0xFF,
        visibility=report.visibility_pct,
        north=report.north_m,
        east=report.east_m,
        down=report.down_m,
        cov_nn=cov_nn,
        cov_ne=cov_ne,
        cov_ee=cov_ee,
        lat=lat,
        lon=lon,
        alt=alt,
        observations=min(report.observations, 0xFFFF),
        cues=int(report.cues) & 0xFF,
    )


def msg_to_victim_report(msg: MavMessage) -> VictimReport:
    """VictimReport from RESCUE_VICTIM_REPORT; ValueError naming the bad field.

    ``cues`` is taken as sent (0 from a robot older than the field: not known); bits
    no Cue names are the receiver's to refuse or mask (hq.wire does)."""
    try:
        state = TrackState(msg.state)
        urgency = Urgency(msg.urgency)
    except ValueError as exc:
        raise ValueError(f"RESCUE_VICTIM_REPORT victim {msg.victim_id}: {exc}") from None
    has_global = bool(msg.flags & FLAG_GLOBAL_VALID)
    try:
        return VictimReport(
            victim_id=msg.victim_id,
            robot_sysid=msg.robot_sysid,
            state=state,
            urgency=urgency,
            visibility_pct=msg.visibility,
            north_m=msg.north,
            east_m=msg.east,
            down_m=msg.down,
            cov_ne_m2=((msg.cov_nn, msg.cov_ne), (msg.cov_ne, msg.cov_ee)),
            observations=msg.observations,
            first_seen_unix_s=msg.first_seen_usec / US_PER_S,
            last_seen_unix_s=msg.last_seen_usec / US_PER_S,
            lat_deg=deg_from_e7(msg.lat) if has_global else None,
            lon_deg=deg_from_e7(msg.lon) if has_global else None,
            alt_m=msg.alt / MM_PER_M if has_global else None,
            cues=Cue(int(msg.cues)),
        )
    except ValueError as exc:
        raise ValueError(f"RESCUE_VICTIM_REPORT victim {msg.victim_id}: {exc}") from None
