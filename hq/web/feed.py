"""What the console's pages are fed: the database thread that watches for news, the hub.

``ConsoleDatabase`` (thread ``hq-web-db``) owns the console's own registry
connection and notes. It runs every database job the pages ask for (actions,
notes, exports, the state for /api/state) one after the other. While at least one
page watches (an open event stream) it also compares, every 0.1 s, SQLite's
``data_version`` (which moves when the HQ's main thread commits a report, a
status or an acknowledgement), LiveRobots' version (positions) and the set of
robots whose link is lost; on a change it updates the page state at most every
0.2 s (every 1 s when only robots moved) and hands it to ``publish``. With no
page open nothing is built; a request for the state updates it then.

An update is incremental (``Changes``): the sources touched by reports stored
since the last update (the reports' AUTOINCREMENT id) are read again, and only
the HQ victims whose sources (HQ victim, report number, merge target, when
stored), actions, notes or pictures changed are rebuilt (read, fused, made
JSON; hq.web.state.Page keeps the rest). ``Hub`` lives in the web server's event
loop and holds the latest state for the event streams.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import queue
import sqlite3
import threading
import time
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import Any, TypeVar

from fusion.types import Sensor
from hq.merge import Origins
from hq.records import Action, BadRecord, Robot, Source, report_from_payload
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.registry_rows import PictureKey, cell_float, cell_int
from hq.view import HqVictim, build, hq_victims
from hq.web.notes import Notes
from hq.web.state import (
    LiveRobots,
    Note,
    Page,
    actions_by_source,
    robot_actions,
    robots_lost,
    victim_actions,
)

log = logging.getLogger(__name__)

_TICK_S = 0.1  # how often the console looks for news in the registry
_MIN_PUBLISH_S = 0.2  # pages get at most 5 states a second
_MOVED_PUBLISH_S = 1.0  # and robots' movements alone at most once a second
_ROBOTS_READ_S = 1.0  # robots' rows (when each was last heard) read for lost links
T = TypeVar("T")
Job = Callable[[Registry, Notes], T]
_Queued = tuple[Callable[[Registry, Notes], Any], "concurrent.futures.Future[Any]"]
SourceKey = tuple[int, int]  # (robot sysid, robot's victim ID)
_Marks = tuple[object, ...]  # a source row's hq_id, report_seq, merge target, when stored
_FULL_READ = 200  # more changed sources than this: read them all in one query
_SOURCE_COLUMNS = (
    "robot_sysid, victim_id, hq_id, payload, report_seq, merged_into_id, updated_unix_s"
)


def picture_versions(registry: Registry, victims: list[HqVictim]) -> dict[int, dict[Sensor, str]]:
    """The version of each HQ victim's evidence pictures, per kind (the colour and the
    thermal camera's view; of each the newest received among its robots' pictures):
    ``robot-victim-picture_id``, so a better picture is a new address and the browser
    fetches it."""
    return picture_versions_of(registry.picture_versions(), victims)


def picture_versions_of(
    stored: dict[PictureKey, tuple[int, float]], victims: list[HqVictim]
) -> dict[int, dict[Sensor, str]]:
    """``picture_versions`` from the stored pictures' (picture_id, received time)."""
    out: dict[int, dict[Sensor, str]] = {}
    for v in victims:
        for kind in Sensor:
            held = [
                (stored[k][1], k, stored[k][0])
                for k in ((r, i, kind) for r, i in v.sources)
                if k in stored
            ]
            if held:
                _, (robot, victim_id, _kind), picture_id = max(held)
                out.setdefault(v.hq_id, {})[kind] = f"{robot}-{victim_id}-{picture_id}"
    return out


def picture_job(hq_id: int, version: str | None, kind: Sensor = Sensor.COLOUR) -> Job[bytes | None]:
    """The JPEG of an HQ victim's picture of this kind: the version asked for when
    given (and still one of its robots'), else the newest; None when there is none."""

    def job(registry: Registry, _notes: Notes) -> bytes | None:
        victim = next((v for v in hq_victims(registry) if v.hq_id == hq_id), None)
        if victim is None:
            return None
        key = picture_versions(registry, [victim]).get(hq_id, {}).get(kind)
        if key is None:
            return None
        if version is not None:
            robot, victim_id, _ = (int(x) for x in version.split("-"))
            if (robot, victim_id) in victim.sources:
                return registry.picture(robot, victim_id, kind)
        robot, victim_id, _ = (int(x) for x in key.split("-"))
        return registry.picture(robot, victim_id, kind)

    return job


class Hub:
    """The latest page state, in the event loop; SSE streams wait on it."""

    def __init__(self) -> None:
        self.version = 0
        self.data = ""
        self.closing = False
        self._changed = asyncio.Event()

    def publish(self, data: str) -> None:
        self.version += 1
        self.data = data
        self._changed.set()
        self._changed = asyncio.Event()

    def forget(self) -> None:
        """Drop the state: it is not kept up to date while no page watches."""
        self.data = ""

    def close(self) -> None:
        self.closing = True
        self._changed.set()

    async def wait(self, seen: int, timeout_s: float) -> None:
        if self.version != seen or self.closing:
            return
        with suppress(TimeoutError):
            await asyncio.wait_for(self._changed.wait(), timeout_s)


class Changes:
    """What the page shows, kept between updates, and which HQ victims changed since.

    The console thread's own read connection; ``update`` brings a Page up to date.
    """

    def __init__(self, db: sqlite3.Connection) -> None:
        self._db = db
        self._marks: dict[SourceKey, _Marks] = {}
        self._report_id: int | None = None  # the newest report row seen
        self._sources: dict[SourceKey, Source] = {}
        self._actions: dict[SourceKey, list[Action]] = {}
        self.robot_actions: dict[int, Action] = {}  # each robot's newest looks off/on
        self._notes: dict[int, list[Note]] = {}
        self._pictures: dict[PictureKey, tuple[int, float]] = {}
        self._origins: Origins | None = None
        self._dirty: set[int] = set()  # found changed, not yet rebuilt
        self.victims_built = 0  # HQ victims rebuilt in all (what the incremental saves)

    def update(self, registry: Registry, notes: Notes, page: Page, robots: list[Robot]) -> None:
        """Bring ``page``'s victims up to date (``robots``: the registry's, just read).
        A read that fails (busy) leaves what it found to rebuild for the next update."""
        dirty = self._dirty  # HQ victims to rebuild
        per_robot = {r.sysid: r.origin for r in robots if r.origin is not None}
        origins = Origins(per_robot, registry.default_origin())  # as Registry.origins()
        if origins != self._origins:
            self._origins = origins
            dirty |= {source.hq_id for source in self._sources.values()}
        dirty |= self._sources_changed()
        every = registry.actions()
        self.robot_actions = robot_actions(every)
        actions = actions_by_source(every)
        for key in set(actions) | set(self._actions):
            if actions.get(key) != self._actions.get(key):
                dirty |= self._hq_ids(key)
        self._actions = actions
        by_victim: dict[int, list[Note]] = {}
        for n in notes.all():
            by_victim.setdefault(n.hq_id, []).append(n)
        for hq_id in set(by_victim) | set(self._notes):
            if by_victim.get(hq_id) != self._notes.get(hq_id):
                dirty.add(hq_id)
        self._notes = by_victim
        pictures = registry.picture_versions()
        for shot in set(pictures) | set(self._pictures):
            if pictures.get(shot) != self._pictures.get(shot):
                dirty |= self._hq_ids((shot[0], shot[1]))
        self._pictures = pictures
        if dirty:
            self._rebuild(dirty, page)
            dirty.clear()

    def _hq_ids(self, key: SourceKey) -> set[int]:
        source = self._sources.get(key)
        return set() if source is None else {source.hq_id}

    def _sources_changed(self) -> set[int]:
        """Read the sources touched since the last update; the HQ victims they left
        and joined. A source changes only with a report stored in the same
        transaction (hq.registry), so the reports' AUTOINCREMENT id says which."""
        touched: set[SourceKey] | None = None  # None: all (the first update)
        if self._report_id is not None:
            rows = self._db.execute(
                "SELECT id, robot_sysid, victim_id FROM reports WHERE id > ?", (self._report_id,)
            ).fetchall()
            touched = {(robot, victim) for _, robot, victim in rows}
            newest = max((row_id for row_id, _, _ in rows), default=self._report_id)
        else:
            newest = self._db.execute("SELECT COALESCE(MAX(id), 0) FROM reports").fetchone()[0]
        if touched is not None and not touched:
            return set()
        if touched is None or len(touched) > _FULL_READ:
            rows = self._db.execute(f"SELECT {_SOURCE_COLUMNS} FROM sources").fetchall()
        else:
            rows = []
            for robot, victim in touched:
                rows += self._db.execute(
                    f"SELECT {_SOURCE_COLUMNS} FROM sources WHERE robot_sysid=? AND victim_id=?",
                    (robot, victim),
                ).fetchall()
        dirty = self._dirty  # kept if a later read of this update fails
        for robot, victim, hq_id, payload, seq, merged, updated in rows:
            key, marks = (robot, victim), (hq_id, seq, merged, updated)
            if self._marks.get(key) == marks:
                continue
            self._marks[key] = marks
            dirty |= self._hq_ids(key)  # the HQ victim it was part of
            self._sources.pop(key, None)
            try:
                source = Source(
                    cell_int(hq_id),
                    report_from_payload(payload),
                    cell_int(seq),
                    cell_int(merged),
                    cell_float(updated),
                )
            except (BadRecord, TypeError, ValueError) as exc:  # the HQ's registry says it once
                log.debug("console: source robot %s victim %s skipped: %s", robot, victim, exc)
                continue
            self._sources[key] = source
            dirty.add(source.hq_id)
        self._report_id = int(newest)
        return dirty

    def _rebuild(self, dirty: set[int], page: Page) -> None:
        members = [s for s in self._sources.values() if s.hq_id in dirty]
        keys = {(s.report.robot_sysid, s.report.victim_id) for s in members}
        actions = [a for k in keys for a in self._actions.get(k, [])]
        assert self._origins is not None  # update() set them first
        victims = build(members, actions, self._origins)
        pictures = picture_versions_of(self._pictures, victims)
        for v in victims:
            page.set_victim(
                v,
                victim_actions(v, self._actions),
                self._notes.get(v.hq_id, []),
                pictures.get(v.hq_id, {}),
            )
        self.victims_built += len(victims)
        for hq_id in dirty - {v.hq_id for v in victims}:
            page.drop_victim(hq_id)  # no one left in it (merged away)


class ConsoleDatabase(threading.Thread):
    """The console's database thread: jobs in order, and the watch for news while
    a page watches."""

    def __init__(
        self,
        db_path: Path,
        live: LiveRobots,
        link_timeout_s: float,
        publish: Callable[[str], None],
    ) -> None:
        super().__init__(name="hq-web-db", daemon=True)
        self.db_path = db_path
        self.live = live
        self.link_timeout_s = link_timeout_s
        self._publish = publish
        self._jobs: queue.Queue[_Queued] = queue.Queue()
        self._halt = threading.Event()
        self.opened = threading.Event()
        self.open_error: str | None = None
        self.watchers = 0  # open event streams; set by the web server's event loop
        self.wanted = threading.Event()  # set when a page opens and no current state is held
        self._page = Page()
        self._changes: Changes | None = None
        self._read: sqlite3.Connection | None = None
        self._built_for: tuple[int, int, frozenset[int]] | None = None

    def submit(self, job: Job[T]) -> concurrent.futures.Future[T]:
        future: concurrent.futures.Future[T] = concurrent.futures.Future()
        self._jobs.put((job, future))
        return future

    def stop(self) -> None:
        self._halt.set()

    def run(self) -> None:
        try:
            registry = Registry(self.db_path)
            notes = Notes(self.db_path)
            self._read = sqlite3.connect(
                f"file:{self.db_path}?mode=ro", uri=True, isolation_level=None, timeout=1.5
            )
        except (RegistryError, sqlite3.Error) as exc:
            self.open_error = str(exc)
            self.opened.set()
            return
        self._changes = Changes(self._read)
        self.opened.set()
        try:
            self._loop(registry, notes)
        finally:
            self._read.close()
            notes.close()
            registry.close()

    def _data_version(self) -> int:
        """Moves when any other connection commits: the HQ's, and this thread's own
        registry and notes connections (the pages' writes)."""
        assert self._read is not None
        return int(self._read.execute("PRAGMA data_version").fetchone()[0])

    def _loop(self, registry: Registry, notes: Notes) -> None:
        db_version = live_version = -1
        lost: frozenset[int] = frozenset()
        robots = registry.robots()
        next_tick = last_publish = robots_read = 0.0
        dirty = True
        while not self._halt.is_set():
            try:
                job, future = self._jobs.get(timeout=max(0.0, next_tick - time.monotonic()))
            except queue.Empty:
                pass
            else:
                if future.set_running_or_notify_cancel():
                    try:
                        future.set_result(job(registry, notes))
                    except BaseException as exc:  # handed to the request that asked
                        future.set_exception(exc)
                continue
            now = time.monotonic()
            next_tick = now + _TICK_S
            if self.watchers <= 0:  # no page open: nothing to build
                continue
            try:
                if self.wanted.is_set():  # a page waits for a state: it gets one now
                    self.wanted.clear()
                    dirty, last_publish = True, 0.0
                version = self._data_version()
                if version != db_version:
                    db_version, dirty = version, True
                    if now - robots_read >= _ROBOTS_READ_S:  # for lost links only
                        robots, robots_read = registry.robots(), now
                moved = self.live.version != live_version
                now_lost = robots_lost(robots, self.live, time.time(), self.link_timeout_s)
                if now_lost != lost:
                    lost, dirty = now_lost, True
                since = now - last_publish
                if (dirty and since >= _MIN_PUBLISH_S) or (moved and since >= _MOVED_PUBLISH_S):
                    dirty = False
                    live_version = self.live.version
                    last_publish = now
                    self._publish(self.state_json(registry, notes))
            except (RegistryError, sqlite3.Error) as exc:  # busy or locked: the next tick
                log.debug("console: cannot read the registry: %s", exc)
            except Exception:  # a bug: say so, keep the pages served with the last state
                log.exception("console: cannot build the page state")
                next_tick = time.monotonic() + 1.0

    def state_json(self, registry: Registry, notes: Notes) -> str:
        """The page's whole state, brought up to date from what changed since the last
        build (no build when nothing did). The database thread only."""
        assert self._changes is not None
        now = time.time()
        robots = registry.robots()
        key = (
            self._data_version(),
            self.live.version,
            robots_lost(robots, self.live, now, self.link_timeout_s),
        )
        if key != self._built_for:
            self._changes.update(registry, notes, self._page, robots)
            tracks = self.live.tracks(self._page.paths_held())
            self._page.set_robots(
                robots, tracks, now, self.link_timeout_s, self._changes.robot_actions
            )
            self._page.builds += 1
            self._built_for = key
        return self._page.json(now, self.link_timeout_s)
