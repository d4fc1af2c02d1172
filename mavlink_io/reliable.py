"""Reliable delivery of dialect messages: resend until acknowledged, drop duplicates.

Sender side, ``Outbox``: a message with a sequence number (RESCUE_VICTIM_REPORT's
``report_seq``, RESCUE_OPERATOR_ACTION's ``action_seq``) is stored, sent at once,
and resent after ``initial_s``, then doubling up to ``max_s``, until a RESCUE_ACK
names the same (``acked_msgid``, ``seq``). Messages live in an ``OutboxStore``
(in memory here; the companion adds a durable one) as unsigned MAVLink 2 frames, so
a restart resends what was never acknowledged. Each resend is re-encoded by the
caller's codec: a fresh sequence number and signature timestamp, so signing's replay
protection does not reject it.

Receiver side, ``Deduplicator``: remembers (sysid, msgid, seq) keys it has seen (a
bounded, oldest-first memory) and tells the caller whether a message is a repeat;
the receiver acknowledges repeats too (the first ACK may have been lost) but acts
on a message once.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from mavlink_io.codec import Codec, MavMessage
from mavlink_io.dialect import RESCUE_OPERATOR_ACTION_ID, RESCUE_VICTIM_REPORT_ID

log = logging.getLogger(__name__)

SEQ_FIELD = {RESCUE_VICTIM_REPORT_ID: "report_seq", RESCUE_OPERATOR_ACTION_ID: "action_seq"}
"""The field that numbers each acknowledged message type."""


def seq_of(msg: MavMessage) -> int:
    """The sequence number an acknowledgement names for ``msg``."""
    field = SEQ_FIELD.get(msg.get_msgId())
    if field is None:
        raise ValueError(f"{msg.get_type()} is not an acknowledged message type")
    return int(getattr(msg, field))


class OutboxStore(Protocol):
    """Where unacknowledged messages wait (as unsigned MAVLink 2 frames)."""

    def put(self, msgid: int, seq: int, frame: bytes) -> None:
        """Store (or replace) the message with this key."""
        ...

    def ack(self, msgid: int, seq: int) -> bool:
        """Remove it; True if it was pending."""
        ...

    def pending(self) -> list[tuple[int, int, bytes]]:
        """(msgid, seq, frame) of every pending message, oldest first."""
        ...


class MemoryOutboxStore:
    """An OutboxStore that forgets on restart. Thread-safe."""

    def __init__(self) -> None:
        self._items: OrderedDict[tuple[int, int], bytes] = OrderedDict()
        self._lock = threading.Lock()

    def put(self, msgid: int, seq: int, frame: bytes) -> None:
        with self._lock:
            self._items[(msgid, seq)] = frame

    def ack(self, msgid: int, seq: int) -> bool:
        with self._lock:
            return self._items.pop((msgid, seq), None) is not None

    def pending(self) -> list[tuple[int, int, bytes]]:
        with self._lock:
            return [(k[0], k[1], v) for k, v in self._items.items()]


@dataclass
class _Schedule:
    msg: MavMessage
    next_due_s: float
    backoff_s: float
    attempts: int


@dataclass
class OutboxCounters:
    submitted: int = 0
    sent: int = 0  # first sends and resends
    resent: int = 0
    acked: int = 0
    unmatched_acks: int = 0  # acks for nothing pending (late duplicates)


class Outbox:
    """Resends unacknowledged messages with exponential backoff. Thread-safe.

    ``send`` is called with the message object (the caller encodes it, for each of its
    links); it is never called while the outbox's lock is held.
    """

    def __init__(
        self,
        send: Callable[[MavMessage], None],
        store: OutboxStore | None = None,
        *,
        initial_s: float = 1.0,
        max_s: float = 30.0,
        clock: Callable[[], float] = time.monotonic,
        codec: Codec | None = None,
    ) -> None:
        if initial_s <= 0 or max_s < initial_s:
            raise ValueError(f"need 0 < initial_s ({initial_s}) <= max_s ({max_s})")
        self._send = send
        self._store: OutboxStore = store if store is not None else MemoryOutboxStore()
        self._initial_s = initial_s
        self._max_s = max_s
        self._clock = clock
        # Frames in the store are written and read by this unsigned codec only.
        self._frames = codec if codec is not None else Codec(1, 1)
        self._lock = threading.Lock()
        self._schedule: dict[tuple[int, int], _Schedule] = {}
        self.counters = OutboxCounters()
        now = clock()
        for msgid, seq, frame in self._store.pending():  # left over from a previous run
            msg = self._frames.decode_frame(frame)
            if msg is None:
                log.warning("outbox: stored message %d/%d does not decode; dropped", msgid, seq)
                self._store.ack(msgid, seq)
                continue
            self._schedule[(msgid, seq)] = _Schedule(msg, now, initial_s, 0)

    def submit(self, msg: MavMessage, *, send: bool = True) -> None:
        """Store ``msg`` and keep resending it until acknowledged.

        ``send=False`` only stores and schedules it as due now: the caller commits
        its own transaction first, and the next ``poll()`` sends it.
        """
        key = (msg.get_msgId(), seq_of(msg))
        frame = self._frames.encode(msg)
        self._store.put(key[0], key[1], frame)
        now = self._clock()
        with self._lock:
            self.counters.submitted += 1
            if not send:
                self._schedule[key] = _Schedule(msg, now, self._initial_s, 0)
                return
            next_backoff_s = min(2.0 * self._initial_s, self._max_s)
            self._schedule[key] = _Schedule(msg, now + self._initial_s, next_backoff_s, 1)
            self.counters.sent += 1
        self._send(msg)

    def on_ack(self, ack: MavMessage) -> bool:
        """Handle a RESCUE_ACK; True if it acknowledged a pending message."""
        key = (int(ack.acked_msgid), int(ack.seq))
        with self._lock:
            found = self._schedule.pop(key, None) is not None
            if found:
                self.counters.acked += 1
            else:
                self.counters.unmatched_acks += 1
        self._store.ack(*key)
        return found

    def poll(self) -> int:
        """Send every message that is due (first sends and resends); how many."""
        now = self._clock()
        due: list[MavMessage] = []
        with self._lock:
            for item in self._schedule.values():
                if item.next_due_s <= now:
                    due.append(item.msg)
                    if item.attempts > 0:
                        self.counters.resent += 1
                    item.attempts += 1
                    item.next_due_s = now + item.backoff_s
                    item.backoff_s = min(item.backoff_s * 2.0, self._max_s)
            self.counters.sent += len(due)
        for msg in due:
            self._send(msg)
        return len(due)

    def seconds_until_due(self) -> float | None:
        """How long until the next resend (0 if overdue); None when nothing is pending."""
        with self._lock:
            if not self._schedule:
                return None
            return max(0.0, min(s.next_due_s for s in self._schedule.values()) - self._clock())

    def resend_all_now(self) -> None:
        """Make everything due now (e.g. the HQ link came back) with the backoff reset."""
        now = self._clock()
        with self._lock:
            for item in self._schedule.values():
                item.next_due_s = now
                item.backoff_s = self._initial_s

    @property
    def pending_count(self) -> int:
        with self._lock:
            return len(self._schedule)

    def attempts(self, msgid: int, seq: int) -> int | None:
        """How many times a pending message was sent, or None if it is not pending."""
        with self._lock:
            item = self._schedule.get((msgid, seq))
            return None if item is None else item.attempts


class Deduplicator:
    """Remembers the last ``capacity`` (sysid, msgid, seq) keys. Thread-safe."""

    def __init__(self, capacity: int = 65536) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._capacity = capacity
        self._seen: OrderedDict[tuple[int, int, int], None] = OrderedDict()
        self._lock = threading.Lock()
        self.duplicates = 0

    def is_duplicate(self, sysid: int, seq: int, msgid: int = 0) -> bool:
        """True if this key was seen before; records it otherwise."""
        key = (sysid, msgid, seq)
        with self._lock:
            if key in self._seen:
                self._seen.move_to_end(key)
                self.duplicates += 1
                return True
            self._seen[key] = None
            if len(self._seen) > self._capacity:
                self._seen.popitem(last=False)
            return False

    def check(self, msg: MavMessage) -> bool:
        """is_duplicate for a received acknowledged-type message.

        Keyed by the report's ``robot_sysid`` (the robot that numbered it, even when
        relayed), else by the sender's system id.
        """
        sysid = int(getattr(msg, "robot_sysid", msg.get_srcSystem()))
        return self.is_duplicate(sysid, seq_of(msg), msg.get_msgId())
