"""The HQ's durable registry of victims: one SQLite file (WAL, synchronous=FULL).

Its tables, opening, write transactions and errors are hq.registry_file; reading
rows back as checked records is hq.registry_rows. Here: what is stored, how a
report's source finds its HQ victim (hq.merge), and the numbering of actions.

A batch of reports is written in one transaction; the caller acknowledges only
after ``store_reports`` returned, i.e. after the commit reached the disk: nothing
acknowledged is ever lost. A report is a duplicate when (robot, report_seq,
victim_id, report time) was stored before. An older report (by report_seq, then
report time) than the one a source holds is stored but does not change the source.
When a source leaves an HQ victim (its robot merged it into another victim) and no
one is left there, the operator's notes on it move with the person.

Errors (hq.registry_file): ``RegistryError`` (cannot open: corrupt, not SQLite,
locked, foreign schema) names the file; ``RegistryBusy`` (a write could not get the
lock in time); ``RegistryFull`` (the disk is full). A failed write leaves nothing
of itself behind and the registry usable: the next write, once space returns, works.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

from fusion.types import GlobalOrigin, Sensor, TrackState
from hq import epoch, merge, registry_rows
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
    report_payload,
)
from hq.registry_file import RegistryError, open_db, transaction

log = logging.getLogger(__name__)

# action_seq never counts below the seconds since this instant (see _seed_action_seq).
_ACTION_SEQ_EPOCH_UNIX_S = 1_735_689_600  # 2025-01-01T00:00:00Z
_ACTION_SEQ_TICKS_PER_S = 4  # the clock floor counts quarter seconds: uint32 lasts until 2059
_MAX_ACTION_SEQ = 0xFFFFFFFF  # RESCUE_OPERATOR_ACTION.action_seq is a uint32
_ACTION_SEQ_HEADROOM = 1 << 24  # numbers left above the highest clock floor
_BUSY_TIMEOUT_MS = 1500  # a concurrent `rescue-hq mark` holds the lock for milliseconds


class Registry:
    """The SQLite registry. One instance per thread (sqlite3 connections are not shared)."""

    def __init__(self, path: Path, *, busy_timeout_ms: int = _BUSY_TIMEOUT_MS) -> None:
        self.path = path
        self._cache: dict[tuple[int, int], tuple[int, Placed]] | None = None
        self._origins_cache: Origins | None = None
        self.bad_rows: set[str] = set()  # unusable rows found while reading, said once each
        self._db, self.epoch = open_db(path, busy_timeout_ms)

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

    def store_reports(self, batch: Sequence[IncomingReport]) -> list[StoreResult]:
        """Store a batch durably (one transaction); the result of each, in order.

        Raises RegistryBusy (the lock was not free in time) or RegistryFull (the
        disk is full); nothing of the batch is stored then.
        """
        if not batch:
            return []
        try:
            with transaction(self._db, self.path):
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
        if held is not None and int(held[2]) != hq_id:
            self._notes_follow(int(held[2]), hq_id, cache)
        return StoreResult.ACCEPTED

    def _notes_follow(
        self, left: int, joined: int, cache: dict[tuple[int, int], tuple[int, Placed]]
    ) -> None:
        """A source went from HQ victim ``left`` to ``joined`` (its robot merged it into
        another victim, or it moved): when no one is left in ``left``, which the
        console then no longer shows, the operator's notes on it go with the person."""
        if any(hq_id == left for hq_id, _ in cache.values()):
            return
        moved = self._db.execute(
            "UPDATE operator_notes SET hq_id=? WHERE hq_id=?", (joined, left)
        ).rowcount
        if moved:
            log.info("%d note(s) of HQ victim %d moved to HQ victim %d", moved, left, joined)

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
        with transaction(self._db, self.path) as db:
            self._touch_robot(sysid, compid, now_unix_s)
            db.execute(
                "UPDATE robots SET status=?, status_unix_s=? WHERE sysid=?",
                (status.to_json(), now_unix_s, sysid),
            )

    def set_robot_origin(self, sysid: int, compid: int, origin: GlobalOrigin) -> None:
        self._forget_cache()
        with transaction(self._db, self.path) as db:
            self._touch_robot(sysid, compid, time.time())
            db.execute(
                "UPDATE robots SET origin_lat_deg=?, origin_lon_deg=?, origin_alt_m=?"
                " WHERE sysid=?",
                (origin.lat_deg, origin.lon_deg, origin.alt_m, sysid),
            )

    def set_default_origin(self, origin: GlobalOrigin | None) -> None:
        value = None if origin is None else json.dumps(asdict(origin))
        self._forget_cache()
        with transaction(self._db, self.path) as db:
            if value is None:
                db.execute("DELETE FROM meta WHERE key='default_origin'")
            else:
                db.execute("INSERT OR REPLACE INTO meta VALUES ('default_origin', ?)", (value,))

    def add_action(self, robot_sysid: int, victim_id: int, action: OperatorAction) -> int:
        """Record an operator action; its action_seq. KeyError for an unknown victim, or,
        for an action about the whole robot (victim_id 0), a robot never heard."""
        with transaction(self._db, self.path) as db:
            if action.whole_robot:
                if victim_id != 0:
                    raise KeyError(f"{action.name} is for a whole robot: victim 0, not {victim_id}")
                known = db.execute("SELECT 1 FROM robots WHERE sysid=?", (robot_sysid,)).fetchone()
                if known is None:
                    raise KeyError(f"robot {robot_sysid} has never been heard")
            else:
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
        with transaction(self._db, self.path) as db:
            db.execute(
                "UPDATE actions SET sent_count=sent_count+1, last_sent_unix_s=? WHERE action_seq=?",
                (now_unix_s, action_seq),
            )

    def ack_action(self, action_seq: int, now_unix_s: float, result: int) -> bool:
        """Record the robot's answer to an action; False when unknown or already answered."""
        with transaction(self._db, self.path) as db:
            cur = db.execute(
                "UPDATE actions SET acked_unix_s=?, ack_result=? WHERE action_seq=?"
                " AND acked_unix_s IS NULL",
                (now_unix_s, result, action_seq),
            )
        return cur.rowcount == 1

    # -- evidence pictures (per robot's victim and kind: the newest picture_id) -----------

    def store_picture(
        self,
        robot_sysid: int,
        victim_id: int,
        picture_id: int,
        jpeg: bytes,
        now_unix_s: float,
        kind: Sensor = Sensor.COLOUR,
    ) -> bool:
        """Keep a robot's picture of its victim, of this kind (the colour or the thermal
        camera's view), unless a newer one (higher picture_id) or this very one is
        stored; True when stored. The same picture_id with other bytes (a robot that
        lost its last commits gave the number out again) replaces the stored one: it
        is the robot's newest. RegistryError as for reports."""
        with transaction(self._db, self.path) as db:
            cur = db.execute(
                "INSERT INTO pictures (robot_sysid, victim_id, kind, picture_id, received_unix_s,"
                " jpeg) VALUES (?, ?, ?, ?, ?, ?) ON CONFLICT (robot_sysid, victim_id, kind)"
                " DO UPDATE SET picture_id=excluded.picture_id,"
                " received_unix_s=excluded.received_unix_s, jpeg=excluded.jpeg"
                " WHERE excluded.picture_id > pictures.picture_id"
                " OR (excluded.picture_id = pictures.picture_id AND excluded.jpeg != pictures.jpeg)"
                " OR typeof(pictures.picture_id) != 'integer'",  # a damaged row is replaced
                (robot_sysid, victim_id, str(kind), picture_id, now_unix_s, jpeg),
            )
        return cur.rowcount == 1

    def picture_id(
        self, robot_sysid: int, victim_id: int, kind: Sensor = Sensor.COLOUR
    ) -> int | None:
        """The stored picture's number for this robot's victim and kind, None without one."""
        row = self._db.execute(
            "SELECT picture_id FROM pictures WHERE robot_sysid=? AND victim_id=? AND kind=?",
            (robot_sysid, victim_id, str(kind)),
        ).fetchone()
        if row is None:
            return None
        try:
            return registry_rows.cell_int(row[0])
        except BadRecord as exc:  # unusable: a new picture replaces it
            self._bad_row(registry_rows.picture_row(robot_sysid, victim_id, kind), exc)
            return None

    def picture_versions(self) -> dict[registry_rows.PictureKey, tuple[int, float]]:
        """(picture_id, received time) of every stored picture by (robot, victim, kind)."""
        return registry_rows.picture_versions(self._db, self._bad_row)

    def picture(
        self, robot_sysid: int, victim_id: int, kind: Sensor = Sensor.COLOUR
    ) -> bytes | None:
        """The stored JPEG, None without one or when the row is unusable (said once)."""
        return registry_rows.picture(self._db, self._bad_row, robot_sysid, victim_id, kind)

    def hq_id_of(self, robot_sysid: int, victim_id: int) -> int | None:
        """The HQ victim a robot's victim is in (None: not stored, or unusable)."""
        row = self._db.execute(
            "SELECT hq_id FROM sources WHERE robot_sysid=? AND victim_id=?",
            (robot_sysid, victim_id),
        ).fetchone()
        if row is None:
            return None
        try:
            return registry_rows.cell_int(row[0])
        except BadRecord:
            return None

    # -- searched-area maps (per robot: the largest p_q of each cell it sent) ------------

    def store_coverage(self, robot_sysid: int, cells: Sequence[tuple[int, int, int]]) -> None:
        """Keep a robot's cells (north index, east index, p_q): each at the larger of
        what is stored and what it says, so a late or repeated piece never lowers
        one. RegistryError as for reports."""
        with transaction(self._db, self.path) as db:
            db.executemany(
                "INSERT INTO coverage (robot_sysid, north_idx, east_idx, p_q) VALUES (?, ?, ?, ?)"
                " ON CONFLICT (robot_sysid, north_idx, east_idx) DO UPDATE SET p_q = excluded.p_q"
                " WHERE excluded.p_q > coverage.p_q OR typeof(coverage.p_q) != 'integer'",
                [(robot_sysid, n, e, q) for n, e, q in cells],
            )

    def coverage(self) -> dict[int, list[tuple[int, int, int]]]:
        """Every robot's usable cells (north index, east index, p_q); a damaged row
        is skipped and said once."""
        return registry_rows.coverage(self._db, self._bad_row)

    def data_version(self) -> int:
        """Changes whenever another connection commits (cheap; see PRAGMA data_version)."""
        return int(self._db.execute("PRAGMA data_version").fetchone()[0])

    def sources(self) -> list[Source]:
        """Every usable source; a row that does not check (see hq.records) is skipped, said once."""
        return registry_rows.sources(self._db, self._bad_row)

    def _bad_row(self, where: str, exc: Exception) -> None:
        """Say once per row that it is unusable and count it; the row stays in the file."""
        if where not in self.bad_rows:
            self.bad_rows.add(where)
            log.error("database %s: %s is unusable and ignored: %s", self.path, where, exc)

    def first_received_unix_s(self) -> dict[tuple[int, int], float]:
        """When the first report of each (robot sysid, robot's victim id) arrived."""
        return registry_rows.first_received_unix_s(self._db, self._bad_row)

    def report_count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM reports").fetchone()[0])

    def actions(self, *, pending_only: bool = False) -> list[Action]:
        return registry_rows.actions(self._db, self._bad_row, pending_only=pending_only)

    def robots(self) -> list[Robot]:
        return registry_rows.robots(self._db, self._bad_row)

    def default_origin(self) -> GlobalOrigin | None:
        return registry_rows.default_origin(self._db, self._bad_row)

    def origins(self) -> Origins:
        per_robot = {r.sysid: r.origin for r in self.robots() if r.origin is not None}
        return Origins(per_robot, self.default_origin())
