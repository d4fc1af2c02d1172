"""What the console's pages are fed: the database thread that watches for news, the hub.

``ConsoleDatabase`` (thread ``hq-web-db``) owns the console's own registry
connection and notes. It runs every database job the pages ask for (actions,
notes, exports) one after the other, and every 0.1 s compares SQLite's
``data_version`` (which moves when the HQ's main thread commits a report, a
status or an acknowledgement), LiveRobots' version (positions) and the set of
robots whose link is lost; on a change it builds the whole page state
(hq.web.state.snapshot) at most every 0.2 s (every 1 s when only robots moved)
and hands it to ``publish``. ``Hub`` lives in the web server's event loop and
holds the latest state for the event streams.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import logging
import queue
import sqlite3
import threading
import time
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import Any, TypeVar

from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.view import HqVictim, hq_victims
from hq.web.notes import Notes
from hq.web.state import LiveRobots, robots_lost, snapshot

log = logging.getLogger(__name__)

_TICK_S = 0.1  # how often the console looks for news in the registry
_MIN_PUBLISH_S = 0.2  # pages get at most 5 states a second
_MOVED_PUBLISH_S = 1.0  # and robots' movements alone at most once a second
T = TypeVar("T")
Job = Callable[[Registry, Notes], T]
_Queued = tuple[Callable[[Registry, Notes], Any], "concurrent.futures.Future[Any]"]


def picture_versions(registry: Registry, victims: list[HqVictim]) -> dict[int, str]:
    """The version of each HQ victim's evidence picture (the newest received among
    its robots' pictures): ``robot-victim-picture_id``, so a better picture is a new
    address and the browser fetches it."""
    stored = registry.picture_versions()
    out: dict[int, str] = {}
    for v in victims:
        held = [(stored[s][1], s, stored[s][0]) for s in v.sources if s in stored]
        if held:
            _, (robot, victim_id), picture_id = max(held)
            out[v.hq_id] = f"{robot}-{victim_id}-{picture_id}"
    return out


def picture_job(hq_id: int, version: str | None) -> Job[bytes | None]:
    """The JPEG of an HQ victim's picture: the version asked for when given (and
    still one of its robots'), else the newest; None when there is none."""

    def job(registry: Registry, _notes: Notes) -> bytes | None:
        victim = next((v for v in hq_victims(registry) if v.hq_id == hq_id), None)
        if victim is None:
            return None
        versions = picture_versions(registry, [victim])
        key = versions.get(hq_id)
        if key is None:
            return None
        if version is not None:
            robot, victim_id, _ = (int(x) for x in version.split("-"))
            if (robot, victim_id) in victim.sources:
                return registry.picture(robot, victim_id)
        robot, victim_id, _ = (int(x) for x in key.split("-"))
        return registry.picture(robot, victim_id)

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

    def close(self) -> None:
        self.closing = True
        self._changed.set()

    async def wait(self, seen: int, timeout_s: float) -> None:
        if self.version != seen or self.closing:
            return
        with suppress(TimeoutError):
            await asyncio.wait_for(self._changed.wait(), timeout_s)


class ConsoleDatabase(threading.Thread):
    """The console's database thread: jobs in order, and the watch for news."""

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
        self._dirty = True

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
        except (RegistryError, sqlite3.Error) as exc:
            self.open_error = str(exc)
            self.opened.set()
            return
        self.opened.set()
        try:
            self._loop(registry, notes)
        finally:
            notes.close()
            registry.close()

    def _loop(self, registry: Registry, notes: Notes) -> None:
        db_version = live_version = -1
        lost: frozenset[int] = frozenset()
        robots = registry.robots()
        next_tick = last_publish = 0.0
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
                self._dirty = True
                continue
            now = time.monotonic()
            next_tick = now + _TICK_S
            try:
                version = registry.data_version()
                if version != db_version:
                    db_version, self._dirty = version, True
                    robots = registry.robots()
                moved = self.live.version != live_version
                now_lost = robots_lost(robots, self.live, time.time(), self.link_timeout_s)
                if now_lost != lost:
                    lost, self._dirty = now_lost, True
                since = now - last_publish
                if (self._dirty and since >= _MIN_PUBLISH_S) or (
                    moved and since >= _MOVED_PUBLISH_S
                ):
                    self._dirty = False
                    live_version = self.live.version
                    last_publish = now
                    self._publish(self.state_json(registry, notes))
            except (RegistryError, sqlite3.Error) as exc:  # busy or locked: the next tick
                log.debug("console: cannot read the registry: %s", exc)
            except Exception:  # a bug: say so, keep the pages served with the last state
                log.exception("console: cannot build the page state")
                next_tick = time.monotonic() + 1.0

    def state_json(self, registry: Registry, notes: Notes) -> str:
        victims = hq_victims(registry)
        state = snapshot(
            victims,
            registry.robots(),
            registry.actions(),
            notes.all(),
            self.live.tracks(),
            picture_versions(registry, victims),
            time.time(),
            self.link_timeout_s,
        )
        return json.dumps(state, separators=(",", ":"))
