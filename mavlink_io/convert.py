"""The one place where MAVLink's scaled integers become SI units and back.

    degE7 (int32 degrees x 1e7)  <-> lat_deg / lon_deg
    mm (int32)                   <-> alt_m
    ms (time_boot_ms)            <-> t_boot_s
    us (Unix epoch)              <-> *_unix_s
    cm/s (GLOBAL_POSITION_INT)   <-> m/s

Nothing outside mavlink_io reads a MAVLink field. A latitude/longitude of exactly
0/0 is ArduPilot's "no position/origin yet" and never becomes a GlobalOrigin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from fusion.geodesy import ned_to_geodetic
from fusion.types import GlobalOrigin, TrackState, Urgency, VictimReport
from mavlink_io import dialect

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


def attitude(msg: MavMessage) -> AttitudeFields | None:
    """ATTITUDE in SI units; None when a field is not finite."""
    values = (msg.roll, msg.pitch, msg.yaw)
    if not all(math.isfinite(v) for v in values):
        return None
    return AttitudeFields(msg.time_boot_ms / MS_PER_S, *values)


def local_position(msg: MavMessage) -> LocalPositionFields | None:
    """LOCAL_POSITION_NED in SI units; None when a field is not finite."""
    values = (msg.x, msg.y, msg.z, msg.vx, msg.vy, msg.vz)
    if not all(math.isfinite(v) for v in values):
        return None
    return LocalPositionFields(msg.time_boot_ms / MS_PER_S, *values)


def global_position(msg: MavMessage) -> GlobalPositionFields | None:
    """GLOBAL_POSITION_INT in SI units; None when it is 0/0 (no position yet)."""
    if msg.lat == 0 and msg.lon == 0:
        return None
    return GlobalPositionFields(
        t_boot_s=msg.time_boot_ms / MS_PER_S,
        lat_deg=deg_from_e7(msg.lat),
        lon_deg=deg_from_e7(msg.lon),
        alt_m=msg.alt / MM_PER_M,
        relative_alt_m=msg.relative_alt / MM_PER_M,
        vn_m_s=msg.vx / CM_PER_M,
        ve_m_s=msg.vy / CM_PER_M,
        vd_m_s=msg.vz / CM_PER_M,
    )


def _origin(lat_e7: int, lon_e7: int, alt_mm: int) -> GlobalOrigin | None:
    if lat_e7 == 0 and lon_e7 == 0:
        return None
    try:
        return GlobalOrigin(deg_from_e7(lat_e7), deg_from_e7(lon_e7), alt_mm / MM_PER_M)
    except ValueError:  # out of range: corrupt or bogus
        return None


def origin_from_gps_global_origin(msg: MavMessage) -> GlobalOrigin | None:
    """GPS_GLOBAL_ORIGIN (the EKF origin itself); None for 0/0."""
    return _origin(msg.latitude, msg.longitude, msg.altitude)


def origin_from_home_position(msg: MavMessage) -> GlobalOrigin | None:
    """The EKF origin implied by HOME_POSITION: home's lat/lon/alt minus its local x, y, z."""
    home = _origin(msg.latitude, msg.longitude, msg.altitude)
    if home is None or not all(math.isfinite(v) for v in (msg.x, msg.y, msg.z)):
        return None
    return _shift(home, -msg.x, -msg.y, -msg.z)


def origin_from_global_and_local(
    glob: GlobalPositionFields, local: LocalPositionFields
) -> GlobalOrigin | None:
    """The EKF origin implied by the vehicle's global and local position at one instant."""
    origin = _origin(e7_from_deg(glob.lat_deg), e7_from_deg(glob.lon_deg), round(glob.alt_m * 1e3))
    if origin is None:
        return None
    return _shift(origin, -local.north_m, -local.east_m, -local.down_m)


def _shift(at: GlobalOrigin, north_m: float, east_m: float, down_m: float) -> GlobalOrigin | None:
    lat_deg, lon_deg, alt_m = ned_to_geodetic(at, north_m, east_m, down_m)
    try:
        return GlobalOrigin(lat_deg, lon_deg, alt_m)
    except ValueError:
        return None


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
    )


def msg_to_victim_report(msg: MavMessage) -> VictimReport:
    """VictimReport from RESCUE_VICTIM_REPORT; ValueError naming the bad field."""
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
        )
    except ValueError as exc:
        raise ValueError(f"RESCUE_VICTIM_REPORT victim {msg.victim_id}: {exc}") from None
