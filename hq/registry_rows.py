"""The registry's rows read back as checked records (hq.records); an unusable row is skipped.

A row that does not check (a damaged file, one edited by hand) stays in the file
and is left out of what is returned; ``bad_row`` is told where it is and why,
and says it once.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Callable

from fusion.types import GlobalOrigin
from hq.records import (
    Action,
    BadRecord,
    OperatorAction,
    Robot,
    RobotStatus,
    Source,
    check_origin,
    check_picture,
    report_from_payload,
)

BadRow = Callable[[str, Exception], None]  # (which row, what is wrong with it)


def picture(
    db: sqlite3.Connection, bad_row: BadRow, robot_sysid: int, victim_id: int
) -> bytes | None:
    """The stored JPEG, None without one or when the row is unusable."""
    row = db.execute(
        "SELECT jpeg FROM pictures WHERE robot_sysid=? AND victim_id=?",
        (robot_sysid, victim_id),
    ).fetchone()
    if row is None:
        return None
    try:
        return check_picture(row[0])
    except BadRecord as exc:
        bad_row(f"pictures robot {robot_sysid} victim {victim_id}", exc)
        return None


def sources(db: sqlite3.Connection, bad_row: BadRow) -> list[Source]:
    """Every usable source, by HQ ID, robot and victim."""
    rows = db.execute(
        "SELECT robot_sysid, victim_id, hq_id, payload, report_seq, merged_into_id,"
        " updated_unix_s FROM sources ORDER BY hq_id, robot_sysid, victim_id"
    ).fetchall()
    out = []
    for robot, victim, h, p, s, m, u in rows:
        try:
            out.append(Source(int(h), report_from_payload(p), int(s), int(m), float(u)))
        except (BadRecord, TypeError, ValueError) as exc:
            bad_row(f"sources robot {robot} victim {victim}", exc)
    return out


def actions(db: sqlite3.Connection, bad_row: BadRow, *, pending_only: bool) -> list[Action]:
    """Every usable operator action (only the unanswered ones when ``pending_only``), in order."""
    sql = (
        "SELECT action_seq, robot_sysid, victim_id, action, created_unix_s, sent_count,"
        " acked_unix_s, ack_result FROM actions"
    )
    if pending_only:
        sql += " WHERE acked_unix_s IS NULL"
    rows = db.execute(sql + " ORDER BY action_seq").fetchall()
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
            bad_row(f"action {a}", exc)
    return out


def robots(db: sqlite3.Connection, bad_row: BadRow) -> list[Robot]:
    """Every robot heard; an unusable status or origin alone is left out of its robot."""
    rows = db.execute(
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
            bad_row(f"origin of robot {sysid}", exc)
        try:
            parsed = RobotStatus.from_json(status) if status else None
        except BadRecord as exc:
            bad_row(f"status of robot {sysid}", exc)
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
            bad_row(f"robot {sysid}", exc)
    return out


def default_origin(db: sqlite3.Connection, bad_row: BadRow) -> GlobalOrigin | None:
    """The operator's default EKF origin, None when unset or unusable."""
    row = db.execute("SELECT value FROM meta WHERE key='default_origin'").fetchone()
    if row is None:
        return None
    try:
        return check_origin(GlobalOrigin(**json.loads(row[0])))
    except (TypeError, ValueError) as exc:
        bad_row("the default origin", exc)
        return None
