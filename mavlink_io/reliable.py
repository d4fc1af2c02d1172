"""Reliable delivery of dialect messages: resend until acknowledged, drop duplicates.

Sender side, ``Outbox``: a message with a sequence number (RESCUE_VICTIM_REPORT's
``report_seq``, RESCUE_OPERATOR_ACTION's ``action_seq``) is stored, sent at once,
and resent after ``initial_s``, then doubling up to ``max_s``, until a RESCUE_ACK
names the same (``acked_msgid``, ``seq``). Messages live in an ``OutboxStore``
(in memory here; the companion adds a durable one) as unsigned MAVLink 2 frames, so
a restart resends what was never acknowledged. Each resend is re-encoded by the
caller's codec: a fresh sequence number and signature timestamp, so signing's replay
protection does not reject it.

One pending report per victim: a RESCUE_VICTIM_REPORT replaces a pending report of
the same (``robot_sysid``, ``victim_id``), since the newest says everything the HQ
needs; it inherits the replaced one's event flags (NEW, URGENCY_CHANGED, ...) so
the HQ still learns that the victim is new. The acknowledgement of a replaced
report is counted as unmatched. Bound: at most ``max_pending`` messages wait; a new
one beyond that drops the oldest pending one, loudly (``dropped`` counts it; the
victim is reported again at its next change, and the HQ's RESEND re-reports all).
With one report per victim the bound is only reached with that many victims
unacknowledged.

Transactions: ``stage(msg)`` writes to the store inside the caller's open
transaction (the report's commit and its outbox entry are one transaction) and
keeps the message out of the schedule; ``publish()`` after the commit schedules what
was staged (``discard()`` after a rollback forgets it). So nothing is sent before
it is on disk.

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
    unmatched_acks: int = 0  # acks for nothing pending (late duplicates, replaced reports)
    replaced: int = 0  # pending reports replaced by a newer one of the same victim
    dropped: int = 0  # the oldest pending message, dropped at the bound


# Fields that name what a message is about: a newer message about the same thing
# replaces a pending one. Flags that mean an event carry over to the replacement.
_SUBJECT_FIELDS = {RESCUE_VICTIM_REPORT_ID: ("robot_sysid", "victim_id")}
_FLAG_GLOBAL_VALID = 1  # follows the newest report, the other flags are events
MAX_PENDING = 1000

Key = tuple[int, int]


def _subject(msg: MavMessage) -> tuple[int, ...] | None:
    fields = _SUBJECT_FIELDS.get(msg.get_msgId())
    if fields is None:
        return None
    return (msg.get_msgId(), *(int(getattr(msg, f)) for f in fields))


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
        max_pending: int = MAX_PENDING,
        clock: Callable[[], float] = time.monotonic,
        codec: Codec | None = None,
    ) -> None:
        if initial_s <= 0 or max_s < initial_s:
            raise ValueError(f"need 0 < initial_s ({initial_s}) <= max_s ({max_s})")
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1, got {max_pending}")
        self._send = send
        self._store: OutboxStore = store if store is not None else MemoryOutboxStore()
        self._initial_s = initial_s
        self._max_s = max_s
        self._max_pending = max_pending
        self._clock = clock
        # Frames in the store are written and read by this unsigned codec only.
        self._frames = codec if codec is not None else Codec(1, 1)
        self._lock = threading.Lock()
        self._schedule: dict[Key, _Schedule] = {}  # insertion order: oldest first
        self._staged: dict[Key, MavMessage] = {}
        self._subjects: dict[tuple[int, ...], Key] = {}  # what is about whom, pending or staged
        self.counters = OutboxCounters()
        now = clock()
        for msgid, seq, frame in self._store.pending():  # left over from a previous run
            msg = self._frames.decode_frame(frame)
            if msg is None:
                log.warning("outbox: stored message %d/%d does not decode; dropped", msgid, seq)
                self._store.ack(msgid, seq)
                continue
            key = (msgid, seq)
            subject = _subject(msg)
            older = self._subjects.get(subject) if subject is not None else None
            if older is not None:  # an older version kept two reports of one victim
                self._schedule.pop(older, None)
                self._store.ack(*older)
            if subject is not None:
                self._subjects[subject] = key
            self._schedule[key] = _Schedule(msg, now, initial_s, 0)

    # -- submitting ----------------------------------------------------------------

    def submit(self, msg: MavMessage, *, send: bool = True) -> None:
        """Store ``msg``, send it now (or at the next ``poll()`` with ``send=False``)
        and keep resending it until acknowledged."""
        self.stage(msg)
        self.publish(due_now=not send)
        if send:
            self._send(msg)

    def stage(self, msg: MavMessage) -> None:
        """Store ``msg`` (in the caller's open transaction, if its store has them) and
        hold it until ``publish()``; a pending message about the same victim is
        replaced (in the store now, in the schedule at publish)."""
        key = (msg.get_msgId(), seq_of(msg))
        subject = _subject(msg)
        older: Key | None = None
        old_msg: MavMessage | None = None
        with self._lock:
            if subject is not None and self._subjects.get(subject, key) != key:
                older = self._subjects[subject]
                item = self._schedule.get(older)
                old_msg = item.msg if item is not None else self._staged.get(older)
        if older is not None and old_msg is not None:
            msg.flags |= int(old_msg.flags) & ~_FLAG_GLOBAL_VALID & 0xFF
            self._store.ack(*older)
        self._store.put(key[0], key[1], self._frames.encode(msg))
        with self._lock:
            if older is not None:
                self._staged.pop(older, None)
            self._staged[key] = msg
            if subject is not None:
                self._subjects[subject] = key

    def publish(self, *, due_now: bool = True) -> None:
        """Schedule everything staged (after the caller's commit). ``due_now``: the
        next ``poll()`` sends it; else the caller sends it now itself."""
        now = self._clock()
        dropped: list[Key] = []
        with self._lock:
            staged, self._staged = self._staged, {}
            for key, msg in staged.items():
                self.counters.submitted += 1
                subject = _subject(msg)
                for k, item in list(self._schedule.items()):
                    if subject is not None and _subject(item.msg) == subject:
                        del self._schedule[k]
                        self.counters.replaced += 1
                if due_now:
                    self._schedule[key] = _Schedule(msg, now, self._initial_s, 0)
                else:
                    backoff_s = min(2.0 * self._initial_s, self._max_s)
                    self._schedule[key] = _Schedule(msg, now + self._initial_s, backoff_s, 1)
                    self.counters.sent += 1
                while len(self._schedule) > self._max_pending:
                    oldest = next(iter(self._schedule))
                    self._forget(oldest)
                    dropped.append(oldest)
        for msgid, seq in dropped:
            self._store.ack(msgid, seq)
            log.warning(
                "outbox full (%d pending): message %d/%d dropped unacknowledged",
                self._max_pending,
                msgid,
                seq,
            )

    def discard(self) -> None:
        """Forget what was staged (the caller's transaction rolled back)."""
        with self._lock:
            for key, msg in self._staged.items():
                subject = _subject(msg)
                if subject is not None and self._subjects.get(subject) == key:
                    del self._subjects[subject]
            self._staged.clear()
            for key, item in self._schedule.items():  # the replaced ones are pending again
                subject = _subject(item.msg)
                if subject is not None:
                    self._subjects.setdefault(subject, key)

    def _forget(self, key: Key) -> None:
        """Remove a pending message from memory (lock held)."""
        item = self._schedule.pop(key)
        self.counters.dropped += 1
        subject = _subject(item.msg)
        if subject is not None and self._subjects.get(subject) == key:
            del self._subjects[subject]

    # -- acknowledgements and sending ---------------------------------------------

    def on_ack(self, ack: MavMessage) -> bool:
        """Handle a RESCUE_ACK; True if it acknowledged a pending message. It writes
        the store: call it from the one thread that owns the outbox, not a reader."""
        return self.acknowledged(ack) is not None

    def acknowledged(self, ack: MavMessage) -> MavMessage | None:
        """``on_ack``, returning the message it acknowledged (None: nothing pending)."""
        key = (int(ack.acked_msgid), int(ack.seq))
        with self._lock:
            item = self._schedule.pop(key, None)
            if item is not None:
                self.counters.acked += 1
                subject = _subject(item.msg)
                if subject is not None and self._subjects.get(subject) == key:
                    del self._subjects[subject]
            else:
                self.counters.unmatched_acks += 1
        if item is None:
            return None
        self._store.ack(*key)
        return item.msg

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

    def pending_keys(self) -> list[Key]:
        """(msgid, seq) of every pending message, oldest first."""
        with self._lock:
            return list(self._schedule)

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
