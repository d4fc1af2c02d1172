"""The HQ's durable registry of victims: one SQLite file (WAL, synchronous=FULL).

Tables:
    meta        schema version, the operator's default EKF origin
    reports     every report ever accepted, verbatim (nothing received is lost)
    sources     the latest state of each (robot, victim_id), and the HQ victim it is in
    hq_victims  HQ victim IDs (a group of sources: one person seen by several robots)
    robots      every robot heard (sysid), its last status and its EKF origin
    actions     operator actions (rescued, false alarm), their action_seq and ack time

A batch of reports is written in one transaction; the caller acknowledges only
after ``store_reports`` returned, i.e. after the commit reached the disk: nothing
acknowledged is ever lost. A report is a duplicate when (robot, report_seq,
victim_id, report time) was stored before. An older report (by report time, then
report_seq) than the one a source holds is stored but does not change the source.

Errors: ``RegistryError`` (cannot open: corrupt, not SQLite, locked, foreign schema)
names the file; ``RegistryBusy`` (a write could not get the lock in time).
"""

from __future__ import annotations

import json
import logging
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from enum import Enum
from pathlib import Path

from fusion.geodesy import ned_to_geodetic
from fusion.types import GlobalOrigin, TrackState, Urgency, VictimReport
from hq import merge
from hq.merge import Geo, Placed

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
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
    last_sent_unix_s REAL, acked_unix_s REAL
);
"""


class RegistryError(Exception):
    """The registry file cannot be used; the message names the file."""


class RegistryBusy(RegistryError):
    """A write did not get the database lock in time; nothing was stored."""


class StoreResult(Enum):
    ACCEPTED = "accepted"  # new, stored, and the newest state of its victim
    STALE = "stale"  # new and stored, but older than what the victim already holds
    DUPLICATE = "duplicate"  # stored before


class OperatorAction(Enum):
    """Values match RESCUE_OPERATOR_ACTION_TYPE."""

    RESCUED = 1
    FALSE_ALARM = 2
    CONFIRMED = 4  # the operator saw the evidence: a real person (reopens a resolved one)


@dataclass(frozen=True)
class IncomingReport:
    report: VictimReport
    report_seq: int
    report_time_usec: int
    merged_into_id: int
    src_compid: int
    received_unix_s: float


@dataclass(frozen=True)
class Action:
    action_seq: int
    robot_sysid: int
    victim_id: int
    action: OperatorAction
    created_unix_s: float
    sent_count: int
    acked_unix_s: float | None


@dataclass(frozen=True)
class Source:
    hq_id: int
    report: VictimReport
    report_seq: int
    merged_into_id: int
    updated_unix_s: float


@dataclass(frozen=True)
class Robot:
    sysid: int
    compid: int
    first_heard_unix_s: float
    last_heard_unix_s: float
    status: dict[str, float] | None
    status_unix_s: float | None
    origin: GlobalOrigin | None


def _payload(report: VictimReport) -> str:
    d = asdict(report)
    d["state"] = int(report.state)
    d["urgency"] = int(report.urgency)
    return json.dumps(d)


def _report(payload: str) -> VictimReport:
    d = json.loads(payload)
    d["state"] = TrackState(d["state"])
    d["urgency"] = Urgency(d["urgency"])
    (a, b), (c, e) = d["cov_ne_m2"]
    d["cov_ne_m2"] = ((a, b), (c, e))
    return VictimReport(**d)


def _is_lock_error(exc: sqlite3.OperationalError) -> bool:
    text = str(exc).lower()
    return "locked" in text or "busy" in text


class Registry:
    """The SQLite registry. One instance per thread (sqlite3 connections are not shared)."""

    def __init__(self, path: Path, *, busy_timeout_ms: int = _BUSY_TIMEOUT_MS) -> None:
        self.path = path
        self._cache: dict[tuple[int, int], tuple[int, Placed]] | None = None
        self._origins_cache: Origins | None = None
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
            raise RegistryError(f"database {path}: {_describe(exc)}") from None
        except RegistryError:
            self._db.close()
            raise

    def _setup(self) -> None:
        db = self._db
        db.execute("PRAGMA journal_mode=WAL")
        # FULL: a commit is on the disk before we acknowledge, even across a power cut.
        db.execute("PRAGMA synchronous=FULL")
        db.execute("PRAGMA foreign_keys=ON")
        row = db.execute("PRAGMA quick_check").fetchone()
        if row is None or row[0] != "ok":
            raise RegistryError(f"database {self.path}: integrity check failed: {row}")
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
            elif int(version[0]) != SCHEMA_VERSION:
                raise RegistryError(
                    f"database {self.path}: schema version {version[0]}, "
                    f"this rescue-hq knows {SCHEMA_VERSION}"
                )
            db.execute("COMMIT")
        except BaseException:
            db.execute("ROLLBACK")
            raise

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

    def _begin(self) -> None:
        try:
            self._db.execute("BEGIN IMMEDIATE")
        except sqlite3.OperationalError as exc:
            if _is_lock_error(exc):
                raise RegistryBusy(f"database {self.path} is locked: {exc}") from None
            raise RegistryError(f"database {self.path}: {exc}") from None

    def _commit(self) -> None:
        try:
            self._db.execute("COMMIT")
        except sqlite3.OperationalError as exc:
            self._db.execute("ROLLBACK")
            if _is_lock_error(exc):
                raise RegistryBusy(f"database {self.path} is locked: {exc}") from None
            raise RegistryError(f"database {self.path}: {exc}") from None

    def store_reports(self, batch: Sequence[IncomingReport]) -> list[StoreResult]:
        """Store a batch durably (one transaction); the result of each, in order.

        Raises RegistryBusy (nothing stored) when the lock is not free in time.
        """
        if not batch:
            return []
        self._begin()
        try:
            results = [self._store_one(item) for item in batch]
        except sqlite3.OperationalError as exc:
            self._forget_cache()
            self._db.execute("ROLLBACK")
            if _is_lock_error(exc):
                raise RegistryBusy(f"database {self.path} is locked: {exc}") from None
            raise RegistryError(f"database {self.path}: {exc}") from None
        except BaseException:
            self._forget_cache()
            self._db.execute("ROLLBACK")
            raise
        try:
            self._commit()
        except RegistryError:
            self._forget_cache()
            raise
        return results

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
                _payload(r),
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
        if held is not None and (item.report_time_usec, item.report_seq) <= (held[0], held[1]):
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
                _payload(r),
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

    def store_status(
        self, sysid: int, compid: int, status: dict[str, float], now_unix_s: float
    ) -> None:
        self._begin()
        try:
            self._touch_robot(sysid, compid, now_unix_s)
            self._db.execute(
                "UPDATE robots SET status=?, status_unix_s=? WHERE sysid=?",
                (json.dumps(status), now_unix_s, sysid),
            )
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._commit()

    def set_robot_origin(self, sysid: int, compid: int, origin: GlobalOrigin) -> None:
        self._forget_cache()
        self._begin()
        try:
            self._touch_robot(sysid, compid, time.time())
            self._db.execute(
                "UPDATE robots SET origin_lat_deg=?, origin_lon_deg=?, origin_alt_m=?"
                " WHERE sysid=?",
                (origin.lat_deg, origin.lon_deg, origin.alt_m, sysid),
            )
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._commit()

    def set_default_origin(self, origin: GlobalOrigin | None) -> None:
        value = None if origin is None else json.dumps(asdict(origin))
        self._forget_cache()
        self._begin()
        if value is None:
            self._db.execute("DELETE FROM meta WHERE key='default_origin'")
        else:
            self._db.execute("INSERT OR REPLACE INTO meta VALUES ('default_origin', ?)", (value,))
        self._commit()

    def add_action(self, robot_sysid: int, victim_id: int, action: OperatorAction) -> int:
        """Record an operator action; its action_seq. KeyError for an unknown victim."""
        self._begin()
        try:
            known = self._db.execute(
                "SELECT 1 FROM sources WHERE robot_sysid=? AND victim_id=?",
                (robot_sysid, victim_id),
            ).fetchone()
            if known is None:
                raise KeyError(f"robot {robot_sysid} has reported no victim {victim_id}")
            cur = self._db.execute(
                "INSERT INTO actions (robot_sysid, victim_id, action, created_unix_s)"
                " VALUES (?, ?, ?, ?)",
                (robot_sysid, victim_id, action.value, time.time()),
            )
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._commit()
        assert cur.lastrowid is not None
        return int(cur.lastrowid)

    def note_action_sent(self, action_seq: int, now_unix_s: float) -> None:
        self._simple_write(
            "UPDATE actions SET sent_count=sent_count+1, last_sent_unix_s=? WHERE action_seq=?",
            (now_unix_s, action_seq),
        )

    def ack_action(self, action_seq: int, now_unix_s: float) -> bool:
        """Mark an action acknowledged; False when it was unknown or already acked."""
        self._begin()
        cur = self._db.execute(
            "UPDATE actions SET acked_unix_s=? WHERE action_seq=? AND acked_unix_s IS NULL",
            (now_unix_s, action_seq),
        )
        self._commit()
        return cur.rowcount == 1

    def _simple_write(self, sql: str, args: tuple[object, ...]) -> None:
        self._begin()
        try:
            self._db.execute(sql, args)
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._commit()

    # -- reading ---------------------------------------------------------------

    def data_version(self) -> int:
        """Changes whenever another connection commits (cheap; see PRAGMA data_version)."""
        return int(self._db.execute("PRAGMA data_version").fetchone()[0])

    def sources(self) -> list[Source]:
        rows = self._db.execute(
            "SELECT hq_id, payload, report_seq, merged_into_id, updated_unix_s FROM sources"
            " ORDER BY hq_id, robot_sysid, victim_id"
        ).fetchall()
        return [Source(int(h), _report(p), int(s), int(m), float(u)) for h, p, s, m, u in rows]

    def report_count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM reports").fetchone()[0])

    def actions(self, *, pending_only: bool = False) -> list[Action]:
        sql = (
            "SELECT action_seq, robot_sysid, victim_id, action, created_unix_s, sent_count,"
            " acked_unix_s FROM actions"
        )
        if pending_only:
            sql += " WHERE acked_unix_s IS NULL"
        rows = self._db.execute(sql + " ORDER BY action_seq").fetchall()
        return [
            Action(int(a), int(r), int(v), OperatorAction(int(k)), float(c), int(n), ack)
            for a, r, v, k, c, n, ack in rows
        ]

    def robots(self) -> list[Robot]:
        rows = self._db.execute(
            "SELECT sysid, compid, first_heard_unix_s, last_heard_unix_s, status, status_unix_s,"
            " origin_lat_deg, origin_lon_deg, origin_alt_m FROM robots ORDER BY sysid"
        ).fetchall()
        out = []
        for sysid, compid, first, last, status, status_t, lat, lon, alt in rows:
            origin = GlobalOrigin(lat, lon, alt) if lat is not None else None
            parsed = json.loads(status) if status else None
            out.append(Robot(sysid, compid, first, last, parsed, status_t, origin))
        return out

    def default_origin(self) -> GlobalOrigin | None:
        row = self._db.execute("SELECT value FROM meta WHERE key='default_origin'").fetchone()
        return None if row is None else GlobalOrigin(**json.loads(row[0]))

    def origins(self) -> Origins:
        per_robot = {r.sysid: r.origin for r in self.robots() if r.origin is not None}
        return Origins(per_robot, self.default_origin())


@dataclass(frozen=True)
class Origins:
    """EKF origins the HQ knows: per robot (GPS_GLOBAL_ORIGIN) and the operator's default."""

    per_robot: dict[int, GlobalOrigin]
    default: GlobalOrigin | None

    def for_robot(self, sysid: int) -> GlobalOrigin | None:
        return self.per_robot.get(sysid, self.default)


def geo_of(report: VictimReport, origins: Origins) -> Geo | None:
    """A report's (lat, lon, alt): as reported, else from its robot's EKF origin, else None."""
    if report.lat_deg is not None and report.lon_deg is not None and report.alt_m is not None:
        return (report.lat_deg, report.lon_deg, report.alt_m)
    origin = origins.for_robot(report.robot_sysid)
    if origin is None:
        return None
    return ned_to_geodetic(origin, report.north_m, report.east_m, report.down_m)


def placed(report: VictimReport, origins: Origins) -> Placed:
    return Placed(
        report.robot_sysid,
        report.victim_id,
        report.north_m,
        report.east_m,
        report.cov_ne_m2,
        geo_of(report, origins),
    )


def _describe(exc: sqlite3.DatabaseError) -> str:
    text = str(exc)
    if "not a database" in text or "malformed" in text:
        return f"{text} (corrupt, or not a SQLite file)"
    if "locked" in text or "busy" in text:
        return f"{text} (another process holds it; is another rescue-hq running?)"
    return text
