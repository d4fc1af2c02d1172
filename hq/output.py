"""What the HQ shows and publishes: event lines, the live table, the exports, the SBS feed.

``changed`` marks that what is shown is out of date; ``refresh`` (the main loop,
every turn) redraws the table and writes the exports and the SBS feed at most
twice a second, and only after a change, except that the live table is redrawn
every second anyway (the ages on it tick).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from hq import export, table
from hq.counters import Counters
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.sbs import SbsServer
from hq.view import hq_victims

log = logging.getLogger(__name__)

_REDRAW_MIN_PERIOD_S = 0.5  # the table and the exports: at most 2 Hz
_AGE_REFRESH_S = 1.0  # redraw the live table this often even without news (ages tick)


class Output:
    """Event lines (or the live table) on ``out``, exports to a directory, victims to SBS."""

    def __init__(
        self,
        registry: Registry,
        out: TextIO,
        counters: Counters,
        header: Callable[[int], table.Header],
        *,
        live_table: bool,
        export_dir: Path | None,
        sbs: SbsServer | None,
    ) -> None:
        self.registry = registry
        self.out = out
        self.counters = counters
        self._header = header  # the table's header, given the number of reports stored
        self.live_table = live_table
        self.export_dir = export_dir
        self.sbs = sbs  # the victims as ADS-B traffic for QGC (hq/sbs.py)
        self._dirty = True
        self._last_draw_mono_s = 0.0

    def changed(self) -> None:
        """What the table, the exports and the SBS feed show has changed."""
        self._dirty = True

    def event(self, line: str, level: int = logging.INFO) -> None:
        log.log(level, "%s", line)
        if not self.live_table:
            self.out.write(f"{time.strftime('%H:%M:%S')} {line}\n")
            self.out.flush()

    def refresh(self, now: float, *, force: bool = False) -> None:
        since = now - self._last_draw_mono_s
        live_tick = self.live_table and since >= _AGE_REFRESH_S
        if not force and (since < _REDRAW_MIN_PERIOD_S or not (self._dirty or live_tick)):
            return
        self._last_draw_mono_s = now
        dirty, self._dirty = self._dirty, False
        try:
            victims = hq_victims(self.registry)
            robots = self.registry.robots()
            stored = self.registry.report_count()
        except RegistryError as exc:
            log.warning("cannot read the registry: %s", exc)
            return
        if dirty and self.export_dir is not None:
            self._export(victims, self.export_dir)
        if dirty and self.sbs is not None:
            self.sbs.publish(victims)
        if self.live_table:
            text = table.render(self._header(stored), victims, robots, time.time(), colour=True)
            self.out.write(table.CLEAR_SCREEN + text)
            self.out.flush()

    def _export(self, victims: list[Any], export_dir: Path) -> None:
        try:
            export.export_all(victims, export_dir)
        except OSError as exc:
            log.error("export to %s failed: %s", export_dir, exc)
            return
        self.counters.exports += 1
