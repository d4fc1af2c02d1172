"""What people hear, and how often: the rate limit and the robot's own conditions.

``Announcer`` is what the threads call (the processing, camera and reporter threads
all announce, the reporter sends): it words a line, queues it and wakes the
reporter. ``Announcements`` and ``Conditions`` under it are pure logic on a
caller-given monotonic time. All three are thread-safe.

``Announcements`` is a token bucket over STATUSTEXT announcements: ``burst`` go out
at once, then one every ``interval_s``; the rest wait in order. It keeps the radio
free and the operator's speech queue short. When more than ``max_waiting`` wait,
the oldest quiet (unspoken) one is dropped first, then the oldest of all, and the
drop is logged: the HQ still has every report.

``Conditions`` turns the robot's health (camera, HQ link, disk) into one
announcement per change: "camera lost" when it goes, "camera back" when it
returns, never repeated while the state holds. A condition that flaps is
announced at most once per ``hold_s``: the state it settles in is told when the
hold is over, and nothing when it settled back where it was announced.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from companion.reporting.policy import Decision
from fusion.types import VictimReport
from mavlink_io import statustext

log = logging.getLogger(__name__)

BURST = 3
INTERVAL_S = 2.0
MAX_WAITING = 20
HOLD_S = 10.0
# What people are told when a health condition changes: (text, MAV_SEVERITY) when it
# goes bad, when it is fine again. Severity 5 (NOTICE) or more urgent: QGC speaks it.
CONDITION_WORDS = {
    "camera": (("camera lost", 3), ("camera back", 5)),
    "thermal camera": (("thermal camera lost", 3), ("thermal camera back", 5)),
    "hq": (("HQ link lost", 4), ("HQ link back", 5)),
    "disk": (("disk full", 4), ("disk space free again", 5)),
}


@dataclass(frozen=True)
class Announcement:
    text: str
    severity: int  # MAV_SEVERITY
    spoken: bool  # QGC speaks it (severity NOTICE or more urgent)


class Announcements:
    def __init__(
        self, burst: int = BURST, interval_s: float = INTERVAL_S, max_waiting: int = MAX_WAITING
    ) -> None:
        if burst < 1 or interval_s <= 0 or max_waiting < 1:
            raise ValueError("burst and max_waiting must be >= 1 and interval_s > 0")
        self.burst = burst
        self.interval_s = interval_s
        self.max_waiting = max_waiting
        self.dropped = 0
        self._lock = threading.Lock()
        self._waiting: deque[Announcement] = deque()
        self._tokens = float(burst)
        self._t_mono_s: float | None = None

    def put(self, announcement: Announcement) -> None:
        with self._lock:
            self._waiting.append(announcement)
            if len(self._waiting) > self.max_waiting:
                quiet = next((a for a in self._waiting if not a.spoken), None)
                drop = quiet if quiet is not None else self._waiting[0]
                self._waiting.remove(drop)
                self.dropped += 1
                log.warning("announcements: too many waiting; dropped %r", drop.text)

    def take(self, now_mono_s: float) -> list[Announcement]:
        """The announcements due now, in order."""
        with self._lock:
            self._refill(now_mono_s)
            out = []
            while self._waiting and self._tokens >= 1.0:
                out.append(self._waiting.popleft())
                self._tokens -= 1.0
            return out

    def seconds_until_due(self, now_mono_s: float) -> float | None:
        """None when nothing waits."""
        with self._lock:
            if not self._waiting:
                return None
            self._refill(now_mono_s)
            return max(0.0, (1.0 - self._tokens) * self.interval_s)

    def _refill(self, now_mono_s: float) -> None:
        if self._t_mono_s is not None:
            gained = max(0.0, now_mono_s - self._t_mono_s) / self.interval_s
            self._tokens = min(float(self.burst), self._tokens + gained)
        self._t_mono_s = now_mono_s


@dataclass
class _Condition:
    told_ok: bool = True  # the state last announced (a condition starts fine, unannounced)
    told_mono_s: float = float("-inf")
    ok: bool = True


class Conditions:
    """Health conditions by name; ``update`` returns the changes to announce."""

    def __init__(self, hold_s: float = HOLD_S) -> None:
        self.hold_s = hold_s
        self._lock = threading.Lock()
        self._conditions: dict[str, _Condition] = {}

    def update(self, name: str, ok: bool, now_mono_s: float) -> list[tuple[str, bool]]:
        """Set ``name``'s state; the (name, ok) changes due for announcement now
        (this condition's, and any other whose hold just ended)."""
        with self._lock:
            self._conditions.setdefault(name, _Condition()).ok = ok
            return self._due(now_mono_s)

    def due(self, now_mono_s: float) -> list[tuple[str, bool]]:
        with self._lock:
            return self._due(now_mono_s)

    def _due(self, now_mono_s: float) -> list[tuple[str, bool]]:
        out = []
        for name, c in self._conditions.items():
            if c.ok != c.told_ok and now_mono_s - c.told_mono_s >= self.hold_s:
                c.told_ok, c.told_mono_s = c.ok, now_mono_s
                out.append((name, c.ok))
        return out


class Announcer:
    """Lines for people, worded and queued for the reporter, which sends them as
    STATUSTEXT (``take``) and is woken by ``wake`` when one is queued.

    ``enabled`` is ``[reporting] statustext`` (off: lines are only logged);
    ``announce_severity`` is a setting the processing thread changes
    (``RC_ANN_SEV``); ``robot_sysid`` names this robot in its lines.
    """

    def __init__(
        self,
        *,
        enabled: bool,
        announce_severity: int,
        robot_sysid: Callable[[], int],
        wake: threading.Event,
    ) -> None:
        self.enabled = enabled
        self.announce_severity = announce_severity
        self._robot_sysid = robot_sysid
        self._wake = wake
        self.waiting = Announcements()
        self.conditions = Conditions()
        self._hq_numbers: dict[int, int] = {}  # robot's victim ID -> the HQ's number
        self._numbers_lock = threading.Lock()

    def hq_number(self, victim_id: int, hq_id: int) -> None:
        """The HQ's number for this robot's victim (its acknowledgement said it): the
        lines about that victim use it from now on (``CRIT07``, as QGC's map label)."""
        with self._numbers_lock:
            if self._hq_numbers.get(victim_id) != hq_id:
                log.info("victim %d is the HQ's %d", victim_id, hq_id)
            self._hq_numbers[victim_id] = hq_id

    def announce(self, text: str, severity: int) -> None:
        """A status line for people, naming this robot (QGC shows it; NOTICE and
        more urgent are spoken)."""
        self._put(f"{statustext.robot_label(self._robot_sysid())} {text}", severity)

    def victim(self, d: Decision, report: VictimReport) -> None:
        """A victim's line, when its decision says people hear of it."""
        if d.announce:
            with self._numbers_lock:
                hq_id = self._hq_numbers.get(report.victim_id)
            text = statustext.victim_text(report, hq_id)
            severity = statustext.victim_severity(report, d.spoken, self.announce_severity)
            self._put(text, severity)

    def condition(self, name: str, ok: bool, now_mono_s: float) -> None:
        """A health condition's state; its changes are announced once each."""
        self._announce_changes(self.conditions.update(name, ok, now_mono_s))

    def settle(self, now_mono_s: float) -> None:
        """Announce the conditions whose flapping settled (their hold ended)."""
        self._announce_changes(self.conditions.due(now_mono_s))

    def take(self, now_mono_s: float) -> list[Announcement]:
        """The lines the rate limit lets out now, in order (the reporter sends them)."""
        return self.waiting.take(now_mono_s)

    def seconds_until_due(self, now_mono_s: float) -> float | None:
        return self.waiting.seconds_until_due(now_mono_s)

    def _announce_changes(self, changes: list[tuple[str, bool]]) -> None:
        for name, ok in changes:
            text, severity = CONDITION_WORDS[name][ok]
            self.announce(text, severity)

    def _put(self, text: str, severity: int) -> None:
        log.info("announce: %s", text)
        if not self.enabled:
            return
        spoken = severity <= statustext.MAV_SEVERITY_NOTICE
        self.waiting.put(Announcement(text, severity, spoken))
        self._wake.set()
