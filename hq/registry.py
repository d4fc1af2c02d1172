"""The HQ's durable registry of victims: one SQLite file (WAL, synchronous=FULL).

Tables:
    meta        schema version, the operator's default EKF origin
    reports     every report ever accepted, verbatim (nothing received is lost)
    sources     the latest state of each (robot, victim_id), and the HQ victim it is in
    hq_victims  HQ victim IDs (a group of sources: one person seen by several robots)
    robots      every robot heard (sysid), its last status and its EKF origin
    actions     operator actions (rescued, false alarm), their action_seq and ack time
    pictures    the newest evidence picture (JPEG) of each (robot, victim_id)

A batch of reports is written in one transaction; the caller acknowledges only
after ``store_reports`` returned, i.e. after the commit reached the disk: nothing
acknowledged is ever lost. A report is a duplicate when (robot, report_seq,
victim_id, report time) was stored before. An older report (by report_seq, then
report time) than the one a source holds is stored but does not change the source.

Errors: ``RegistryError`` (cannot open: corrupt, not SQLite, locked, foreign schema)
names the file; ``RegistryBusy`` (a write could not get the lock in time);
``RegistryFull`` (the disk is full). A failed write leaves nothing of itself behind
and the registry usable: the next write, once space returns, works.
"""

from __future__ import annotations

import contextlib
import json
import logging
import sqlite3
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict
from pathlib import Path

from fusion.types import GlobalOrigin, TrackState
from hq import epoch, merge
from hq.errors import HqError
from hq.merge import Origins, Placed, placed
from hq.records import (
    Action,
    BadRecord,
    IncomingReport,
    OperatorAction,
    Robot,
    RobotStatus,
    Source,
    StoreResult,
    check_origin,
    check_picture,
    report_from_payload,
    report_payload,
)

log = logging.getLogger(__name__)

SCHEMA_VERSION = 3  # 2: actions.ack_result; 3: pictures
# From version: SQL. The pictures table of version 3 is created by _SCHEMA itself.
_MIGRATIONS: dict[int, tuple[str, ...]] = {
    1: ("ALTER TABLE actions ADD COLUMN ack_result INTEGER",),
    2: (),
}
# action_seq never counts below the seconds since this instant (see _seed_action_seq).
_ACTION_SEQ_EPOCH_UNIX_S = 1_735_689_600  # 2025-01-01T00:00:00Z
_ACTION_SEQ_TICKS_PER_S = 4  # the clock floor counts quarter seconds: uint32 lasts until 2059
_MAX_ACTION_SEQ = 0xFFFFFFFF  # RESCUE_OPERATOR_ACTION.action_seq is a uint32
_ACTION_SEQ_HEADROOM = 1 << 24  # numbers left above the highest clock floor
_BUSY_TIMEOUT_MS = 1500  # a concurrent `rescue-hq mark` holds the lock for milliseconds

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS reports (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    robot_sysid INTEGER NOT NULL, report_seq INTEGER NOT NULL, victim_id INTEGER NOT NULL,
    report_time_usec INTEGER NOT NULL, src_compid INTEGER NOT NULL,
    received_unix_s REAL NOT NULL, applied INTEGER NOT NULL, payload TEXT NOT NULL,
    UNIQUE (robot_sysid, report_seq, victim_id, report_time_usec)
);
CREATE TABLE IF NOT EXISTS hq_victims (
    hq_id INTEGER PRIMARY KEY AUTOINCREMENT, created_unix_s REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS sources (
    robot_sysid INTEGER NOT NULL, victim_id INTEGER NOT NULL,
    hq_id INTEGER NOT NULL REFERENCES hq_victims(hq_id),
    report_seq INTEGER NOT NULL, report_time_usec INTEGER NOT NULL,
    merged_into_id INTEGER NOT NULL, updated_unix_s REAL NOT NULL, payload TEXT NOT NULL,
    PRIMARY KEY (robot_sysid, victim_id)
);
CREATE TABLE IF NOT EXISTS robots (
    sysid INTEGER PRIMARY KEY, compid INTEGER NOT NULL,
    first_heard_unix_s REAL NOT NULL, last_heard_unix_s REAL NOT NULL,
    status TEXT, status_unix_s REAL,
    origin_lat_deg REAL, origin_lon_deg REAL, origin_alt_m REAL
);
CREATE TABLE IF NOT EXISTS actions (
    action_seq INTEGER PRIMARY KEY AUTOINCREMENT,
    robot_sysid INTEGER NOT NULL, victim_id INTEGER NOT NULL, action INTEGER NOT NULL,
    created_unix_s REAL NOT NULL, sent_count INTEGER NOT NULL DEFAULT 0,
    last_sent_unix_s REAL, acked_unix_s REAL, ack_result INTEGER
);
CREATE TABLE IF NOT EXISTS pictures (
    robot_sysid INTEGER NOT NULL, victim_id INTEGER NOT NULL,
    picture_id INTEGER NOT NULL, received_unix_s REAL NOT NULL, jpeg BLOB NOT NULL,
    PRIMARY KEY (robot_sysid, victim_id)
);
"""


class RegistryError(HqError):
    """The registry file cannot be used; the message names the file."""


class RegistryBusy(RegistryError):
    """A write did not get the database lock in time; nothing was stored."""


class RegistryCorrupt(RegistryError):
    """The file is damaged (not SQLite, malformed, or emptied); `run` moves it aside."""


class RegistryFull(RegistryError):
    """The disk is full; nothing of the write was stored."""


class Registry:
    """The SQLite registry. One instance per thread (sqlite3 connections are not shared)."""

    def __init__(self, path: Path, *, busy_timeout_ms: int = _BUSY_TIMEOUT_MS) -> None:
        self.path = path
        self._cache: dict[tuple[int, int], tuple[int, Placed]] | None = None
        self._origins_cache: Origins | None = None
        self.bad_rows: set[str] = set()  # unusable rows found while reading, said once each
        self.epoch = 1
        if path.is_file() and path.stat().st_size == 0:
            raise RegistryCorrupt(f"database {path} is empty (0 bytes): its contents were lost")
        try:
            self._db = sqlite3.connect(
                str(path), isolation_level=None, timeout=busy_timeout_ms / 1000.0
            )
        except sqlite3.Error as exc:
            raise RegistryError(f"database {path}: cannot open: {exc}") from None
        try:
            self._setup()
        except sqlite3.DatabaseError as exc:
            self._db.close()
            code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
            damaged = code in (sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_NOTADB)
            kind = RegistryCorrupt if damaged else RegistryError
            raise kind(f"database {path}: {_describe(exc)}") from None
        except RegistryError:
            self._db.close()
            raise

    def _setup(self) -> None:
        db = self._db
        # Text that is not UTF-8 (a damaged file) reads as U+FFFD and then fails its
        # check, instead of raising out of a whole query.
        db.text_factory = lambda raw: raw.decode("utf-8", "replace")
        db.execute("PRAGMA journal_mode=WAL")
        # FULL: a commit is on the disk before we acknowledge, even across a power cut.
        db.execute("PRAGMA synchronous=FULL")
        db.execute("PRAGMA foreign_keys=ON")
        row = db.execute("PRAGMA quick_check").fetchone()
        if row is None or row[0] != "ok":
            raise RegistryCorrupt(f"database {self.path}: integrity check failed: {row}")
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if tables and "meta" not in tables:
            raise RegistryError(
                f"database {self.path}: not a rescue-hq registry (tables: {sorted(tables)})"
            )
        db.execute("BEGIN IMMEDIATE")
        try:
            for statement in _SCHEMA.split(";"):
                if statement.strip():
                    db.execute(statement)
            version = db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
            if version is None:
                db.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
                self._start_epoch(epoch.last_epoch(self.path) + 1)
            elif int(version[0]) in _MIGRATIONS:
                for old in range(int(version[0]), SCHEMA_VERSION):
                    for statement in _MIGRATIONS[old]:
                        db.execute(statement)
                db.execute(
                    "UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION),)
                )
            elif int(version[0]) != SCHEMA_VERSION:
                raise RegistryError(
                    f"database {self.path}: schema version {version[0]}, "
                    f"this rescue-hq knows {SCHEMA_VERSION}"
                )
            row = db.execute("SELECT value FROM meta WHERE key='epoch'").fetchone()
            self.epoch = 1 if row is None else int(row[0])  # no epoch yet: an older registry
            epoch.record(self.path, epoch=self.epoch)  # a lost epoch file is written again
            db.execute("COMMIT")
        except epoch.EpochError as exc:
            self._rollback()
            raise RegistryError(str(exc)) from None
        except BaseException:
            self._rollback()
            raise

    def _start_epoch(self, number: int) -> None:
        """A new registry: HQ victim IDs from epoch ``number``'s first ID on.

        The epoch file is written before this transaction commits, so an epoch
        whose IDs were handed out is always on record.
        """
        self._db.execute("INSERT INTO meta VALUES ('epoch', ?)", (str(number),))
        self._db.execute(
            "INSERT INTO sqlite_sequence (name, seq) VALUES ('hq_victims', ?)",
            (epoch.first_id(number) - 1,),
        )
        epoch.record(self.path, epoch=number)

    def _seed_action_seq(self) -> None:
        """Make the next action_seq above every one given out before.

        A robot drops an action_seq it has seen from this HQ as a duplicate. Within
        one registry AUTOINCREMENT never goes back. At the same path, the epoch file
        records the highest number given out (hq.epoch), which survives a lost or
        corrupt registry. Across paths (another --db), the HQ's clock in quarter
        seconds since 2025 keeps numbers apart, unless the other registry numbered
        faster than four actions a second, or the clock went back.
        """
        ticks = int((time.time() - _ACTION_SEQ_EPOCH_UNIX_S) * _ACTION_SEQ_TICKS_PER_S)
        # A clock gone wild is ignored beyond the headroom kept for counting on.
        floor = max(0, min(ticks, _MAX_ACTION_SEQ - _ACTION_SEQ_HEADROOM))
        floor = max(floor, epoch.read(self.path).action_seq)
        row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name='actions'").fetchone()
        if row is None:
            self._db.execute(
                "INSERT INTO sqlite_sequence (name, seq) VALUES ('actions', ?)", (floor,)
            )
        elif int(row[0]) < floor:
            self._db.execute("UPDATE sqlite_sequence SET seq=? WHERE name='actions'", (floor,))

    def close(self) -> None:
        db = getattr(self, "_db", None)
        if db is not None:
            self._db = None  # type: ignore[assignment]
            db.close()

    def __enter__(self) -> Registry:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------

    @contextlib.contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction: committed when the block ends, rolled back on any error.

        SQLite errors become RegistryBusy (locked), RegistryFull (disk full) or
        RegistryError; nothing of the block is stored then. SQLite may already have
        rolled back by itself (it does on SQLITE_FULL), so the rollback is only
        attempted inside a transaction.
        """
        try:
            self._db.execute("BEGIN IMMEDIATE")
        except sqlite3.Error as exc:
            raise self._failure(exc) from None
        try:
            yield self._db
            self._db.execute("COMMIT")
        except sqlite3.Error as exc:
            self._rollback()
            raise self._failure(exc) from None
        except BaseException:
            self._rollback()
            raise

    def _rollback(self) -> None:
        if not self._db.in_transaction:
            return
        try:
            self._db.execute("ROLLBACK")
        except sqlite3.Error as exc:  # nothing more to undo; the connection stays usable
            log.warning("database %s: rollback failed: %s", self.path, exc)

    def _failure(self, exc: sqlite3.Error) -> RegistryError:
        code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
        text = str(exc)
        if code == sqlite3.SQLITE_FULL or "disk is full" in text:
            return RegistryFull(f"database {self.path}: the disk is full ({text})")
        if code in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED) or "locked" in text:
            return RegistryBusy(f"database {self.path} is locked: {text}")
        return RegistryError(f"database {self.path}: {text}")

    def store_reports(self, batch: Sequence[IncomingReport]) -> list[StoreResult]:
        """Store a batch durably (one transaction); the result of each, in order.

        Raises RegistryBusy (the lock was not free in time) or RegistryFull (the
        disk is full); nothing of the batch is stored then.
        """
        if not batch:
            return []
        try:
            with self._write():
                return [self._store_one(item) for item in batch]
        except BaseException:
            self._forget_cache()  # it may hold sources of the rolled-back batch
            raise

    def _store_one(self, item: IncomingReport) -> StoreResult:
        r = item.report
        db = self._db
        self._touch_robot(r.robot_sysid, item.src_compid, item.received_unix_s)
        cur = db.execute(
            "INSERT OR IGNORE INTO reports (robot_sysid, report_seq, victim_id, report_time_usec,"
            " src_compid, received_unix_s, applied, payload) VALUES (?, ?, ?, ?, ?, ?, 0, ?)",
            (
                r.robot_sysid,
                item.report_seq,
                r.victim_id,
                item.report_time_usec,
                item.src_compid,
                item.received_unix_s,
                report_payload(r),
            ),
        )
        if cur.rowcount == 0:
            return StoreResult.DUPLICATE
        report_row = cur.lastrowid
        held = db.execute(
            "SELECT report_time_usec, report_seq, hq_id FROM sources"
            " WHERE robot_sysid=? AND victim_id=?",
            (r.robot_sysid, r.victim_id),
        ).fetchone()
        # Newer means a higher report_seq (the robot's own monotonic count); its wall
        # clock only breaks ties, so a clock step cannot reorder a robot's reports.
        if held is not None and (item.report_seq, item.report_time_usec) <= (held[1], held[0]):
            return StoreResult.STALE
        hq_id = self._place(item, None if held is None else int(held[2]))
        db.execute(
            "INSERT OR REPLACE INTO sources (robot_sysid, victim_id, hq_id, report_seq,"
            " report_time_usec, merged_into_id, updated_unix_s, payload)"
            " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (
                r.robot_sysid,
                r.victim_id,
                hq_id,
                item.report_seq,
                item.report_time_usec,
                item.merged_into_id,
                item.received_unix_s,
                report_payload(r),
            ),
        )
        db.execute("UPDATE reports SET applied=1 WHERE id=?", (report_row,))
        cache = self._placed_sources()
        if r.state == TrackState.MERGED:
            cache.pop((r.robot_sysid, r.victim_id), None)
        else:
            cache[(r.robot_sysid, r.victim_id)] = (
                hq_id,
                placed(r, self._origins_cache or self.origins()),
            )
        return StoreResult.ACCEPTED

    def _placed_sources(self) -> dict[tuple[int, int], tuple[int, Placed]]:
        """(robot, victim) -> (HQ ID, position) of every unmerged source, kept in memory.

        Only the HQ process writes sources; the cache is dropped on a rollback and
        when an origin changes, and rebuilt from the database on next use.
        """
        if self._cache is None:
            self._origins_cache = self.origins()
            self._cache = {
                (s.report.robot_sysid, s.report.victim_id): (
                    s.hq_id,
                    placed(s.report, self._origins_cache),
                )
                for s in self.sources()
                if s.report.state != TrackState.MERGED
            }
        return self._cache

    def _forget_cache(self) -> None:
        self._cache = None
        self._origins_cache = None

    def _place(self, item: IncomingReport, current: int | None) -> int:
        """The HQ victim ID for this report's source (creating one when needed)."""
        r = item.report
        if r.state == TrackState.MERGED and item.merged_into_id:
            target = self._db.execute(
                "SELECT hq_id FROM sources WHERE robot_sysid=? AND victim_id=?",
                (r.robot_sysid, item.merged_into_id),
            ).fetchone()
            if target is not None:
                return int(target[0])
        if r.state != TrackState.MERGED:
            cache = self._placed_sources()
            candidate = placed(r, self._origins_cache or self.origins())
            groups: dict[int, list[Placed]] = {}
            for hq_id, p in cache.values():
                groups.setdefault(hq_id, []).append(p)
            chosen = merge.assign(candidate, current, groups)
            if chosen is not None:
                if chosen != current:
                    log.info(
                        "robot %d victim %d is HQ victim %d", r.robot_sysid, r.victim_id, chosen
                    )
                return chosen
        elif current is not None:
            return current
        cur = self._db.execute(
            "INSERT INTO hq_victims (created_unix_s) VALUES (?)", (item.received_unix_s,)
        )
        assert cur.lastrowid is not None  # sqlite3 sets it after an INSERT
        if cur.lastrowid >= epoch.first_id(self.epoch + 1):
            raise RegistryError(
                f"database {self.path}: HQ victim IDs of epoch {self.epoch} used up"
            )
        return int(cur.lastrowid)

    def _touch_robot(self, sysid: int, compid: int, now_unix_s: float) -> None:
        cur = self._db.execute(
            "UPDATE robots SET last_heard_unix_s=?, compid=? WHERE sysid=?",
            (now_unix_s, compid, sysid),
        )
        if cur.rowcount == 0:
            log.warning("new robot: system ID %d (component %d)", sysid, compid)
            self._db.execute(
                "INSERT INTO robots (sysid, compid, first_heard_unix_s, last_heard_unix_s)"
                " VALUES (?, ?, ?, ?)",
                (sysid, compid, now_unix_s, now_unix_s),
            )

    def store_status(self, sysid: int, compid: int, status: RobotStatus, now_unix_s: float) -> None:
        with self._write() as db:
            self._touch_robot(sysid, compid, now_unix_s)
            db.execute(
                "UPDATE robots SET status=?, status_unix_s=? WHERE sysid=?",
                (status.to_json(), now_unix_s, sysid),
            )

    def set_robot_origin(self, sysid: int, compid: int, origin: GlobalOrigin) -> None:
        self._forget_cache()
        with self._write() as db:
            self._touch_robot(sysid, compid, time.time())
            db.execute(
                "UPDATE robots SET origin_lat_deg=?, origin_lon_deg=?, origin_alt_m=?"
                " WHERE sysid=?",
                (origin.lat_deg, origin.lon_deg, origin.alt_m, sysid),
            )

    def set_default_origin(self, origin: GlobalOrigin | None) -> None:
        value = None if origin is None else json.dumps(asdict(origin))
        self._forget_cache()
        with self._write() as db:
            if value is None:
                db.execute("DELETE FROM meta WHERE key='default_origin'")
            else:
                db.execute("INSERT OR REPLACE INTO meta VALUES ('default_origin', ?)", (value,))

    def add_action(self, robot_sysid: int, victim_id: int, action: OperatorAction) -> int:
        """Record an operator action; its action_seq. KeyError for an unknown victim."""
        with self._write() as db:
            known = db.execute(
                "SELECT 1 FROM sources WHERE robot_sysid=? AND victim_id=?",
                (robot_sysid, victim_id),
            ).fetchone()
            if known is None:
                raise KeyError(f"robot {robot_sysid} has reported no victim {victim_id}")
            self._seed_action_seq()
            cur = db.execute(
                "INSERT INTO actions (robot_sysid, victim_id, action, created_unix_s)"
                " VALUES (?, ?, ?, ?)",
                (robot_sysid, victim_id, action.value, time.time()),
            )
            if cur.lastrowid is None or cur.lastrowid > _MAX_ACTION_SEQ:
                raise RegistryError(f"database {self.path}: action numbers exhausted")
            try:  # on record before the action exists (this transaction commits)
                epoch.record(self.path, action_seq=cur.lastrowid)
            except epoch.EpochError as exc:
                raise RegistryError(str(exc)) from None
        return int(cur.lastrowid)

    def note_action_sent(self, action_seq: int, now_unix_s: float) -> None:
        with self._write() as db:
            db.execute(
                "UPDATE actions SET sent_count=sent_count+1, last_sent_unix_s=? WHERE action_seq=?",
                (now_unix_s, action_seq),
            )

    def ack_action(self, action_seq: int, now_unix_s: float, result: int) -> bool:
        """Record the robot's answer to an action; False when unknown or already answered."""
        with self._write() as db:
            cur = db.execute(
                "UPDATE actions SET acked_unix_s=?, ack_result=? WHERE action_seq=?"
                " AND acked_unix_s IS NULL",
                (now_unix_s, result, action_seq),
            )
        return cur.rowcount == 1

    # -- evidence pictures (one per robot's victim: the newest picture_id) ----------------

    def store_picture(
        self, robot_sysid: int, victim_id: int, picture_id: int, jpeg: bytes, now_unix_s: float
    ) -> bool:
        """Keep a robot's picture of its victim unless one as new (same or higher
        picture_id) is stored; True when stored. RegistryError as for reports."""
        with self._write() as db:
            cur = db.execute(
                "INSERT INTO pictures (robot_sysid, victim_id, picture_id, received_unix_s, jpeg)"
                " VALUES (?, ?, ?, ?, ?) ON CONFLICT (robot_sysid, victim_id) DO UPDATE SET"
                " picture_id=excluded.picture_id, received_unix_s=excluded.received_unix_s,"
                " jpeg=excluded.jpeg WHERE excluded.picture_id > pictures.picture_id",
                (robot_sysid, victim_id, picture_id, now_unix_s, jpeg),
            )
        return cur.rowcount == 1

    def picture_id(self, robot_sysid: int, victim_id: int) -> int | None:
        """The stored picture's number for this robot's victim, None without one."""
        row = self._db.execute(
            "SELECT picture_id FROM pictures WHERE robot_sysid=? AND victim_id=?",
            (robot_sysid, victim_id),
        ).fetchone()
        return None if row is None else int(row[0])

    def picture_versions(self) -> dict[tuple[int, int], tuple[int, float]]:
        """(picture_id, received time) of every stored picture by (robot, victim)."""
        rows = self._db.execute(
            "SELECT robot_sysid, victim_id, picture_id, received_unix_s FROM pictures"
        ).fetchall()
        return {(int(r), int(v)): (int(p), float(t)) for r, v, p, t in rows}

    def picture(self, robot_sysid: int, victim_id: int) -> bytes | None:
        """The stored JPEG, None without one or when the row is unusable (said once)."""
        row = self._db.execute(
            "SELECT jpeg FROM pictures WHERE robot_sysid=? AND victim_id=?",
            (robot_sysid, victim_id),
        ).fetchone()
        if row is None:
            return None
        try:
            return check_picture(row[0])
        except BadRecord as exc:
            self._bad_row(f"pictures robot {robot_sysid} victim {victim_id}", exc)
            return None

    def data_version(self) -> int:
        """Changes whenever another connection commits (cheap; see PRAGMA data_version)."""
        return int(self._db.execute("PRAGMA data_version").fetchone()[0])

    def sources(self) -> list[Source]:
        """Every usable source; a row that does not check (see hq.records) is skipped, said once."""
        rows = self._db.execute(
            "SELECT robot_sysid, victim_id, hq_id, payload, report_seq, merged_into_id,"
            " updated_unix_s FROM sources ORDER BY hq_id, robot_sysid, victim_id"
        ).fetchall()
        out = []
        for robot, victim, h, p, s, m, u in rows:
            try:
                out.append(Source(int(h), report_from_payload(p), int(s), int(m), float(u)))
            except (BadRecord, TypeError, ValueError) as exc:
                self._bad_row(f"sources robot {robot} victim {victim}", exc)
        return out

    def _bad_row(self, where: str, exc: Exception) -> None:
        """Say once per row that it is unusable and count it; the row stays in the file."""
        if where not in self.bad_rows:
            self.bad_rows.add(where)
            log.error("database %s: %s is unusable and ignored: %s", self.path, where, exc)

    def first_received_unix_s(self) -> dict[tuple[int, int], float]:
        """When the first report of each (robot sysid, robot's victim id) arrived."""
        rows = self._db.execute(
            "SELECT robot_sysid, victim_id, MIN(received_unix_s) FROM reports"
            " GROUP BY robot_sysid, victim_id"
        ).fetchall()
        return {(int(r), int(v)): float(t) for r, v, t in rows}

    def report_count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM reports").fetchone()[0])

    def actions(self, *, pending_only: bool = False) -> list[Action]:
        sql = (
            "SELECT action_seq, robot_sysid, victim_id, action, created_unix_s, sent_count,"
            " acked_unix_s, ack_result FROM actions"
        )
        if pending_only:
            sql += " WHERE acked_unix_s IS NULL"
        rows = self._db.execute(sql + " ORDER BY action_seq").fetchall()
        out = []
        for a, r, v, k, c, n, ack, result in rows:
            try:
                acked = None if ack is None else float(ack)
                answer = None if result is None else int(result)
                out.append(
                    Action(
                        int(a),
                        int(r),
                        int(v),
                        OperatorAction(int(k)),
                        float(c),
                        int(n),
                        acked,
                        answer,
                    )
                )
            except (TypeError, ValueError) as exc:
                self._bad_row(f"action {a}", exc)
        return out

    def robots(self) -> list[Robot]:
        rows = self._db.execute(
            "SELECT sysid, compid, first_heard_unix_s, last_heard_unix_s, status, status_unix_s,"
            " origin_lat_deg, origin_lon_deg, origin_alt_m FROM robots ORDER BY sysid"
        ).fetchall()
        out = []
        for sysid, compid, first, last, status, status_t, lat, lon, alt in rows:
            origin = parsed = None
            try:
                if lat is not None:
                    origin = check_origin(GlobalOrigin(float(lat), float(lon), float(alt)))
            except (TypeError, ValueError) as exc:
                self._bad_row(f"origin of robot {sysid}", exc)
            try:
                parsed = RobotStatus.from_json(status) if status else None
            except BadRecord as exc:
                self._bad_row(f"status of robot {sysid}", exc)
            try:
                out.append(
                    Robot(
                        int(sysid),
                        int(compid),
                        float(first),
                        float(last),
                        parsed,
                        None if status_t is None else float(status_t),
                        origin,
                    )
                )
            except (TypeError, ValueError) as exc:
                self._bad_row(f"robot {sysid}", exc)
        return out

    def default_origin(self) -> GlobalOrigin | None:
        row = self._db.execute("SELECT value FROM meta WHERE key='default_origin'").fetchone()
        if row is None:
            return None
        try:
            return check_origin(GlobalOrigin(**json.loads(row[0])))
        except (TypeError, ValueError) as exc:
            self._bad_row("the default origin", exc)
            return None

    def origins(self) -> Origins:
        per_robot = {r.sysid: r.origin for r in self.robots() if r.origin is not None}
        return Origins(per_robot, self.default_origin())


def _describe(exc: sqlite3.DatabaseError) -> str:
    text = str(exc)
    if "not a database" in text or "malformed" in text:
        return f"{text} (corrupt, or not a SQLite file)"
    if "locked" in text or "busy" in text:
        return f"{text} (another process holds it; is another rescue-hq running?)"
    return text
