"""Evidence pictures arriving in chunks: the HQ's partial pictures, bounded.

The main thread feeds every checked RESCUE_PICTURE_CHUNK (mavlink_io.picture.Chunk)
with its robot's system ID; ``PictureAssembler.add`` returns the picture's
``Reassembly`` (complete or not). Memory is bounded whatever robots send: at most
``max_per_robot`` partial pictures per robot and ``max_total`` in all (a new one
beyond either bound drops the one heard from longest ago, counted), each at most
``MAX_PICTURE_BYTES``, and a partial picture not added to for ``idle_s`` is
forgotten (the robot's next round starts it again). So the worst case is
``max_total`` x 22 kB, about 1.4 MB.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

from mavlink_io.picture import Chunk, Reassembly

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
