"""STATUSTEXT that a stock QGroundControl shows, pops up and speaks.

QGC shows severities 0-3 (EMERGENCY..ERROR) in red with a pop-up (from the active
vehicle), 4-5 (WARNING, NOTICE) in orange, and speaks NOTICE or more urgent.
Announcements of a new victim, and of a victim that became CRITICAL, are spoken:

    CRITICAL         -> MAV_SEVERITY_CRITICAL (2)   red, pop-up, spoken
    MEDIUM and LIGHT -> ``announce_severity`` ([reporting], default
                        MAV_SEVERITY_NOTICE (5): orange, spoken; 6 or 7: listed only)

Other news of a victim (an escalation to MEDIUM, rescued, false alarm, merged) is
quiet: MAV_SEVERITY_INFO (6), listed, not spoken.

An announcement says which robot, what, how urgent and where, in one 50-byte
chunk when it fits: ``R2 CRITICAL victim 7, 12.3 m N 4.5 m E of start`` (metres
from the local frame's origin, where the rover's EKF started). A victim only the
thermal camera has seen (under debris, in the dark: look closer, nothing may show)
says so: ``R2 CRITICAL victim 7, warm only, 12.3 m N 4.5 m E``, shortened to fit
(first without "of start", then without the spaces before the directions).

A STATUSTEXT holds 50 bytes of ASCII. Longer text goes out as MAVLink 2 chunks
sharing a non-zero ``id`` with ``chunk_seq`` 0, 1, ...; QGC (and MAVProxy) take a
chunk shorter than 50 bytes as the last one, so every chunk but the last is
exactly 50 bytes and the last is shorter. Text is split between words: a chunk
ends at a space and is padded with spaces to 50 bytes (QGC's message list shows
runs of spaces as one, and speech ignores them). A text that fits in 50 bytes is
one unchunked STATUSTEXT (id 0), never followed by an empty chunk (which QGC
would show as " ... ").
"""

from __future__ import annotations

import threading
from types import ModuleType

from fusion.types import Cue, TrackState, Urgency, VictimReport
from mavlink_io import dialect
from mavlink_io.codec import MavMessage

TEXT_BYTES = 50
MAV_SEVERITY_EMERGENCY = 0
MAV_SEVERITY_ALERT = 1
MAV_SEVERITY_CRITICAL = 2
MAV_SEVERITY_ERROR = 3
MAV_SEVERITY_WARNING = 4
MAV_SEVERITY_NOTICE = 5
MAV_SEVERITY_INFO = 6

_STATE_WORDS = {
    TrackState.RESCUED: "RESCUED",
    TrackState.FALSE_ALARM: "FALSE ALARM",
    TrackState.MERGED: "MERGED",
    TrackState.NOT_SEEN_RECENTLY: "not seen recently",
}


def _ascii(text: str) -> str:
    return text.encode("ascii", "replace").decode("ascii")


def robot_label(sysid: int) -> str:
    """How announcements name a robot: ``R2`` for system ID 2."""
    return f"R{sysid}"


def where_text(north_m: float, east_m: float) -> str:
    """``12.3 m N 4.5 m E of start`` (S and W for negative offsets)."""
    ns = "N" if north_m >= 0 else "S"
    ew = "E" if east_m >= 0 else "W"
    return f"{abs(north_m):.1f} m {ns} {abs(east_m):.1f} m {ew} of start"


def warm_only(cues: Cue) -> bool:
    """Only the thermal camera has seen it (no colour cue)."""
    return bool(cues & Cue.WARM) and not cues & (Cue.COLOUR_BODY | Cue.COLOUR_PART)


CALLSIGN_MAX = 8  # an ADS-B callsign holds 8 characters
URGENCY_LABEL = {Urgency.CRITICAL: "CRIT", Urgency.MEDIUM: "MED", Urgency.LIGHT: "LIGHT"}
RETIRED_LABEL = {TrackState.RESCUED: "RESC", TrackState.FALSE_ALARM: "FALSE"}


def callsign(label: str, hq_id: int) -> str:
    """The HQ's name for its victim ``hq_id`` (QGC's map label, the console card, the
    CLI): ``label`` + ID (two digits at least) within 8 characters (``CRIT07``); the
    label's first letter when the ID is too long for the whole word (``C123456``)."""
    text = f"{label}{hq_id:02d}"
    return text if len(text) <= CALLSIGN_MAX else f"{label[0]}{hq_id}"[:CALLSIGN_MAX]


def victim_name(report: VictimReport, hq_id: int | None) -> str:
    """How a line names a victim: the HQ's label (``CRIT07``: its urgency, or RESC /
    FALSE, and the HQ's number) once the HQ has said its number, else the robot's own
    number (``7``)."""
    if hq_id is None:
        return str(report.victim_id)
    return callsign(RETIRED_LABEL.get(report.state, URGENCY_LABEL[report.urgency]), hq_id)


def victim_text(report: VictimReport, hq_id: int | None = None) -> str:
    """``R2 CRITICAL victim 7, 12.3 m N 4.5 m E of start`` (``victim CRIT07`` once the
    HQ said its number, ``hq_id``); a state other than confirmed is said instead of the
    urgency (``R2 victim 7 RESCUED, ...``); a victim seen warm only says so, shortened
    to fit one chunk when it can."""
    robot = robot_label(report.robot_sysid)
    where = where_text(report.north_m, report.east_m)
    state = _STATE_WORDS.get(report.state)
    name = victim_name(report, hq_id)
    if state is not None:
        return f"{robot} victim {name} {state}, {where}"
    head = f"{robot} {report.urgency.name} victim {name}"
    if not warm_only(report.cues):
        return f"{head}, {where}"
    shorter = where.removesuffix(" of start")
    forms = [where, shorter, shorter.replace(" m ", "m ")]
    texts = [f"{head}, warm only, {w}" for w in forms]
    return next((t for t in texts if len(t) <= TEXT_BYTES), texts[1])


def split_text(data: bytes) -> list[bytes]:
    """``data`` as STATUSTEXT chunks: all but the last exactly 50 bytes, cut after a
    word and padded with spaces; the last shorter than 50 and never empty. A word of
    50 bytes or more is cut inside."""
    if len(data) <= TEXT_BYTES:
        return [data]
    chunks = []
    rest = data
    while len(rest) >= TEXT_BYTES:  # the last chunk must be shorter than 50
        space = rest.rfind(b" ", 1, TEXT_BYTES)  # a chunk keeps >= 1 byte of padding
        if space > 0:
            chunks.append(rest[:space].ljust(TEXT_BYTES))
            rest = rest[space + 1 :]
        elif len(rest) > TEXT_BYTES:
            chunks.append(rest[:TEXT_BYTES])
            rest = rest[TEXT_BYTES:]
        else:  # one 50-byte word left: a space inside it, rather than an empty chunk
            chunks.append(rest[: TEXT_BYTES - 1].ljust(TEXT_BYTES))
            rest = rest[TEXT_BYTES - 1 :]
    chunks.append(rest)
    return chunks


class ChunkIds:
    """Allocates STATUSTEXT chunk ids 1..65535 for one sender (0 means 'not chunked')."""

    def __init__(self) -> None:
        self._next = 1
        self._lock = threading.Lock()

    def next(self) -> int:
        with self._lock:
            value = self._next
            self._next = value % 0xFFFF + 1
            return value


def statustext_msgs(
    text: str,
    severity: int,
    chunk_ids: ChunkIds | None = None,
    module: ModuleType | None = None,
) -> list[MavMessage]:
    """STATUSTEXT message(s) for ``text``: one when it fits, else MAVLink 2 chunks."""
    if not MAV_SEVERITY_EMERGENCY <= severity <= 7:
        raise ValueError(f"severity must be a MAV_SEVERITY 0..7, got {severity}")
    m = module if module is not None else dialect.load()
    data = _ascii(text).encode("ascii")
    if len(data) <= TEXT_BYTES:
        return [m.MAVLink_statustext_message(severity, data, 0, 0)]
    chunks = split_text(data)
    if len(chunks) > 256:
        raise ValueError(f"text of {len(data)} bytes needs more than 256 chunks")
    ids = chunk_ids if chunk_ids is not None else ChunkIds()
    chunk_id = ids.next()
    return [
        m.MAVLink_statustext_message(severity, chunk, chunk_id, seq)
        for seq, chunk in enumerate(chunks)
    ]


def victim_severity(
    report: VictimReport, spoken: bool, announce_severity: int = MAV_SEVERITY_NOTICE
) -> int:
    """Spoken news: CRITICAL for a CRITICAL victim, else ``announce_severity``;
    other news INFO (listed, not spoken)."""
    if not spoken or report.state in _STATE_WORDS:
        return MAV_SEVERITY_INFO
    if report.urgency is Urgency.CRITICAL:
        return MAV_SEVERITY_CRITICAL
    return announce_severity
