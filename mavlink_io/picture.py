"""Evidence pictures in pieces: RESCUE_PICTURE_CHUNK and RESCUE_PICTURE_ACK, without I/O.

A picture (a JPEG of at most ``MAX_PICTURE_BYTES``) travels as ``chunk_count(size)``
chunks of ``CHUNK_BYTES`` (the last one shorter). 86 bytes is what fits: a signed
RESCUE_PICTURE_CHUNK frame is then exactly the 128 bytes a TUNNEL carries through
the autopilot (10 header + 103 payload + 2 CRC + 13 signature), and 256 chunks is
what the acknowledgement's 32-byte bitmap can name.

Sender, ``Transfer``: sends the chunks the receiver lacks in rounds; the last chunk
of a round asks for an acknowledgement (flag ACK_REQUEST). The acknowledgement's
bitmap says what arrived; the next round sends the rest. No answer within the wait
(doubling from ``initial_wait_s`` to ``max_wait_s``): the last missing chunk alone
goes again, asking again (a lost acknowledgement costs one chunk, not a round).
STORED or REJECTED ends it. Pacing (how many bytes a second) is the caller's.

Receiver, ``Reassembly``: collects one picture's chunks (each checked against the
first: same victim, kind, size and CRC), in any order, duplicates ignored; ``jpeg()``
returns the whole picture once every chunk is in and its CRC-32 matches.

A picture's kind (``fusion.types.Sensor``: the colour camera's view or the thermal
camera's) is the chunk flag THERMAL, a bit of the existing flags byte: a signed chunk
already fills a TUNNEL, so there is no room for a field, and a picture sent before
the flag existed is a colour one, as it was. A receiver that does not know the flag
refuses those chunks (unknown flag bits) instead of taking a thermal view for the
colour one.

``BadChunk`` (a ValueError) names the field of a chunk that cannot be used.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from types import ModuleType
from typing import Any

from fusion.types import Sensor
from mavlink_io.errors import MavlinkIOError

CHUNK_BYTES = 86
BITMAP_BYTES = 32
MAX_CHUNKS = BITMAP_BYTES * 8  # 256
MAX_PICTURE_BYTES = MAX_CHUNKS * CHUNK_BYTES  # 22016
FLAG_ACK_REQUEST = 1
FLAG_THERMAL = 2  # the thermal camera's view (else the colour camera's)
_KNOWN_FLAGS = FLAG_ACK_REQUEST | FLAG_THERMAL
RESULT_STORED = 0
RESULT_PARTIAL = 1
RESULT_REJECTED = 2
_RESULTS = (RESULT_STORED, RESULT_PARTIAL, RESULT_REJECTED)
_MAX_U32 = 0xFFFFFFFF
_JPEG_START = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"


class BadChunk(MavlinkIOError, ValueError):
    """A chunk (or a reassembled picture) that cannot be used; the text says why."""


def chunk_count(size: int) -> int:
    """How many chunks a picture of ``size`` bytes takes."""
    return -(-size // CHUNK_BYTES)


def chunk_length(size: int, index: int) -> int:
    """The bytes chunk ``index`` of a ``size``-byte picture carries."""
    return min(CHUNK_BYTES, size - index * CHUNK_BYTES)


def crc32(data: bytes) -> int:
    return zlib.crc32(data) & _MAX_U32


def check_jpeg(data: bytes) -> None:
    """BadChunk unless ``data`` looks like a whole JPEG (start and end markers)."""
    if not (data.startswith(_JPEG_START) and data.rstrip(b"\x00").endswith(_JPEG_END)):
        raise BadChunk(f"the {len(data)} bytes are not a JPEG (no FFD8 ... FFD9 markers)")


@dataclass(frozen=True)
class Chunk:
    """One checked RESCUE_PICTURE_CHUNK."""

    picture_id: int
    victim_id: int
    crc32: int
    size: int
    index: int
    data: bytes
    ack_request: bool = False
    kind: Sensor = Sensor.COLOUR

    def __post_init__(self) -> None:
        if not 0 < self.picture_id <= _MAX_U32:
            raise BadChunk(f"picture_id {self.picture_id} is not in 1..{_MAX_U32}")
        if not 0 < self.victim_id <= _MAX_U32:
            raise BadChunk(f"victim_id {self.victim_id} is not in 1..{_MAX_U32}")
        if not 0 <= self.crc32 <= _MAX_U32:
            raise BadChunk(f"crc32 {self.crc32} is not a 32-bit value")
        if not 0 < self.size <= MAX_PICTURE_BYTES:
            raise BadChunk(f"size {self.size} is not in 1..{MAX_PICTURE_BYTES} bytes")
        count = chunk_count(self.size)
        if not 0 <= self.index < count:
            raise BadChunk(
                f"chunk_index {self.index} is outside the {count} chunks of a "
                f"{self.size}-byte picture"
            )
        expected = chunk_length(self.size, self.index)
        if len(self.data) != expected:
            raise BadChunk(
                f"length {len(self.data)} of chunk {self.index} should be {expected} "
                f"for a {self.size}-byte picture"
            )

    @classmethod
    def from_msg(cls, msg: Any) -> Chunk:
        """The checked chunk in a RESCUE_PICTURE_CHUNK; BadChunk names the bad field."""
        flags, length = int(msg.flags), int(msg.length)
        if flags & ~_KNOWN_FLAGS:
            raise BadChunk(f"flags {flags:#x} has unknown bits")
        if not 0 < length <= CHUNK_BYTES:
            raise BadChunk(f"length {length} is not in 1..{CHUNK_BYTES}")
        return cls(
            picture_id=int(msg.picture_id),
            victim_id=int(msg.victim_id),
            crc32=int(msg.crc32),
            size=int(msg.size),
            index=int(msg.chunk_index),
            data=bytes(msg.data[:length]),
            ack_request=bool(flags & FLAG_ACK_REQUEST),
            kind=Sensor.THERMAL if flags & FLAG_THERMAL else Sensor.COLOUR,
        )

    def to_msg(self, module: ModuleType) -> Any:
        data = list(self.data) + [0] * (CHUNK_BYTES - len(self.data))
        return module.MAVLink_rescue_picture_chunk_message(
            self.picture_id,
            self.victim_id,
            self.crc32,
            self.size,
            self.index,
            (FLAG_ACK_REQUEST if self.ack_request else 0)
            | (FLAG_THERMAL if self.kind is Sensor.THERMAL else 0),
            len(self.data),
            data,
        )

    def asking(self) -> Chunk:
        """The same chunk with ACK_REQUEST set."""
        return Chunk(
            self.picture_id,
            self.victim_id,
            self.crc32,
            self.size,
            self.index,
            self.data,
            True,
            self.kind,
        )


def split(
    picture_id: int, victim_id: int, jpeg: bytes, kind: Sensor = Sensor.COLOUR
) -> list[Chunk]:
    """The chunks of ``jpeg`` (ValueError when it is empty or too big to send)."""
    if not 0 < len(jpeg) <= MAX_PICTURE_BYTES:
        raise ValueError(f"a picture has 1 to {MAX_PICTURE_BYTES} bytes, not {len(jpeg)}")
    crc = crc32(jpeg)
    return [
        Chunk(
            picture_id,
            victim_id,
            crc,
            len(jpeg),
            i,
            jpeg[i * CHUNK_BYTES : (i + 1) * CHUNK_BYTES],
            kind=kind,
        )
        for i in range(chunk_count(len(jpeg)))
    ]


def to_bitmap(indices: set[int] | frozenset[int]) -> list[int]:
    """The 32-byte bitmap of RESCUE_PICTURE_ACK.received."""
    out = [0] * BITMAP_BYTES
    for i in indices:
        out[i // 8] |= 1 << (i % 8)
    return out


def from_bitmap(bitmap: Any, count: int) -> frozenset[int]:
    """The chunk indices below ``count`` that ``bitmap`` marks received."""
    raw = bytes(bitmap)[:BITMAP_BYTES]
    return frozenset(i for i in range(min(count, len(raw) * 8)) if raw[i // 8] >> (i % 8) & 1)


@dataclass(frozen=True)
class Ack:
    """One checked RESCUE_PICTURE_ACK."""

    picture_id: int
    result: int
    received: Any  # the raw bitmap; decode with the picture's chunk count

    @classmethod
    def from_msg(cls, msg: Any) -> Ack:
        result = int(msg.result)
        if result not in _RESULTS:
            raise BadChunk(f"result {result} is not a RESCUE_PICTURE_RESULT")
        return cls(int(msg.picture_id), result, bytes(msg.received))


def ack_msg(
    module: ModuleType,
    target_system: int,
    target_component: int,
    picture_id: int,
    result: int,
    received: set[int] | frozenset[int],
) -> Any:
    return module.MAVLink_rescue_picture_ack_message(
        target_system, target_component, picture_id, result, to_bitmap(received)
    )


@dataclass
class Reassembly:
    """One picture's chunks as they arrive (receiver side)."""

    picture_id: int
    victim_id: int
    crc32: int
    size: int
    kind: Sensor = Sensor.COLOUR
    parts: dict[int, bytes] = field(default_factory=dict)

    @classmethod
    def starting(cls, chunk: Chunk) -> Reassembly:
        return cls(chunk.picture_id, chunk.victim_id, chunk.crc32, chunk.size, chunk.kind)

    @property
    def count(self) -> int:
        return chunk_count(self.size)

    @property
    def received(self) -> frozenset[int]:
        return frozenset(self.parts)

    @property
    def complete(self) -> bool:
        return len(self.parts) == self.count

    def add(self, chunk: Chunk) -> bool:
        """Take ``chunk``; False for a duplicate. BadChunk when it contradicts the
        picture's first chunk (another victim, kind, size or CRC under the same ID)."""
        for name, mine, theirs in (
            ("victim_id", self.victim_id, chunk.victim_id),
            ("kind", self.kind, chunk.kind),
            ("size", self.size, chunk.size),
            ("crc32", self.crc32, chunk.crc32),
        ):
            if mine != theirs:
                raise BadChunk(
                    f"picture {self.picture_id}: chunk {chunk.index} says {name} {theirs}, "
                    f"earlier chunks {mine}"
                )
        if chunk.index in self.parts:
            return False
        self.parts[chunk.index] = chunk.data
        return True

    def jpeg(self) -> bytes:
        """The whole picture; BadChunk when its CRC or its JPEG markers are wrong."""
        if not self.complete:
            raise BadChunk(f"picture {self.picture_id}: {len(self.parts)} of {self.count} chunks")
        data = b"".join(self.parts[i] for i in range(self.count))
        if crc32(data) != self.crc32:
            raise BadChunk(
                f"picture {self.picture_id}: CRC-32 {crc32(data):#010x} of the joined chunks, "
                f"the robot said {self.crc32:#010x}"
            )
        check_jpeg(data)
        return data


class Transfer:
    """Sending one picture until the receiver has it (sender side; clock injected)."""

    def __init__(
        self,
        picture_id: int,
        victim_id: int,
        jpeg: bytes,
        initial_wait_s: float = 1.5,
        max_wait_s: float = 8.0,
        kind: Sensor = Sensor.COLOUR,
    ) -> None:
        self.picture_id = picture_id
        self.victim_id = victim_id
        self.kind = kind
        self.size = len(jpeg)
        self.chunks = split(picture_id, victim_id, jpeg, kind)
        self.initial_wait_s = initial_wait_s
        self.max_wait_s = max_wait_s
        self.received: frozenset[int] = frozenset()
        self.result: int | None = None  # STORED or REJECTED: done
        self.chunks_sent = 0
        self.rounds = 0
        self._round: list[int] = []
        self._wait_s = initial_wait_s
        self._answer_due_s: float | None = None  # waiting for an ack until then

    @property
    def done(self) -> bool:
        return self.result is not None

    def _missing(self) -> list[int]:
        return [i for i in range(len(self.chunks)) if i not in self.received]

    def next_chunk(self, now_s: float) -> Chunk | None:
        """The chunk to send now, or None (waiting for an answer, or done)."""
        if self.done:
            return None
        if not self._round and self._answer_due_s is None:
            # Everything arrived but no STORED came: ask again with the last chunk.
            self._round = self._missing() or [len(self.chunks) - 1]
            self.rounds += 1
        if self._round:
            index = self._round.pop(0)
            chunk = self.chunks[index]
            if not self._round:  # the last of the round: ask what arrived
                chunk = chunk.asking()
                self._answer_due_s = now_s + self._wait_s
            self.chunks_sent += 1
            return chunk
        assert self._answer_due_s is not None
        if now_s < self._answer_due_s:
            return None
        # No answer: the acknowledgement or the asking chunk was lost. Ask again
        # with one missing chunk, waiting longer each time.
        self._wait_s = min(self.max_wait_s, self._wait_s * 2.0)
        self._answer_due_s = now_s + self._wait_s
        self.chunks_sent += 1
        return self.chunks[self._missing()[-1]].asking()

    def seconds_until_due(self, now_s: float) -> float | None:
        """When ``next_chunk`` may have something (0: now; None: done)."""
        if self.done:
            return None
        if self._round or self._answer_due_s is None:
            return 0.0
        return max(0.0, self._answer_due_s - now_s)

    def on_ack(self, ack: Ack) -> None:
        """Apply an acknowledgement of this picture."""
        if ack.picture_id != self.picture_id or self.done:
            return
        if ack.result in (RESULT_STORED, RESULT_REJECTED):
            self.result = ack.result
            self._round = []
            return
        self.received = self.received | from_bitmap(ack.received, len(self.chunks))
        if self._round:  # an answer to an earlier round: skip what arrived meanwhile
            self._round = [i for i in self._round if i not in self.received]
            return
        self._answer_due_s = None  # the next round starts with the next chunk
        self._wait_s = self.initial_wait_s
