"""STATUSTEXT that a stock QGroundControl shows, pops up and speaks.

QGC shows severities 0-3 (EMERGENCY..ERROR) in red with a pop-up, 4-5 (WARNING,
NOTICE) in orange, and speaks NOTICE or more urgent. Urgency maps to:

    CRITICAL -> MAV_SEVERITY_CRITICAL (2)   red, pop-up, spoken
    MEDIUM   -> MAV_SEVERITY_WARNING  (4)   orange, spoken
    LIGHT    -> MAV_SEVERITY_NOTICE   (5)   orange, spoken

A STATUSTEXT holds 50 bytes of ASCII. Longer text goes out as MAVLink 2 chunks
sharing a non-zero ``id`` with ``chunk_seq`` 0, 1, ...; the last chunk is shorter
than 50 bytes (an empty one is added when the text fills whole chunks), which is
how QGC and MAVProxy know the text is complete.
"""

from __future__ import annotations

import threading
from types import ModuleType

from fusion.types import TrackState, Urgency, VictimReport
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

SEVERITY_BY_URGENCY = {
    Urgency.CRITICAL: MAV_SEVERITY_CRITICAL,
    Urgency.MEDIUM: MAV_SEVERITY_WARNING,
    Urgency.LIGHT: MAV_SEVERITY_NOTICE,
}


def severity_for(urgency: Urgency) -> int:
    """The MAV_SEVERITY a victim of this urgency is announced with."""
    return SEVERITY_BY_URGENCY[urgency]


def _ascii(text: str) -> str:
    return text.encode("ascii", "replace").decode("ascii")


def victim_text(report: VictimReport) -> str:
    """A concise announcement within 50 characters, e.g.
    ``CRITICAL victim #3 at N12.3 E4.5 (8%)``.

    States other than CONFIRMED say so (``RESCUED victim #3``). Falls back to a
    compact form when large numbers would not fit.
    """
    pct = round(report.visibility_pct)
    name = report.urgency.name
    if report.state not in (TrackState.CONFIRMED, TrackState.TENTATIVE):
        name = report.state.name.replace("_", " ")
    where = f"N{report.north_m:.1f} E{report.east_m:.1f}"
    for text in (
        f"{name} victim #{report.victim_id} at {where} ({pct}%)",
        f"{name} #{report.victim_id} {where} {pct}%",
    ):
        if len(text) <= TEXT_BYTES:
            return text
    return f"{name} #{report.victim_id} {where}"[:TEXT_BYTES]


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
    ids = chunk_ids if chunk_ids is not None else ChunkIds()
    chunk_id = ids.next()
    chunks = [data[i : i + TEXT_BYTES] for i in range(0, len(data), TEXT_BYTES)]
    if len(chunks[-1]) == TEXT_BYTES:
        chunks.append(b"")  # a short last chunk tells the receiver the text is complete
    if len(chunks) > 256:
        raise ValueError(f"text of {len(data)} bytes needs more than 256 chunks")
    return [
        m.MAVLink_statustext_message(severity, chunk, chunk_id, seq)
        for seq, chunk in enumerate(chunks)
    ]


def victim_statustext(
    report: VictimReport, chunk_ids: ChunkIds | None = None, module: ModuleType | None = None
) -> list[MavMessage]:
    """The STATUSTEXT announcing a victim, with the severity of its urgency."""
    severity = severity_for(report.urgency)
    if report.state in (TrackState.RESCUED, TrackState.FALSE_ALARM, TrackState.MERGED):
        severity = MAV_SEVERITY_INFO  # news, not an alarm
    return statustext_msgs(victim_text(report), severity, chunk_ids, module)
