"""The HQ's adapter over mavlink_io's conversions and TUNNEL envelope.

mavlink_io.convert owns every scaled-integer conversion (degE7, mm, us) and
mavlink_io.tunnel the TUNNEL envelope (payload_type 32800: one whole MAVLink 2
frame, signed when signing is on). This module only gives them the shapes the HQ
uses: checked, typed values (hq.records) for what robots send, and a TUNNEL
addressed to one robot's component.

This is where a radio message becomes HQ values: every field is checked here once
(``BadMessage`` names the field), so the rest of the HQ never sees a value it cannot
store, merge, draw or export. The one exception is a report's ``cues``: bits no cue
names (a newer robot's sensing) are masked off with a line per robot and minute, not
refused, since the rest of the report is the victim's news.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from fusion.types import GlobalOrigin, VictimReport
from hq import records
from hq.errors import HqError
from hq.ratelog import RateLimitedLog
from hq.records import IncomingReport, RobotStatus
from mavlink_io import convert, tunnel
from mavlink_io.codec import Codec

MavMessage = Any
_UNKNOWN_CUES_LOG = RateLimitedLog(60.0)


class BadMessage(HqError, ValueError):
    """A message from a robot whose fields the HQ cannot use; the text names the field."""


def incoming_report(msg: MavMessage, received_unix_s: float) -> IncomingReport:
    """The checked report in a RESCUE_VICTIM_REPORT; BadMessage when a field is unusable."""
    try:
        records.check_report_time_usec(int(msg.time_usec))
        report = convert.msg_to_victim_report(msg)
        known = records.known_cues(report.cues)
        if known != report.cues:
            _UNKNOWN_CUES_LOG.say(
                ("cues", report.robot_sysid),
                f"robot {report.robot_sysid} victim {report.victim_id}: cues "
                f"{int(report.cues):#04x} has bits no cue names (a newer robot?); kept "
                f"{int(known):#04x} ({', '.join(known.names()) or 'none'})",
            )
            report = dataclasses.replace(report, cues=known)
        report = records.check_report(report)
    except ValueError as exc:  # BadRecord, or VictimReport's own checks
        raise BadMessage(f"victim {msg.victim_id}: {exc}") from None
    return IncomingReport(
        report=report,
        report_seq=int(msg.report_seq),
        report_time_usec=int(msg.time_usec),
        merged_into_id=int(msg.merged_into_id),
        src_compid=int(msg.get_srcComponent()),
        received_unix_s=received_unix_s,
    )


def status_from_msg(msg: MavMessage) -> RobotStatus:
    """The checked RESCUE_STATUS; BadMessage for NaN, infinite or negative values, or
    more closer looks settled or aborted than made. The look counts are extension
    fields: a robot older than them sends none, and they read 0."""
    try:
        return RobotStatus(
            uptime_s=float(msg.uptime_s),
            fps=float(msg.fps),
            drop_pct=float(msg.drop_pct),
            vision_ms=float(msg.vision_ms),
            flags=int(msg.flags),
            victims_confirmed=int(msg.victims_confirmed),
            victims_tentative=int(msg.victims_tentative),
            outbox_pending=int(msg.outbox_pending),
            **{name: int(getattr(msg, name, 0)) for name in records.LOOK_COUNTS},
        )
    except ValueError as exc:
        raise BadMessage(str(exc)) from None


def report_to_msg(
    codec: Codec, report: VictimReport, report_seq: int, report_time_unix_s: float, flags: int = 0
) -> MavMessage:
    """A RESCUE_VICTIM_REPORT for a VictimReport (used by the simulated robots)."""
    return convert.victim_report_to_msg(
        report, report_seq, flags, report_time_unix_s, None, codec.module
    )


def origin_from_msg(msg: MavMessage) -> GlobalOrigin | None:
    """The EKF origin in a GPS_GLOBAL_ORIGIN (None for ArduPilot's 0/0 'no origin').

    BadMessage when it is off the globe or its altitude is implausible.
    """
    try:
        origin = convert.parse_gps_global_origin(msg)  # None for 0/0
        return None if origin is None else records.check_origin(origin)
    except (convert.BadField, records.BadRecord) as exc:
        raise BadMessage(str(exc)) from None


def wrap_tunnel(
    codec: Codec, inner: MavMessage, target_system: int, target_component: int
) -> MavMessage:
    """A TUNNEL carrying ``inner`` (encoded, and signed, by ``codec``) to the target."""
    return tunnel.pack_tunnel(codec.encode(inner), target_system, target_component, codec.module)


def unwrap_tunnel(codec: Codec, msg: MavMessage) -> MavMessage | None:
    """The dialect message inside one of our TUNNELs; None for foreign or broken payloads."""
    return tunnel.unpack_tunnel(msg, codec)
