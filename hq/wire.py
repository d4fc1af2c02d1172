"""The HQ's adapter over mavlink_io's conversions and TUNNEL envelope.

mavlink_io.convert owns every scaled-integer conversion (degE7, mm, us) and
mavlink_io.tunnel the TUNNEL envelope (payload_type 32800: one whole MAVLink 2
frame, signed when signing is on). This module only gives them the shapes the HQ
uses: a typed ``BadReport`` for reports that do not validate, and a TUNNEL
addressed to one robot's component.
"""

from __future__ import annotations

from typing import Any

from fusion.types import GlobalOrigin, VictimReport
from mavlink_io import convert, tunnel
from mavlink_io.codec import Codec

MavMessage = Any


class BadReport(ValueError):
    """A RESCUE_VICTIM_REPORT whose fields do not make a VictimReport."""


def report_from_msg(msg: MavMessage) -> VictimReport:
    """The VictimReport (SI units) in a RESCUE_VICTIM_REPORT; BadReport when invalid."""
    try:
        return convert.msg_to_victim_report(msg)
    except ValueError as exc:
        raise BadReport(str(exc)) from None


def report_to_msg(
    codec: Codec, report: VictimReport, report_seq: int, report_time_unix_s: float, flags: int = 0
) -> MavMessage:
    """A RESCUE_VICTIM_REPORT for a VictimReport (used by the simulated robots)."""
    return convert.victim_report_to_msg(
        report, report_seq, flags, report_time_unix_s, None, codec.module
    )


def origin_from_msg(msg: MavMessage) -> GlobalOrigin | None:
    """The EKF origin in a GPS_GLOBAL_ORIGIN (None for ArduPilot's 0/0 'no origin')."""
    return convert.origin_from_gps_global_origin(msg)


def wrap_tunnel(
    codec: Codec, inner: MavMessage, target_system: int, target_component: int
) -> MavMessage:
    """A TUNNEL carrying ``inner`` (encoded, and signed, by ``codec``) to the target."""
    return tunnel.pack_tunnel(codec.encode(inner), target_system, target_component, codec.module)


def unwrap_tunnel(codec: Codec, msg: MavMessage) -> MavMessage | None:
    """The dialect message inside one of our TUNNELs; None for foreign or broken payloads."""
    return tunnel.unpack_tunnel(msg, codec)
