"""Log lines for refused input, at most one per key and period (a flood stays readable)."""

from __future__ import annotations

import logging
import time

log = logging.getLogger("hq.app")
_MAX_KEYS = 1024  # keys remembered; beyond, the memory of what was said starts afresh


class RateLimitedLog:
    """WARNING lines per key, at most one per period; the lines left out are counted in the next."""

    def __init__(self, period_s: float) -> None:
        self._period_s = period_s
        self._last: dict[tuple[str, int], tuple[float, int]] = {}  # key -> (said at, left out)

    def say(self, key: tuple[str, int], text: str) -> None:
        now = time.monotonic()
        said, left_out = self._last.get(key, (-self._period_s, 0))
        if now - said < self._period_s:
            self._last[key] = (said, left_out + 1)
            return
        more = f" ({left_out} more like it left out)" if left_out else ""
        log.warning("%s%s", text, more)
        if len(self._last) >= _MAX_KEYS:
            self._last.clear()
        self._last[key] = (now, 0)
