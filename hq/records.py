"""The HQ's typed records and the one place their values are checked.

Records: a report as it arrives (IncomingReport) and as a victim's source holds it
(Source), an operator action and the robot's answer (Action: a decision about a
victim, a closer look at one, or closer looks off/on for a whole robot), a robot
(Robot, RobotStatus, with its closer looks' counts), and what storing a report did
(StoreResult).

Everything the HQ keeps about a victim or a robot passes ``check_report``,
``check_origin`` or ``RobotStatus`` twice: once when it arrives on the radio
(hq.wire turns a MAVLink message into these values) and once when it is read back
from SQLite (a row written by an older rescue-hq, or damaged on disk). A value
that fails raises ``BadRecord`` naming the field and the value; the caller refuses
the message or skips the row with a log line and a counter, so no single value can
crash the HQ, now or at the next start.

Bounds beyond what VictimReport itself checks (finite numbers, positive-definite
covariance, ordered times), chosen so that every later computation (geodesy, the
merge's matrix inverse, ISO dates in the exports, SQLite's signed 64-bit integers)
is defined:

- wall times (``*_unix_s``, ``report_time_usec``): from 1970 to 2100-01-01;
- local NED positions: within ``MAX_LOCAL_M`` of the EKF origin;
- covariance: variances from ``MIN_VARIANCE_M2`` to ``MAX_VARIANCE_M2``;
- latitude/longitude (when given): on the globe and not exactly 0/0 (ArduPilot's
  "no position yet"); altitude within ``MIN_ALT_M``..``MAX_ALT_M``;
- cues: only the bits fusion.types.Cue names (0: not known, a robot that does not
  say); hq.wire masks others off as a report arrives, a stored one is refused;
- an evidence picture: a JPEG (start and end markers) of 1 to ``MAX_PICTURE_BYTES``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields
from enum import Enum
from typing import Any

from fusion.types import MAX_LOCAL_M, NO_CUES, Cue, GlobalOrigin, TrackState, Urgency, VictimReport
from hq.errors import HqError
from mavlink_io.picture import MAX_PICTURE_BYTES, BadChunk, check_jpeg

MAX_UNIX_S = 4_102_444_800.0  # 2100-01-01T00:00:00Z
MAX_REPORT_TIME_USEC = int(MAX_UNIX_S) * 1_000_000
MIN_VARIANCE_M2 = 1e-6  # 1 mm sigma
MAX_VARIANCE_M2 = 1e10  # 100 km sigma
MIN_ALT_M = -1_000.0  # below the Dead Sea shore, above any mine floor
MAX_ALT_M = 10_000.0
ALL_CUES = Cue.COLOUR_BODY | Cue.COLOUR_PART | Cue.WARM


ACK_RESULT_ACCEPTED = 0  # RESCUE_ACK_RESULT
ACK_RESULT_DUPLICATE = 1
ACK_RESULT_REJECTED = 2


class StoreResult(Enum):
    ACCEPTED = "accepted"  # new, stored, and the newest state of its victim
    STALE = "stale"  # new and stored, but older than what the victim already holds
    DUPLICATE = "duplicate"  # stored before


class OperatorAction(Enum):
    """Values match RESCUE_OPERATOR_ACTION_TYPE."""

    RESCUED = 1
    FALSE_ALARM = 2
    CONFIRMED = 4  # the operator saw the evidence: a real person (reopens a resolved one)
    LOOK_CLOSER = 5  # the robot's next closer look goes to this victim (docs/LOOKS.md)
    LOOKS_OFF = 6  # no more closer looks on this robot (victim_id 0: the whole robot)
    LOOKS_ON = 7  # closer looks allowed again on this robot (victim_id 0)

    @property
    def decides_state(self) -> bool:
        """A decision about the victim's state (what the HQ shows it as)."""
        return self in (
            OperatorAction.RESCUED,
            OperatorAction.FALSE_ALARM,
            OperatorAction.CONFIRMED,
        )

    @property
    def whole_robot(self) -> bool:
        """About the robot, not a victim: sent with victim_id 0."""
        return self in (OperatorAction.LOOKS_OFF, OperatorAction.LOOKS_ON)


@dataclass(frozen=True)
class IncomingReport:
    report: VictimReport
    report_seq: int
    report_time_usec: int
    merged_into_id: int
    src_compid: int
    received_unix_s: float


@dataclass(frozen=True)
class Action:
    action_seq: int
    robot_sysid: int
    victim_id: int
    action: OperatorAction
    created_unix_s: float
    sent_count: int
    acked_unix_s: float | None
    ack_result: int | None = None  # RESCUE_ACK_RESULT the robot answered with

    @property
    def rejected(self) -> bool:
        """The robot answered, and did not apply it (REJECTED, or a result we do not know)."""
        return self.ack_result is not None and self.ack_result not in (
            ACK_RESULT_ACCEPTED,
            ACK_RESULT_DUPLICATE,
        )


@dataclass(frozen=True)
class Source:
    hq_id: int
    report: VictimReport
    report_seq: int
    merged_into_id: int
    updated_unix_s: float


@dataclass(frozen=True)
class Robot:
    sysid: int
    compid: int
    first_heard_unix_s: float
    last_heard_unix_s: float
    status: RobotStatus | None
    status_unix_s: float | None
    origin: GlobalOrigin | None


class BadRecord(HqError, ValueError):
    """A value the HQ cannot use; the message names the field."""


def check_picture(jpeg: object) -> bytes:
    """A stored evidence picture: bytes of a JPEG, at most MAX_PICTURE_BYTES."""
    if not isinstance(jpeg, bytes):
        raise BadRecord(f"picture is {type(jpeg).__name__}, not bytes")
    if not 0 < len(jpeg) <= MAX_PICTURE_BYTES:
        raise BadRecord(f"picture of {len(jpeg)} bytes, not 1..{MAX_PICTURE_BYTES}")
    try:
        check_jpeg(jpeg)
    except BadChunk as exc:
        raise BadRecord(str(exc)) from None
    return jpeg


def _in(name: str, value: float, low: float, high: float) -> None:
    if not (math.isfinite(value) and low <= value <= high):
        raise BadRecord(f"{name} {value!r} is outside {low:g}..{high:g}")


def check_time(name: str, unix_s: float) -> None:
    _in(name, unix_s, 0.0, MAX_UNIX_S)


def check_report_time_usec(value: int) -> None:
    if not 0 <= value <= MAX_REPORT_TIME_USEC:
        raise BadRecord(f"time_usec {value} is outside 0..{MAX_REPORT_TIME_USEC} (year 2100)")


def check_origin(origin: GlobalOrigin) -> GlobalOrigin:
    """``origin`` itself when its altitude is plausible; BadRecord otherwise."""
    _in("origin altitude (m)", origin.alt_m, MIN_ALT_M, MAX_ALT_M)
    return origin


def known_cues(cues: int) -> Cue:
    """The cue bits the HQ knows (others dropped)."""
    return Cue(int(cues) & int(ALL_CUES))


def cue_words(cues: Cue) -> str:
    """How people read the cues: ``colour body · warm``; ``not known`` for none."""
    return " · ".join(n.replace("_", " ") for n in cues.names()) or "not known"


def check_report(r: VictimReport) -> VictimReport:
    """``r`` itself when every value is usable by the HQ; BadRecord naming the first that is not."""
    if not isinstance(r.cues, int) or isinstance(r.cues, bool) or r.cues != known_cues(r.cues):
        raise BadRecord(f"cues {r.cues!r} is not a bitmask of {int(ALL_CUES)} (RESCUE_CUE)")
    check_time("first_seen (Unix s)", r.first_seen_unix_s)
    check_time("last_seen (Unix s)", r.last_seen_unix_s)
    for name, value in (("north_m", r.north_m), ("east_m", r.east_m), ("down_m", r.down_m)):
        _in(name, value, -MAX_LOCAL_M, MAX_LOCAL_M)
    (nn, ne), (_, ee) = r.cov_ne_m2
    _in("cov_nn (m²)", nn, MIN_VARIANCE_M2, MAX_VARIANCE_M2)
    _in("cov_ee (m²)", ee, MIN_VARIANCE_M2, MAX_VARIANCE_M2)
    if not ne * ne < nn * ee * (1.0 - 1e-9):
        raise BadRecord(f"covariance {r.cov_ne_m2} is not positive definite")
    if r.lat_deg is not None and r.lon_deg is not None and r.alt_m is not None:
        _in("lat_deg", r.lat_deg, -90.0, 90.0)
        _in("lon_deg", r.lon_deg, -180.0, 180.0)
        _in("alt_m", r.alt_m, MIN_ALT_M, MAX_ALT_M)
        if r.lat_deg == 0.0 and r.lon_deg == 0.0:
            raise BadRecord("lat/lon 0/0 flagged global (that is ArduPilot's 'no position yet')")
    return r


def report_payload(report: VictimReport) -> str:
    """The JSON stored for a report (read back by ``report_from_payload``)."""
    d = asdict(report)
    d["state"] = int(report.state)
    d["urgency"] = int(report.urgency)
    return json.dumps(d, allow_nan=False)


def report_from_payload(payload: str) -> VictimReport:
    """The checked VictimReport in a stored payload; BadRecord when it is not one."""
    try:
        d = json.loads(payload)
        d["state"] = TrackState(d["state"])
        d["urgency"] = Urgency(d["urgency"])
        (a, b), (c, e) = d["cov_ne_m2"]
        d["cov_ne_m2"] = ((a, b), (c, e))
        cues = d.get("cues", int(NO_CUES))  # a row from before the cues were kept: not known
        if not isinstance(cues, int) or isinstance(cues, bool) or not 0 <= cues <= ALL_CUES:
            raise TypeError(f"cues {cues!r} is not a bitmask of {int(ALL_CUES)} (RESCUE_CUE)")
        d["cues"] = Cue(cues)
        report = VictimReport(**d)
    except (ValueError, KeyError, TypeError) as exc:  # JSONDecodeError is a ValueError
        raise BadRecord(f"stored report: {exc}") from None
    return check_report(report)


STATUS_FLAG_LOOKS_ON = 128  # RESCUE_STATUS_FLAGS_LOOKS_ON
LOOK_COUNTS = (
    "looks_made",
    "looks_confirmed",
    "looks_rejected",
    "looks_urgency_changed",
    "looks_aborted",
)


@dataclass(frozen=True)
class RobotStatus:
    """A robot's last RESCUE_STATUS, checked: finite, non-negative numbers; the closer
    looks' counts (0 from a robot older than them) whole, and no more looks settled or
    aborted than were made."""

    uptime_s: float
    fps: float
    drop_pct: float
    vision_ms: float
    flags: int
    victims_confirmed: int
    victims_tentative: int
    outbox_pending: int
    looks_made: int = 0
    looks_confirmed: int = 0
    looks_rejected: int = 0
    looks_urgency_changed: int = 0
    looks_aborted: int = 0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and 0 <= value <= 1e9):
                raise BadRecord(f"RESCUE_STATUS {f.name} {value!r} is outside 0..1e9")
        for name in LOOK_COUNTS:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool):
                raise BadRecord(f"RESCUE_STATUS {name} {value!r} is not a whole number")
        ended = sum(getattr(self, name) for name in LOOK_COUNTS[1:])
        if ended > self.looks_made:
            raise BadRecord(
                f"RESCUE_STATUS looks: {ended} settled or aborted of {self.looks_made} made"
            )

    @property
    def looks_on(self) -> bool:
        return bool(self.flags & STATUS_FLAG_LOOKS_ON)

    def look_words(self) -> str:
        """How people read the closer looks: ``looks on: 3 made, 1 confirmed, 1 aborted``."""
        line = f"looks {'on' if self.looks_on else 'off'}"
        if not self.looks_made:
            return line
        counts = [
            (self.looks_confirmed, "confirmed"),
            (self.looks_rejected, "rejected"),
            (self.looks_urgency_changed, "urgency changed"),
            (self.looks_aborted, "aborted"),
        ]
        parts = [f"{self.looks_made} made"] + [f"{n} {word}" for n, word in counts if n]
        return f"{line}: {', '.join(parts)}"

    def to_json(self) -> str:
        return json.dumps(asdict(self), allow_nan=False)

    @classmethod
    def from_json(cls, text: str) -> RobotStatus:
        try:
            d: dict[str, Any] = json.loads(text)
            if not isinstance(d, dict):
                raise TypeError(f"{type(d).__name__}, not an object")
            looks = {name: d.get(name, 0) for name in LOOK_COUNTS}  # 0: stored before them
            return cls(
                uptime_s=float(d["uptime_s"]),
                fps=float(d["fps"]),
                drop_pct=float(d["drop_pct"]),
                vision_ms=float(d["vision_ms"]),
                flags=int(d["flags"]),
                victims_confirmed=int(d["victims_confirmed"]),
                victims_tentative=int(d["victims_tentative"]),
                outbox_pending=int(d["outbox_pending"]),
                **looks,
            )
        except (ValueError, KeyError, TypeError) as exc:
            raise BadRecord(f"stored status: {exc}") from None
