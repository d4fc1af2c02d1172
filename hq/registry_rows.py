"""The registry's rows read back as checked records (hq.records); an unusable row is skipped.

A row that does not check (a damaged file, one edited by hand) stays in the file
and is left out of what is returned; ``bad_row`` is told where it is and why,
and says it once.
"""

from __future__ import annotations

import json
import math
import sqlite3
from collections.abc import Callable

from fusion.types import GlobalOrigin, Sensor
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
PictureKey = tuple[int, int, Sensor]  # (robot sysid, robot's victim ID, the camera)


def cell_int(value: object) -> int:
    """A cell the registry wrote as an INTEGER; BadRecord for text, bytes, NaN, a
    fraction or an infinity (a file damaged or edited by hand)."""
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        return int(value)
    if not isinstance(value, int) or isinstance(value, bool):
        raise BadRecord(f"{value!r} is not a whole number")
    return value


def cell_float(value: object) -> float:
    """A cell the registry wrote as a REAL; BadRecord unless a finite number."""
    if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
        raise BadRecord(f"{value!r} is not a finite number")
    return float(value)


def cell_optional_float(value: object) -> float | None:
    return None if value is None else cell_float(value)


def cell_name(value: object) -> str:
    """A row's key cell as an unusable row's name shows it, on one line: a whole
    number as it is, anything else (text with a newline, bytes, a float) as its
    repr, at most 20 characters."""
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    return repr(value)[:20]


def picture_row(robot: object, victim: object, kind: object = Sensor.COLOUR) -> str:
    """How a picture row is named when it is unusable (a colour one as before kinds)."""
    name = f"pictures robot {cell_name(robot)} victim {cell_name(victim)}"
    if kind == Sensor.COLOUR:
        return name
    return f"{name} {kind if isinstance(kind, Sensor) else cell_name(kind)}"


def cell_kind(value: object) -> Sensor:
    """A picture's kind as the registry writes it (``colour``, ``thermal``)."""
    if isinstance(value, str) and value in set(Sensor):
        return Sensor(value)
    raise BadRecord(f"picture kind {value!r} is not one of colour, thermal")


def picture(
    db: sqlite3.Connection,
    bad_row: BadRow,
    robot_sysid: int,
    victim_id: int,
    kind: Sensor = Sensor.COLOUR,
) -> bytes | None:
    """The stored JPEG, None without one or when the row is unusable."""
    row = db.execute(
        "SELECT jpeg FROM pictures WHERE robot_sysid=? AND victim_id=? AND kind=?",
        (robot_sysid, victim_id, str(kind)),
    ).fetchone()
    if row is None:
        return None
    try:
        return check_picture(row[0])
    except BadRecord as exc:
        bad_row(picture_row(robot_sysid, victim_id, kind), exc)
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
            source = Source(
                cell_int(h), report_from_payload(p), cell_int(s), cell_int(m), cell_float(u)
            )
            out.append(source)
        except (BadRecord, TypeError, ValueError) as exc:
            bad_row(f"sources robot {cell_name(robot)} victim {cell_name(victim)}", exc)
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
            answer = None if result is None else cell_int(result)
            out.append(
                Action(
                    cell_int(a),
                    cell_int(r),
                    cell_int(v),
                    OperatorAction(cell_int(k)),
                    cell_float(c),
                    cell_int(n),
                    cell_optional_float(ack),
                    answer,
                )
            )
        except (TypeError, ValueError) as exc:
            bad_row(f"action {cell_name(a)}", exc)
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
                origin = check_origin(
                    GlobalOrigin(cell_float(lat), cell_float(lon), cell_float(alt))
                )
        except (TypeError, ValueError) as exc:
            bad_row(f"origin of robot {cell_name(sysid)}", exc)
        try:
            parsed = RobotStatus.from_json(status) if status else None
        except BadRecord as exc:
            bad_row(f"status of robot {cell_name(sysid)}", exc)
        try:
            out.append(
                Robot(
                    cell_int(sysid),
                    cell_int(compid),
                    cell_float(first),
                    cell_float(last),
                    parsed,
                    cell_optional_float(status_t),
                    origin,
                )
            )
        except (TypeError, ValueError) as exc:
            bad_row(f"robot {cell_name(sysid)}", exc)
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


def picture_versions(
    db: sqlite3.Connection, bad_row: BadRow
) -> dict[PictureKey, tuple[int, float]]:
    """(picture_id, received time) of every usable stored picture by (robot, victim, kind)."""
    rows = db.execute(
        "SELECT robot_sysid, victim_id, kind, picture_id, received_unix_s FROM pictures"
    ).fetchall()
    out = {}
    for r, v, k, p, t in rows:
        try:
            out[(cell_int(r), cell_int(v), cell_kind(k))] = (cell_int(p), cell_float(t))
        except BadRecord as exc:
            bad_row(picture_row(r, v, k), exc)
    return out


def first_received_unix_s(db: sqlite3.Connection, bad_row: BadRow) -> dict[tuple[int, int], float]:
    """When the first report of each (robot sysid, robot's victim id) arrived."""
    rows = db.execute(
        "SELECT robot_sysid, victim_id, MIN(received_unix_s) FROM reports"
        " GROUP BY robot_sysid, victim_id"
    ).fetchall()
    out = {}
    for r, v, t in rows:
        try:
            out[(cell_int(r), cell_int(v))] = cell_float(t)
        except BadRecord as exc:
            bad_row(f"reports robot {cell_name(r)} victim {cell_name(v)}", exc)
    return out


_COVERAGE_OK = (
    "typeof(robot_sysid) = 'integer' AND typeof(north_idx) = 'integer'"
    " AND typeof(east_idx) = 'integer' AND typeof(p_q) = 'integer'"
    " AND p_q BETWEEN 1 AND 255 AND north_idx BETWEEN -32768 AND 32767"
    " AND east_idx BETWEEN -32768 AND 32767"
)


def coverage(db: sqlite3.Connection, bad_row: BadRow) -> dict[int, list[tuple[int, int, int]]]:
    """Each robot's usable searched-area cells (north index, east index, p_q); the
    damaged rows of a robot are said once (checked in SQL: a map has many cells)."""
    out: dict[int, list[tuple[int, int, int]]] = {}
    for r, n, e, q in db.execute(
        f"SELECT robot_sysid, north_idx, east_idx, p_q FROM coverage WHERE {_COVERAGE_OK}"
    ):
        out.setdefault(r, []).append((n, e, q))
    for r, count in db.execute(
        f"SELECT robot_sysid, COUNT(*) FROM coverage WHERE NOT ({_COVERAGE_OK}) GROUP BY 1"
    ):
        bad_row(f"coverage of robot {cell_name(r)}", BadRecord(f"{count} cell(s) unusable"))
    return out
