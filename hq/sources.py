"""The HQ's state per source (link, address): a decoder each, bounded and expiring.

A decoder holds a source's partial frame and its signing replay window. Sources are
kept least recently heard first; a new one beyond ``limit`` pushes out the longest
silent, and ``forget_silent`` drops those silent longer than ``idle_s``. A sender
that hops ports, or a spoofed flood, cannot grow the HQ's memory.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable

from mavlink_io.codec import Codec


class SourceTable:
    def __init__(self, make: Callable[[], Codec], limit: int, idle_s: float) -> None:
        self._make = make
        self._limit = limit
        self._idle_s = idle_s
        self._items: OrderedDict[Hashable, tuple[Codec, float]] = OrderedDict()
        self.forgotten = 0  # sources dropped: silent too long, or too many

    def __len__(self) -> int:
        return len(self._items)

    def decoder(self, key: Hashable, now_s: float) -> Codec:
        """The decoder of ``key`` (a new one for a new source), marked heard at ``now_s``."""
        entry = self._items.pop(key, None)
        if entry is None:
            while len(self._items) >= self._limit:
                self._items.popitem(last=False)
                self.forgotten += 1
            codec = self._make()
        else:
            codec = entry[0]
        self._items[key] = (codec, now_s)
        return codec

    def forget_silent(self, now_s: float) -> None:
        while self._items:
            key, (_codec, heard_s) = next(iter(self._items.items()))
            if now_s - heard_s <= self._idle_s:
                return
            del self._items[key]
            self.forgotten += 1
