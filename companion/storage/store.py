"""The companion's durable state: one SQLite file (WAL) in the state directory.

What survives a crash or ``kill -9``:
- the tracker snapshot (victims, their IDs, the next ID);
- what was reported about each victim (so a restart re-announces nothing as new);
- the next report sequence number;
- the outbox of dialect messages not yet acknowledged by the HQ
  (mavlink_io.reliable.OutboxStore);
- each victim's evidence picture (the JPEG, its score and number) and whether the
  HQ has it (companion/reporting/pictures.py); its thermal picture likewise, in a table of its
  own (``thermal_pictures``: a state file from before it simply gains the table).

The processing thread writes a frame's consequences in one transaction
(``with store.transaction(durable=True): ...``) *before* anything is sent, so what
was sent is always on disk, across a power cut too (WAL runs synchronous=NORMAL,
and FULL for the commits that give out sequence numbers and IDs). ``put`` is idempotent (INSERT OR IGNORE), so the outbox can store a
message again when it later sends it. One connection, guarded by a lock: the
processing thread writes, the reporter thread acknowledges.
"""

from __future__ import annotations

import contextlib
import json
import logging
import sqlite3
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.errors import CompanionError
from fusion.types import Sensor

log = logging.getLogger(__name__)

SCHEMA_VERSION = 1
_SCHEMA = """
CREATE TABLE IF NOT EXISTS kv (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS outbox (
    msgid INTEGER NOT NULL,
    seq INTEGER NOT NULL,
    frame BLOB NOT NULL,
    PRIMARY KEY (msgid, seq)
);
CREATE TABLE IF NOT EXISTS pictures (
    victim_id INTEGER PRIMARY KEY,
    picture_id INTEGER NOT NULL,
    score REAL NOT NULL,
    taken_unix_s REAL NOT NULL,
    jpeg BLOB NOT NULL,
    delivered INTEGER NOT NULL DEFAULT 0
);
CREATE TABLE IF NOT EXISTS thermal_pictures (
    victim_id INTEGER PRIMARY KEY,
    picture_id INTEGER NOT NULL,
    score REAL NOT NULL,
    taken_unix_s REAL NOT NULL,
    jpeg BLOB NOT NULL,
    delivered INTEGER NOT NULL DEFAULT 0
);
"""
_PICTURE_TABLES = {Sensor.COLOUR: "pictures", Sensor.THERMAL: "thermal_pictures"}


@dataclass(frozen=True)
class StoredPicture:
    """A victim's kept evidence picture; ``delivered`` once the HQ said STORED."""

    victim_id: int
    picture_id: int
    score: float
    taken_unix_s: float
    jpeg: bytes
    delivered: bool = False
    kind: Sensor = Sensor.COLOUR  # the colour or the thermal camera's view


class StoreError(CompanionError):
    """The state database cannot be opened or used; the message names the file."""


class StoreCorrupt(StoreError):
    """The file is not a usable state database (not SQLite, malformed, bad JSON):
    waiting or restarting will not mend it (companion.storage.recovery moves it aside)."""


_CORRUPT_CODES = (11, 26)  # SQLITE_CORRUPT, SQLITE_NOTADB
# What a usable row holds, as this program writes it: MAVLink message IDs and sequence
# numbers, frames of 1..280 bytes (MAVLink 2, signed); pictures' finite numbers.
_USABLE_OUTBOX = (
    "typeof(msgid) = 'integer' AND msgid BETWEEN 0 AND 16777215"
    " AND typeof(seq) = 'integer' AND seq BETWEEN 0 AND 4294967295"
    " AND typeof(frame) = 'blob' AND length(frame) BETWEEN 1 AND 280"
)
_USABLE_PICTURE = (
    "typeof(picture_id) = 'integer' AND picture_id >= 0"
    " AND typeof(score) IN ('integer', 'real') AND abs(score) <= 1e9"
    " AND typeof(taken_unix_s) IN ('integer', 'real') AND taken_unix_s BETWEEN 0 AND 1e11"
    " AND typeof(jpeg) = 'blob' AND length(jpeg) > 0 AND delivered IN (0, 1)"
)


def _is_corrupt(exc: sqlite3.Error) -> bool:
    code = getattr(exc, "sqlite_errorcode", None)
    return code in _CORRUPT_CODES or type(exc) is sqlite3.DatabaseError


class Store:
    """Durable companion state. Thread-safe; ``close()`` is safe twice."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._lock = threading.RLock()
        self._depth = 0
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._db: sqlite3.Connection | None = sqlite3.connect(
                str(path), timeout=5.0, isolation_level=None, check_same_thread=False
            )
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
            version = self._get("schema_version")
            if version is None:
                self._set("schema_version", SCHEMA_VERSION)
            elif version != SCHEMA_VERSION:
                raise StoreError(
                    f"{path}: state database version {version}, expected {SCHEMA_VERSION}"
                )
        except sqlite3.DatabaseError as exc:
            kind = StoreCorrupt if _is_corrupt(exc) else StoreError
            raise kind(f"{path}: cannot use the state database: {exc}") from None
        except OSError as exc:
            raise StoreError(f"{path}: cannot create the state directory: {exc.strerror}") from None

    # -- transactions ----------------------------------------------------------------

    @contextlib.contextmanager
    def transaction(self, *, durable: bool = False) -> Iterator[None]:
        """Group writes into one commit; nests (the outermost one commits).

        ``durable`` (the outermost one decides): the commit is on the disk before
        this returns, even across a power cut (synchronous=FULL for this commit).
        The commits that give out report sequence numbers, victim and picture IDs or
        record an applied operator action are durable: what the HQ may hear of
        must never be rolled back. The others (acknowledgements, the periodic save)
        keep synchronous=NORMAL, which survives a crash of the program but may lose
        its last commits on a power cut.

        A failure (a full disk: SQLite may already have rolled back by itself) rolls
        back whatever is left and raises StoreError naming the file; the connection
        stays usable for the next transaction.
        """
        with self._lock:
            db = self._conn()
            if self._depth == 0:
                if durable:
                    self._run(db, "PRAGMA synchronous=FULL")
                try:
                    self._run(db, "BEGIN IMMEDIATE")
                except BaseException:
                    self._relax(db, durable)
                    raise
            self._depth += 1
            try:
                yield
            except BaseException:
                self._depth -= 1
                if self._depth == 0:
                    self._rollback(db)
                    self._relax(db, durable)
                raise
            self._depth -= 1
            if self._depth == 0:
                try:
                    db.execute("COMMIT")
                except sqlite3.Error as exc:
                    self._rollback(db)
                    raise StoreError(f"{self.path}: cannot write: {exc}") from None
                finally:
                    self._relax(db, durable)

    def _relax(self, db: sqlite3.Connection, durable: bool) -> None:
        """Back to synchronous=NORMAL after a durable commit (or its failure)."""
        if durable:
            with contextlib.suppress(sqlite3.Error):  # the next durable commit sets FULL again
                db.execute("PRAGMA synchronous=NORMAL")

    def _run(self, db: sqlite3.Connection, sql: str) -> None:
        try:
            db.execute(sql)
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: cannot write: {exc}") from None

    @staticmethod
    def _rollback(db: sqlite3.Connection) -> None:
        if db.in_transaction:  # SQLITE_FULL and others may have rolled back already
            db.execute("ROLLBACK")

    def _conn(self) -> sqlite3.Connection:
        if self._db is None:
            raise StoreError(f"{self.path}: the state database is closed")
        return self._db

    # -- key/value state ---------------------------------------------------------------

    def _read(self, sql: str, args: tuple[Any, ...] = ()) -> list[Any]:
        try:
            return self._conn().execute(sql, args).fetchall()
        except sqlite3.Error as exc:
            kind = StoreCorrupt if _is_corrupt(exc) else StoreError
            raise kind(f"{self.path}: cannot read: {exc}") from None

    def _get(self, key: str) -> Any:
        rows = self._read("SELECT value FROM kv WHERE key = ?", (key,))
        row = rows[0] if rows else None
        if row is None:
            return None
        try:
            return json.loads(row[0])
        except json.JSONDecodeError:
            raise StoreCorrupt(f"{self.path}: stored {key!r} is not valid JSON") from None

    def _set(self, key: str, value: Any) -> None:
        self._write(
            "INSERT OR REPLACE INTO kv (key, value) VALUES (?, ?)", (key, json.dumps(value))
        )

    def _write(self, sql: str, args: tuple[Any, ...]) -> sqlite3.Cursor:
        try:
            return self._conn().execute(sql, args)
        except sqlite3.Error as exc:  # a full disk, a locked or read-only file
            raise StoreError(f"{self.path}: cannot write: {exc}") from None

    def get(self, key: str) -> Any:
        with self._lock:
            return self._get(key)

    def set(self, key: str, value: Any) -> None:
        with self.transaction():
            self._set(key, value)

    # -- mavlink_io.reliable.OutboxStore ------------------------------------------------

    def put(self, msgid: int, seq: int, frame: bytes) -> None:
        with self.transaction():
            self._write(
                "INSERT OR IGNORE INTO outbox (msgid, seq, frame) VALUES (?, ?, ?)",
                (msgid, seq, frame),
            )

    def ack(self, msgid: int, seq: int) -> bool:
        with self.transaction():
            cur = self._write("DELETE FROM outbox WHERE msgid = ? AND seq = ?", (msgid, seq))
            return cur.rowcount > 0

    def pending(self) -> list[tuple[int, int, bytes]]:
        """The frames not yet acknowledged; a row that is not one (a damaged or
        hand-edited file: a text frame, a fractional number) is skipped and said."""
        with self._lock:
            rows = self._usable("outbox", _USABLE_OUTBOX, "msgid, seq, frame", "seq")
        return [(int(m), int(s), bytes(f)) for m, s, f in rows]

    # -- evidence pictures ---------------------------------------------------------------

    def put_picture(self, p: StoredPicture) -> None:
        """Keep ``p`` as its victim's picture of its kind (replacing an older one), not
        delivered."""
        with self.transaction():
            self._write(
                f"INSERT OR REPLACE INTO {_PICTURE_TABLES[p.kind]} (victim_id, picture_id,"
                " score, taken_unix_s, jpeg, delivered) VALUES (?, ?, ?, ?, ?, 0)",
                (p.victim_id, p.picture_id, p.score, p.taken_unix_s, p.jpeg),
            )

    def picture_delivered(self, victim_id: int, picture_id: int) -> None:
        """The HQ has picture ``picture_id`` (of either kind: the numbers are unique)."""
        with self.transaction():
            for table in _PICTURE_TABLES.values():
                self._write(
                    f"UPDATE {table} SET delivered = 1 WHERE victim_id = ? AND picture_id = ?",
                    (victim_id, picture_id),
                )

    def pictures(self) -> list[StoredPicture]:
        """Every usable kept picture of both kinds, by picture_id."""
        out = []
        for kind, table in _PICTURE_TABLES.items():
            with self._lock:
                rows = self._usable(
                    table,
                    _USABLE_PICTURE,
                    "victim_id, picture_id, score, taken_unix_s, jpeg, delivered",
                    "picture_id",
                )
            out += [
                StoredPicture(int(v), int(p), float(s), float(t), bytes(j), bool(d), kind)
                for v, p, s, t, j, d in rows
            ]
        return sorted(out, key=lambda p: p.picture_id)

    def _usable(self, table: str, usable: str, columns: str, order: str) -> list[Any]:
        """The rows of ``table`` whose cells have the types and ranges this program
        writes (SQLite keeps whatever a cell is given); the others are logged."""
        rows = self._read(f"SELECT {columns} FROM {table} WHERE {usable} ORDER BY {order}")
        (total,) = self._read(f"SELECT COUNT(*) FROM {table}")[0]
        if total > len(rows):
            log.warning(
                "%s: %d row(s) of %s unusable (damaged or edited): skipped",
                self.path,
                total - len(rows),
                table,
            )
        return rows

    def close(self) -> None:
        with self._lock:
            if self._db is not None:
                self._db.close()
                self._db = None
