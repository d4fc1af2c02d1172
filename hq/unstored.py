"""Reports the HQ received but could not store yet (a full disk, a failing database)."""

from __future__ import annotations

from typing import Any

from hq.records import IncomingReport

Entry = tuple[IncomingReport, Any, Any]  # the report, its message, the route to ack it by


class UnstoredReports:
    """Reports received but not stored yet (the registry could not be written), in order.

    One entry per report (robot, report_seq, victim, report time), with the route
    of its latest copy. None of them was acknowledged: past ``limit`` the oldest is
    dropped and counted, and the robot's resend brings it back.
    """

    def __init__(self, limit: int) -> None:
        self._limit = limit
        self._items: dict[tuple[int, int, int, int], Entry] = {}
        self.dropped = 0

    def add(self, reports: list[Entry]) -> None:
        for entry in reports:
            item = entry[0]
            key = (item.report.robot_sysid, item.report_seq, item.report.victim_id,
                   item.report_time_usec)  # fmt: skip
            self._items.pop(key, None)
            self._items[key] = entry
        while len(self._items) > self._limit:
            del self._items[next(iter(self._items))]
            self.dropped += 1

    def entries(self) -> list[Entry]:
        return list(self._items.values())

    def clear(self) -> None:
        self._items.clear()

    def __len__(self) -> int:
        return len(self._items)
