"""The registry's SQLite file: its tables, opening and migrating it, write transactions, errors.

Tables:
    meta        schema version, the operator's default EKF origin
    reports     every report ever accepted, verbatim (nothing received is lost)
    sources     the latest state of each (robot, victim_id), and the HQ victim it is in
    hq_victims  HQ victim IDs (a group of sources: one person seen by several robots)
    robots      every robot heard (sysid), its last status and its EKF origin
    actions     operator actions (rescued, false alarm), their action_seq and ack time
    pictures    the newest evidence picture (JPEG) of each (robot, victim_id, kind): kind
                ``colour`` or ``thermal`` (the camera that took it; fusion.types.Sensor)
    operator_notes  the operator's notes on HQ victims (hq.web.notes); moved with the
                person when the robot merges that victim into another (hq.registry)
    coverage    each robot's searched-area map (hq.coverage): per 0.25 m floor cell of
                the robot's local frame, the largest p_q (probability x 255) it sent

``open_db`` opens (WAL, synchronous=FULL), checks, creates or migrates the file
and starts a new registry in a new ID epoch (hq.epoch). ``transaction`` is one
write: committed when its block ends, and leaving nothing of itself behind when it
fails, so the next write, once space returns, works.

Errors: ``RegistryError`` (cannot open: corrupt, not SQLite, locked, foreign schema)
names the file; ``RegistryBusy`` (a write could not get the lock in time);
``RegistryFull`` (the disk is full).
"""

from __future__ import annotations

import contextlib
import logging
import sqlite3
from collections.abc import Iterator
from pathlib import Path

from hq import epoch
from hq.errors import HqError

log = logging.getLogger(__name__)

SCHEMA_VERSION = 5  # 2: actions.ack_result; 3: pictures; 4: pictures.kind; 5: coverage
_PICTURES = """CREATE TABLE IF NOT EXISTS pictures (
    robot_sysid INTEGER NOT NULL, victim_id INTEGER NOT NULL,
    kind TEXT NOT NULL DEFAULT 'colour',
    picture_id INTEGER NOT NULL, received_unix_s REAL NOT NULL, jpeg BLOB NOT NULL,
    PRIMARY KEY (robot_sysid, victim_id, kind)
)"""
COVERAGE_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS coverage ("
    " robot_sysid INTEGER NOT NULL, north_idx INTEGER NOT NULL, east_idx INTEGER NOT NULL,"
    " p_q INTEGER NOT NULL, PRIMARY KEY (robot_sysid, north_idx, east_idx)) WITHOUT ROWID"
)
# From version: SQL. The pictures table of version 3 is created by _SCHEMA itself;
# version 4 makes it again keyed by kind too: the pictures it held are colour ones.
_MIGRATIONS: dict[int, tuple[str, ...]] = {
    1: ("ALTER TABLE actions ADD COLUMN ack_result INTEGER",),
    2: (),
    3: (
        "ALTER TABLE pictures RENAME TO pictures_v3",
        _PICTURES,
        "INSERT INTO pictures (robot_sysid, victim_id, kind, picture_id, received_unix_s, jpeg)"
        " SELECT robot_sysid, victim_id, 'colour', picture_id, received_unix_s, jpeg"
        " FROM pictures_v3",
        "DROP TABLE pictures_v3",
    ),
    4: (),  # the coverage table is created by COVERAGE_SCHEMA itself
}

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
"""
NOTES_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS operator_notes ("
    " note_id INTEGER PRIMARY KEY AUTOINCREMENT, hq_id INTEGER NOT NULL,"
    " text TEXT NOT NULL, created_unix_s REAL NOT NULL)"
)


class RegistryError(HqError):
    """The registry file cannot be used; the message names the file."""


class RegistryBusy(RegistryError):
    """A write did not get the database lock in time; nothing was stored."""


class RegistryCorrupt(RegistryError):
    """The file is damaged (not SQLite, malformed, or emptied); `run` moves it aside."""


class RegistryFull(RegistryError):
    """The disk is full; nothing of the write was stored."""


def open_db(path: Path, busy_timeout_ms: int) -> tuple[sqlite3.Connection, int]:
    """The checked, current-schema connection to ``path`` and the registry's ID epoch.

    Raises RegistryCorrupt (empty, not SQLite, malformed) or RegistryError (cannot
    open, locked, a foreign or newer schema, the epoch file unusable).
    """
    if path.is_file() and path.stat().st_size == 0:
        raise RegistryCorrupt(f"database {path} is empty (0 bytes): its contents were lost")
    try:
        db = sqlite3.connect(str(path), isolation_level=None, timeout=busy_timeout_ms / 1000.0)
    except sqlite3.Error as exc:
        raise RegistryError(f"database {path}: cannot open: {exc}") from None
    try:
        return db, _setup(db, path)
    except sqlite3.DatabaseError as exc:
        db.close()
        code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
        damaged = code in (sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_NOTADB)
        kind = RegistryCorrupt if damaged else RegistryError
        raise kind(f"database {path}: {_describe(exc)}") from None
    except RegistryError:
        db.close()
        raise


def _setup(db: sqlite3.Connection, path: Path) -> int:
    """Check, create or migrate the tables; the registry's epoch (1: an older registry)."""
    # Text that is not UTF-8 (a damaged file) reads as U+FFFD and then fails its
    # check, instead of raising out of a whole query.
    db.text_factory = lambda raw: raw.decode("utf-8", "replace")
    db.execute("PRAGMA journal_mode=WAL")
    # FULL: a commit is on the disk before we acknowledge, even across a power cut.
    db.execute("PRAGMA synchronous=FULL")
    db.execute("PRAGMA foreign_keys=ON")
    row = db.execute("PRAGMA quick_check").fetchone()
    if row is None or row[0] != "ok":
        raise RegistryCorrupt(f"database {path}: integrity check failed: {row}")
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    if tables and "meta" not in tables:
        raise RegistryError(f"database {path}: not a rescue-hq registry (tables: {sorted(tables)})")
    db.execute("BEGIN IMMEDIATE")
    try:
        for statement in _SCHEMA.split(";"):
            if statement.strip():
                db.execute(statement)
        db.execute(_PICTURES)
        db.execute(NOTES_SCHEMA)
        db.execute(COVERAGE_SCHEMA)
        row = db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
        version = None if row is None else _meta_int(row[0], "schema_version", path)
        if version is None:
            db.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            _start_epoch(db, path, epoch.last_epoch(path) + 1)
        elif version in _MIGRATIONS:
            for old in range(version, SCHEMA_VERSION):
                for statement in _MIGRATIONS[old]:
                    db.execute(statement)
            db.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION),))
        elif version != SCHEMA_VERSION:
            raise RegistryError(
                f"database {path}: schema version {version}, this rescue-hq knows {SCHEMA_VERSION}"
            )
        row = db.execute("SELECT value FROM meta WHERE key='epoch'").fetchone()
        number = 1 if row is None else _meta_int(row[0], "epoch", path)  # none: older registry
        epoch.record(path, epoch=number)  # a lost epoch file is written again
        db.execute("COMMIT")
    except epoch.EpochError as exc:
        _rollback(db, path)
        raise RegistryError(str(exc)) from None
    except BaseException:
        _rollback(db, path)
        raise
    return number


def _meta_int(value: object, key: str, path: Path) -> int:
    """A whole number the registry keeps in its meta table (as text)."""
    try:
        return int(str(value))
    except ValueError:
        raise RegistryError(
            f"database {path}: meta {key} = {str(value)[:40]!r} is not a whole number"
        ) from None


def _start_epoch(db: sqlite3.Connection, path: Path, number: int) -> None:
    """A new registry: HQ victim IDs from epoch ``number``'s first ID on.

    The epoch file is written before this transaction commits, so an epoch
    whose IDs were handed out is always on record.
    """
    db.execute("INSERT INTO meta VALUES ('epoch', ?)", (str(number),))
    db.execute(
        "INSERT INTO sqlite_sequence (name, seq) VALUES ('hq_victims', ?)",
        (epoch.first_id(number) - 1,),
    )
    epoch.record(path, epoch=number)


@contextlib.contextmanager
def transaction(db: sqlite3.Connection, path: Path) -> Iterator[sqlite3.Connection]:
    """One write transaction: committed when the block ends, rolled back on any error.

    SQLite errors become RegistryBusy (locked), RegistryFull (disk full) or
    RegistryError; nothing of the block is stored then. SQLite may already have
    rolled back by itself (it does on SQLITE_FULL), so the rollback is only
    attempted inside a transaction.
    """
    try:
        db.execute("BEGIN IMMEDIATE")
    except sqlite3.Error as exc:
        raise _failure(path, exc) from None
    try:
        yield db
        db.execute("COMMIT")
    except sqlite3.Error as exc:
        _rollback(db, path)
        raise _failure(path, exc) from None
    except BaseException:
        _rollback(db, path)
        raise


def _rollback(db: sqlite3.Connection, path: Path) -> None:
    if not db.in_transaction:
        return
    try:
        db.execute("ROLLBACK")
    except sqlite3.Error as exc:  # nothing more to undo; the connection stays usable
        log.warning("database %s: rollback failed: %s", path, exc)


def _failure(path: Path, exc: sqlite3.Error) -> RegistryError:
    code = getattr(exc, "sqlite_errorcode", 0) & 0xFF
    text = str(exc)
    if code == sqlite3.SQLITE_FULL or "disk is full" in text:
        return RegistryFull(f"database {path}: the disk is full ({text})")
    if code in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED) or "locked" in text:
        return RegistryBusy(f"database {path} is locked: {text}")
    return RegistryError(f"database {path}: {text}")


def _describe(exc: sqlite3.DatabaseError) -> str:
    text = str(exc)
    if "not a database" in text or "malformed" in text:
        return f"{text} (corrupt, or not a SQLite file)"
    if "locked" in text or "busy" in text:
        return f"{text} (another process holds it; is another rescue-hq running?)"
    return text
