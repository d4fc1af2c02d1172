"""Evidence pictures arriving in chunks: checked, collected (bounded), stored, answered.

``PictureIntake.on_chunk`` (the HQ's main thread, which owns the registry) takes a
RESCUE_PICTURE_CHUNK: every field is checked (mavlink_io.picture.Chunk; refused
with a counter and a rate-limited line), a picture the registry holds (same number,
size and CRC-32) is answered STORED when asked, one older than the victim's picture
of its kind (colour or thermal: a victim has one of each) the registry holds REJECTED
(it is not kept), the others are collected; a complete
picture is joined, checked (CRC-32, JPEG markers: else REJECTED), stored, and only
then answered STORED: never STORED for what is not kept. A chunk asking for it gets the bitmap of what arrived.

``PictureAssembler`` holds the partial pictures: ``add`` returns the picture's
``Reassembly`` (complete or not). Memory is bounded whatever robots send: at most
``max_per_robot`` partial pictures per robot and ``max_total`` in all (a new one
beyond either bound drops the one heard from longest ago, counted), each at most
``MAX_PICTURE_BYTES``, and a partial picture not added to for ``idle_s`` is
forgotten (the robot's next round starts it again). So the worst case is
``max_total`` x 22 kB, about 1.4 MB.
"""

from __future__ import annotations

import logging
import sqlite3
import time
import zlib
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hq.ratelog import RateLimitedLog
from hq.registry import Registry
from hq.registry_file import RegistryError
from mavlink_io import picture
from mavlink_io.picture import Chunk, Reassembly

log = logging.getLogger(__name__)

MAX_PER_ROBOT = 4
MAX_TOTAL = 64
IDLE_S = 120.0


@dataclass
class AssemblerCounters:
    chunks: int = 0  # fresh chunks taken
    duplicates: int = 0  # chunks already held
    dropped: int = 0  # partial pictures dropped at a bound
    expired: int = 0  # partial pictures forgotten after idle_s


class PictureAssembler:
    """Partial pictures by (robot, picture_id). One thread (the HQ's main thread)."""

    def __init__(
        self, max_per_robot: int = MAX_PER_ROBOT, max_total: int = MAX_TOTAL, idle_s: float = IDLE_S
    ) -> None:
        self.max_per_robot = max_per_robot
        self.max_total = max_total
        self.idle_s = idle_s
        self.counters = AssemblerCounters()
        # Least recently added first: the one to drop at a bound.
        self._partial: OrderedDict[tuple[int, int], tuple[Reassembly, float]] = OrderedDict()

    def __len__(self) -> int:
        return len(self._partial)

    def add(self, robot: int, chunk: Chunk, now_s: float) -> Reassembly:
        """Take one chunk; the picture it belongs to. BadChunk (from Reassembly.add)
        when it contradicts the picture's earlier chunks; nothing changes then."""
        key = (robot, chunk.picture_id)
        held = self._partial.get(key)
        if held is None:
            self._make_room(robot)
            r = Reassembly.starting(chunk)
        else:
            r = held[0]
        if r.add(chunk):
            self.counters.chunks += 1
        else:
            self.counters.duplicates += 1
        self._partial[key] = (r, now_s)
        self._partial.move_to_end(key)
        return r

    def drop(self, robot: int, picture_id: int) -> None:
        """Forget a picture (stored, or refused)."""
        self._partial.pop((robot, picture_id), None)

    def forget_idle(self, now_s: float) -> None:
        while self._partial:
            key, (_, last) = next(iter(self._partial.items()))
            if now_s - last <= self.idle_s:
                return
            del self._partial[key]
            self.counters.expired += 1

    def _make_room(self, robot: int) -> None:
        mine = [k for k in self._partial if k[0] == robot]
        if len(mine) >= self.max_per_robot:
            del self._partial[mine[0]]
            self.counters.dropped += 1
        if len(self._partial) >= self.max_total:
            self._partial.popitem(last=False)
            self.counters.dropped += 1


@dataclass
class IntakeCounters:
    stored: int = 0  # evidence pictures stored
    chunks_refused: int = 0  # chunks with an unusable or contradictory field
    rejected: int = 0  # complete pictures that failed their CRC or are not a JPEG
    store_failures: int = 0  # complete pictures not stored (busy, full disk): asked again
    answers: int = 0  # RESCUE_PICTURE_ACKs sent


Answer = Callable[[int, int, frozenset[int]], None]  # (picture_id, result, received)
_ALL = frozenset(range(picture.MAX_CHUNKS))


class PictureIntake:
    """RESCUE_PICTURE_CHUNKs in, pictures in the registry, answers out."""

    def __init__(
        self, registry: Registry, refusals: RateLimitedLog, event: Callable[[str], None]
    ) -> None:
        self.registry = registry
        self.assembler = PictureAssembler()
        self.counters = IntakeCounters()
        self._refusals = refusals
        self._event = event

    def _answer(
        self, answer: Answer, picture_id: int, result: int, received: frozenset[int]
    ) -> None:
        answer(picture_id, result, received)
        self.counters.answers += 1

    def _refuse(self, robot: int, text: str) -> None:
        self.counters.chunks_refused += 1
        self._refusals.say(("picture", robot), text)

    def on_chunk(self, msg: Any, answer: Answer) -> bool:
        """Take one chunk; True when a new picture was stored."""
        robot = msg.get_srcSystem()
        try:
            chunk = Chunk.from_msg(msg)
        except picture.BadChunk as exc:
            self._refuse(robot, f"refused RESCUE_PICTURE_CHUNK from system {robot}: {exc}")
            return False
        try:
            stored = self.registry.picture_id(robot, chunk.victim_id, chunk.kind)
        except sqlite3.Error as exc:
            log.debug("cannot read pictures: %s", exc)
            return False
        if stored is not None and stored > chunk.picture_id:  # a newer one is kept
            if chunk.ack_request:
                self._answer(answer, chunk.picture_id, picture.RESULT_REJECTED, frozenset())
            return False
        if stored == chunk.picture_id and self._holds(robot, chunk):
            if chunk.ack_request:  # the robot missed our STORED
                self._answer(answer, chunk.picture_id, picture.RESULT_STORED, _ALL)
            return False
        try:
            r = self.assembler.add(robot, chunk, time.monotonic())
        except picture.BadChunk as exc:
            self._refuse(robot, f"refused a picture chunk of robot {robot}: {exc}")
            return False
        if not r.complete:
            if chunk.ack_request:
                self._answer(answer, chunk.picture_id, picture.RESULT_PARTIAL, r.received)
            return False
        return self._complete(robot, chunk, r, answer)

    def _holds(self, robot: int, chunk: Chunk) -> bool:
        """Whether the registry keeps this very picture (its number and its bytes): a
        robot whose state lost commits (a power cut) may give a number again to
        another picture, which is then collected and stored, not answered STORED."""
        jpeg = self.registry.picture(robot, chunk.victim_id, chunk.kind)
        return jpeg is not None and (len(jpeg), zlib.crc32(jpeg)) == (chunk.size, chunk.crc32)

    def _complete(self, robot: int, chunk: Chunk, r: Reassembly, answer: Answer) -> bool:
        try:
            jpeg = r.jpeg()
        except picture.BadChunk as exc:
            self.counters.rejected += 1
            self.assembler.drop(robot, chunk.picture_id)
            self._refusals.say(("picture", robot), f"rejected a picture of robot {robot}: {exc}")
            self._answer(answer, chunk.picture_id, picture.RESULT_REJECTED, frozenset())
            return False
        try:
            fresh = self.registry.store_picture(
                robot, chunk.victim_id, chunk.picture_id, jpeg, time.time(), chunk.kind
            )
        except RegistryError as exc:  # not answered: the robot asks again later
            self.counters.store_failures += 1
            log.warning("picture %d of robot %d not stored: %s", chunk.picture_id, robot, exc)
            return False
        self.assembler.drop(robot, chunk.picture_id)
        if not fresh:  # a newer picture of that victim is kept: this one is not
            self._answer(answer, chunk.picture_id, picture.RESULT_REJECTED, frozenset())
            return False
        self._answer(answer, chunk.picture_id, picture.RESULT_STORED, _ALL)
        self.counters.stored += 1
        self._event(
            f"{chunk.kind} picture robot {robot} victim {chunk.victim_id} #{chunk.picture_id}:"
            f" {len(jpeg)} bytes"
        )
        return True
