"""The HQ's view of the dialect messages: report conversion and the TUNNEL envelope.

STOPGAP: mavlink_io/convert.py and mavlink_io/tunnel.py (issue 4) own these
conversions; until they land, this module holds minimal private versions with the
same meaning, so that the scaled-integer conversions (degE7, mm, us) sit in one
place and can be swapped for mavlink_io's in one edit.

TUNNEL envelope: a whole MAVLink 2 frame of a dialect message (encoded, and signed
when signing is on, by the sender's codec) is the TUNNEL payload, ``payload_length``
its size, ``payload_type`` ``RESCUE_TUNNEL_PAYLOAD_TYPE`` (>= 32768: private).
"""

from __future__ import annotations

from typing import Any

from fusion.types import TrackState, Urgency, VictimReport
from mavlink_io.codec import Codec

RESCUE_TUNNEL_PAYLOAD_TYPE = 32768 + 43100 - 43000  # private range; 32868
_TUNNEL_PAYLOAD_BYTES = 128
_GLOBAL_VALID = 1  # RESCUE_REPORT_FLAGS_GLOBAL_VALID

MavMessage = Any


class BadReport(ValueError):
    """A RESCUE_VICTIM_REPORT whose fields do not make a VictimReport."""


def report_from_msg(msg: MavMessage) -> VictimReport:
    """The VictimReport (SI units) in a RESCUE_VICTIM_REPORT; BadReport when invalid."""
    try:
        has_global = bool(msg.flags & _GLOBAL_VALID)
        return VictimReport(
            victim_id=int(msg.victim_id),
            robot_sysid=int(msg.robot_sysid),
            state=TrackState(int(msg.state)),
            urgency=Urgency(int(msg.urgency)),
            visibility_pct=float(msg.visibility),
            north_m=float(msg.north),
            east_m=float(msg.east),
            down_m=float(msg.down),
            cov_ne_m2=(
                (float(msg.cov_nn), float(msg.cov_ne)),
                (float(msg.cov_ne), float(msg.cov_ee)),
            ),
            observations=int(msg.observations),
            first_seen_unix_s=msg.first_seen_usec * 1e-6,
            last_seen_unix_s=msg.last_seen_usec * 1e-6,
            lat_deg=msg.lat * 1e-7 if has_global else None,
            lon_deg=msg.lon * 1e-7 if has_global else None,
            alt_m=msg.alt * 1e-3 if has_global else None,
        )
    except ValueError as exc:  # TrackState/Urgency out of range, or VictimReport validation
        raise BadReport(str(exc)) from None


def report_time_unix_s(msg: MavMessage) -> float:
    """When the robot made this report (wall time)."""
    return float(msg.time_usec) * 1e-6


def report_to_msg(
    codec: Codec, report: VictimReport, report_seq: int, report_time_unix_s: float, flags: int = 0
) -> MavMessage:
    """A RESCUE_VICTIM_REPORT for a VictimReport (used by the simulated robots in tests)."""
    m = codec.module
    (cnn, cne), (_, cee) = report.cov_ne_m2
    if report.has_global:
        flags |= _GLOBAL_VALID
    return m.MAVLink_rescue_victim_report_message(
        time_usec=round(report_time_unix_s * 1e6),
        first_seen_usec=round(report.first_seen_unix_s * 1e6),
        last_seen_usec=round(report.last_seen_unix_s * 1e6),
        report_seq=report_seq,
        victim_id=report.victim_id,
        merged_into_id=0,
        robot_sysid=report.robot_sysid,
        state=int(report.state),
        urgency=int(report.urgency),
        flags=flags,
        visibility=report.visibility_pct,
        north=report.north_m,
        east=report.east_m,
        down=report.down_m,
        cov_nn=cnn,
        cov_ne=cne,
        cov_ee=cee,
        lat=round((report.lat_deg or 0.0) * 1e7),
        lon=round((report.lon_deg or 0.0) * 1e7),
        alt=round((report.alt_m or 0.0) * 1e3),
        observations=report.observations,
    )


def wrap_tunnel(
    codec: Codec, inner: MavMessage, target_system: int, target_component: int
) -> MavMessage:
    """A TUNNEL message carrying ``inner`` (encoded by ``codec``) to the target."""
    frame = codec.encode(inner)
    if len(frame) > _TUNNEL_PAYLOAD_BYTES:
        raise ValueError(f"{inner.get_type()} frame of {len(frame)} bytes does not fit a TUNNEL")
    payload = list(frame) + [0] * (_TUNNEL_PAYLOAD_BYTES - len(frame))
    return codec.module.MAVLink_tunnel_message(
        target_system, target_component, RESCUE_TUNNEL_PAYLOAD_TYPE, len(frame), payload
    )


def unwrap_tunnel(codec: Codec, tunnel: MavMessage) -> MavMessage | None:
    """The dialect message inside one of our TUNNELs; None for foreign or broken payloads."""
    if tunnel.payload_type != RESCUE_TUNNEL_PAYLOAD_TYPE:
        return None
    length = int(tunnel.payload_length)
    if not 0 < length <= _TUNNEL_PAYLOAD_BYTES:
        return None
    return codec.decode_frame(bytes(tunnel.payload[:length]))
