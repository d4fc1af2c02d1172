"""What the HQ shows and publishes: event lines, the live table, the exports, the SBS feed.

``changed`` marks that what is shown is out of date; ``refresh`` (the main loop,
every turn) redraws the table and writes the exports and the SBS feed at most
twice a second, and only after a change, except that the live table is redrawn
every second anyway (the ages on it tick).

Nothing written for a person may stall the main thread, which acknowledges the
robots' reports: a terminal paused with Ctrl-S, a stalled ssh session or a ``| less``
nobody scrolls stops reading. So the table and the event lines (and rescue-hq's log
on stderr, ``WriterLogHandler``) go through a ``TerminalWriter``: its own thread
writes them; the main thread only hands text over. A newer table replaces one not
yet written; event lines beyond ``MAX_WAITING_LINES`` drop the oldest, which is said
once in the log and, when the terminal reads again, by a line on it (the registry
and the exports keep everything).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from hq import coverage, export, table
from hq.counters import Counters
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.sbs import SbsServer
from hq.view import hq_victims

log = logging.getLogger(__name__)

_REDRAW_MIN_PERIOD_S = 0.5  # the table and the exports: at most 2 Hz
COVERAGE_EXPORT_PERIOD_S = 10.0  # coverage.geojson (large) at most this often, and at the stop
_AGE_REFRESH_S = 1.0  # redraw the live table this often even without news (ages tick)
MAX_WAITING_LINES = 1000  # event or log lines waiting for a terminal that does not read
_CLOSE_WAIT_S = 1.0  # at the stop, how long the last lines may take to be written


class TerminalWriter:
    """Text for a person written by its own thread, so that a reader who stops never
    blocks the caller. ``on_first_drop`` is called once, by the caller's thread, when
    lines are first dropped."""

    def __init__(
        self,
        out: TextIO,
        name: str,
        *,
        max_lines: int = MAX_WAITING_LINES,
        on_first_drop: Callable[[], None] | None = None,
    ) -> None:
        self._out = out
        self._fd = _duplicate(out)  # None: not a file (a StringIO), written as text
        self._max_lines = max_lines
        self._on_first_drop = on_first_drop
        self._cond = threading.Condition()
        self._lines: deque[str] = deque()
        self._table: str | None = None  # the newest table not yet written
        self._dropped = 0  # lines dropped in all
        self._dropped_unsaid = 0  # dropped since the terminal was last told
        self._closing = False
        self._broken = False  # the terminal is gone (EPIPE, EIO): nothing more is written
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    @property
    def dropped(self) -> int:
        with self._cond:
            return self._dropped

    def line(self, text: str) -> None:
        """One line (``text`` ends in a newline); the oldest waiting one goes when full."""
        with self._cond:
            first = False
            if len(self._lines) >= self._max_lines:
                self._lines.popleft()
                self._dropped += 1
                self._dropped_unsaid += 1
                first = self._dropped == 1
            self._lines.append(text)
            self._cond.notify()
        if first and self._on_first_drop is not None:
            self._on_first_drop()

    def table(self, text: str) -> None:
        """A whole screen; replaces the one not yet written."""
        with self._cond:
            self._table = text
            self._cond.notify()

    def close(self) -> None:
        """Write what waits (for at most a second: the terminal may not read); safe twice."""
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join(_CLOSE_WAIT_S)
        if not self._thread.is_alive() and self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def _run(self) -> None:
        while True:
            with self._cond:
                while not (self._lines or self._table is not None or self._closing):
                    self._cond.wait()
                if not self._lines and self._table is None:
                    return  # closing, and everything written
                text = ""
                if self._dropped_unsaid:
                    text = (
                        f"rescue-hq: {self._dropped_unsaid} line(s) of output dropped while "
                        "this terminal was not read (the registry and exports keep every victim)\n"
                    )
                    self._dropped_unsaid = 0
                text += "".join(self._lines) + (self._table or "")
                self._lines.clear()
                self._table = None
            self._write(text)

    def _write(self, text: str) -> None:
        if self._broken:
            return
        try:
            if self._fd is None:
                self._out.write(text)
                self._out.flush()
                return
            data = memoryview(text.encode("utf-8", "replace"))
            while data:
                try:
                    data = data[os.write(self._fd, data) :]
                except BlockingIOError:  # a descriptor someone made non-blocking
                    time.sleep(0.05)
        except (OSError, ValueError):  # the terminal or pipe is gone: the HQ runs on
            self._broken = True


class WriterLogHandler(logging.Handler):
    """Log records as lines through a ``TerminalWriter`` (stderr on a paused terminal)."""

    def __init__(self, writer: TerminalWriter) -> None:
        super().__init__()
        self.writer = writer

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.writer.line(self.format(record) + "\n")
        except Exception:  # logging's own rule: a handler never raises
            self.handleError(record)

    def close(self) -> None:
        self.writer.close()
        super().close()


def _duplicate(out: TextIO) -> int | None:
    """A descriptor of its own for ``out``'s file (written with os.write, no Python
    buffer lock held while the terminal does not read); None when ``out`` is no file."""
    try:
        fd = out.fileno()
    except (OSError, ValueError, AttributeError):
        return None
    out.flush()
    return os.dup(fd)


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
        self._writer = TerminalWriter(out, "hq-out", on_first_drop=_say_dropped)
        self.counters = counters
        self._header = header  # the table's header, given the number of reports stored
        self.live_table = live_table
        self.export_dir = export_dir
        self._next_coverage_export_s = 0.0
        self.sbs = sbs  # the victims as ADS-B traffic for QGC (hq/sbs.py)
        self._dirty = True
        self._last_draw_mono_s = 0.0

    def changed(self) -> None:
        """What the table, the exports and the SBS feed show has changed."""
        self._dirty = True

    def event(self, line: str, level: int = logging.INFO) -> None:
        log.log(level, "%s", line)
        if not self.live_table:
            self._writer.line(f"{time.strftime('%H:%M:%S')} {line}\n")

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
            self._export(victims, self.export_dir, force=force)
        if dirty and self.sbs is not None:
            self.sbs.publish(victims)
        if self.live_table:
            text = table.render(self._header(stored), victims, robots, time.time(), colour=True)
            self._writer.table(table.CLEAR_SCREEN + text)

    def close(self) -> None:
        """Write what waits for the terminal (briefly: it may not read); safe twice."""
        self._writer.close()

    def _export(self, victims: list[Any], export_dir: Path, *, force: bool = False) -> None:
        now = time.monotonic()
        grid = None  # the searched-area map: rewritten at most every COVERAGE_EXPORT_PERIOD_S
        if force or now >= self._next_coverage_export_s:
            self._next_coverage_export_s = now + COVERAGE_EXPORT_PERIOD_S
            try:
                grid = coverage.load(self.registry)
            except RegistryError as exc:
                log.warning("cannot read the searched-area maps: %s", exc)
        try:
            export.export_all(victims, export_dir, grid)
        except OSError as exc:
            log.error("export to %s failed: %s", export_dir, exc)
            return
        self.counters.exports += 1


def _say_dropped() -> None:
    log.warning(
        "the terminal does not read rescue-hq's output (paused, or a stalled session): "
        "older event lines are dropped, the newest %d kept; acknowledgements go on",
        MAX_WAITING_LINES,
    )
