"""One bad message, or one bad row on disk, never takes rescue-hq down.

Each value a robot sends is checked once where it enters the HQ (hq.wire, hq.records):
a report that does not check is acknowledged REJECTED, logged with the field that is
wrong, counted, and never stored; a bad RESCUE_STATUS or GPS_GLOBAL_ORIGIN is refused
the same way. Rows that an older rescue-hq stored (or that rotted on disk) are checked
when read back: skipped with one line each, never a traceback at the next start.
"""

from __future__ import annotations

import json
import math
import sqlite3
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hqproc import ACCEPTED, DUPLICATE, REJECTED, REPO, HqProcess, ack_for, hq_starter

from fusion.types import VictimReport
from hq.records import report_payload
from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.view import hq_victims

GEO = (47.397742, 8.545594, 488.0)


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


def _set(**fields: Any) -> Callable[[Any], None]:
    def mutate(msg: Any) -> None:
        for name, value in fields.items():
            setattr(msg, name, value)

    return mutate


# (what is wrong, global position?, how the message is spoiled, field named in the log)
BAD_REPORTS: list[tuple[str, bool, Callable[[Any], None], str]] = [
    ("lat/lon 0/0 flagged global", True, _set(lat=0, lon=0), "0/0"),
    ("time_usec 2^63+5", False, _set(time_usec=2**63 + 5), "time_usec"),
    ("time_usec 2^64-1", False, _set(time_usec=2**64 - 1), "time_usec"),
    ("last seen 2^62 us", True, _set(last_seen_usec=2**62), "last_seen"),
    ("NaN visibility", False, _set(visibility=math.nan), "visibility"),
    ("infinite north", True, _set(north=math.inf), "north"),
    ("north 3e38 m", False, _set(north=3e38), "north_m"),
    ("NaN covariance", False, _set(cov_nn=math.nan), "cov"),
    ("subnormal covariance", False, _set(cov_nn=1e-45, cov_ee=1e-45, cov_ne=0.0), "cov_nn"),
    ("latitude 91 deg", True, _set(lat=910_000_000), "lat"),
]


def test_each_bad_report_is_rejected_logged_and_not_stored(start_hq, tmp_path: Path) -> None:
    hq = start_hq()
    for n, (what, geo, spoil, field) in enumerate(BAD_REPORTS, start=1):
        with SimRobot(10 + n, hq.address) as robot:  # one robot each: refusals are rate-limited
            msg = robot.report_msg(robot.victim(n, 1.0, 2.0, geo=GEO if geo else None))
            spoil(msg)
            robot.send(msg)
            assert ack_for(robot, msg.report_seq).result == REJECTED, what
            line = hq.wait_line(f"from system {robot.sysid} ", 3.0, stderr=True)
            assert "rejected report" in line and field in line, (what, line)
    with SimRobot(3, hq.address) as robot:
        good = robot.report_msg(robot.victim(99, 1.0, 1.0, geo=GEO))
        robot.send(good)
        assert ack_for(robot, good.report_seq).result == ACCEPTED
    assert hq.stop() == 0
    assert not any("Traceback" in line for line in hq.stderr)
    with Registry(hq.db) as reg:
        assert reg.report_count() == 1
        assert [s.report.victim_id for s in reg.sources()] == [99]
    hq2 = start_hq(db=hq.db)  # and the next start is clean
    with SimRobot(3, hq2.address) as robot:
        robot.send(good)
        assert ack_for(robot, good.report_seq).result == DUPLICATE
    assert hq2.stop() == 0


def test_bad_status_and_origin_are_refused_not_stored(start_hq) -> None:
    hq = start_hq()
    with SimRobot(4, hq.address) as robot:
        m = robot.m
        robot.send(m.MAVLink_rescue_status_message(10, math.nan, math.inf, 40.0, 7, 1, 0, 0))
        hq.wait_line("refused RESCUE_STATUS from system 4", 3.0, stderr=True)
        robot.send(m.MAVLink_gps_global_origin_message(473977420, 85455940, -(2**31), 0))
        line = hq.wait_line("refused GPS_GLOBAL_ORIGIN from system 4", 3.0, stderr=True)
        assert "altitude" in line
        robot.send(m.MAVLink_statustext_message(2, b"\xff\xfe\x80 not utf-8 \xc3"))
        good = robot.report_msg(robot.victim(1, 1.0, 1.0))
        robot.send(good)
        assert ack_for(robot, good.report_seq).result == ACCEPTED
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        (r,) = reg.robots()
        assert (r.status, r.origin) == (None, None)


def _good(victim: int, **over: Any) -> dict[str, Any]:
    report = VictimReport(
        victim_id=victim,
        robot_sysid=1,
        state=1,  # type: ignore[arg-type]
        urgency=2,  # type: ignore[arg-type]
        visibility_pct=30.0,
        north_m=1.0,
        east_m=1.0,
        down_m=0.0,
        cov_ne_m2=((0.25, 0.0), (0.0, 0.25)),
        observations=3,
        first_seen_unix_s=1_700_000_000.0,
        last_seen_unix_s=1_700_000_001.0,
        lat_deg=GEO[0],
        lon_deg=GEO[1],
        alt_m=GEO[2],
    )
    d = json.loads(report_payload(report))
    d.update(over)
    return d


def _plant_bad_rows(db_path: Path) -> None:
    """Rows an older rescue-hq could have written, and rows damaged on disk."""
    Registry(db_path).close()  # the schema
    payloads: list[str | bytes] = [
        json.dumps(_good(1, lat_deg=0.0, lon_deg=0.0)),  # 0/0 "global"
        json.dumps(_good(2, lat_deg=0.0, lon_deg=0.0)),  # two of them reach the merge
        json.dumps(_good(3, last_seen_unix_s=2.0**62 / 1e6)),  # year 148108
        json.dumps(_good(4, visibility_pct=math.nan)),  # NaN (Python writes it as NaN)
        json.dumps(_good(5, observations=-4)),  # a negative count
        b'{"victim_id": 6, "robot_sysid": 1, \xff\xfe not utf-8',
        json.dumps(_good(7)),  # the one good row
    ]
    db = sqlite3.connect(db_path, isolation_level=None)
    for victim, payload in enumerate(payloads, start=1):
        db.execute("INSERT INTO hq_victims (hq_id, created_unix_s) VALUES (?, 0)", (victim,))
        db.execute(
            "INSERT INTO sources VALUES (1, ?, ?, 1, 1, 0, 1700000000.0, ?)",
            (victim, victim, payload),
        )
    db.execute(
        "INSERT INTO robots VALUES (1, 191, 0, 0, ?, 0, 95.0, 8.5, 400.0)",
        ('{"fps": NaN, "flags": 7}',),
    )
    db.execute("INSERT INTO actions (robot_sysid, victim_id, action, created_unix_s)"
               " VALUES (1, 7, 9, 0)")  # fmt: skip
    db.execute(
        "INSERT INTO meta VALUES ('default_origin', ?)",
        (json.dumps({"lat_deg": 0.0, "lon_deg": 0.0, "alt_m": 0.0}),),
    )
    db.close()


def test_bad_rows_on_disk_are_skipped_at_every_start(start_hq, tmp_path: Path) -> None:
    db = tmp_path / "old.sqlite"
    _plant_bad_rows(db)
    for command in (["list"], ["export", "--out", str(tmp_path / "out")]):
        result = subprocess.run(
            [sys.executable, "-m", "hq.cli", *command, "--db", str(db)],
            cwd=REPO, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        assert "Traceback" not in result.stderr
        assert "sources robot 1 victim 3 is unusable" in result.stderr
    hq = start_hq(db=db)
    with SimRobot(2, hq.address) as robot:
        good = robot.report_msg(robot.victim(1, 1.0, 1.0))  # local NED: never merged with 1:7
        robot.send(good)
        assert ack_for(robot, good.report_seq).result == ACCEPTED
    assert hq.stop() == 0
    assert not any("Traceback" in line for line in hq.stderr)
    with Registry(db) as reg:
        victims = hq_victims(reg)
        assert sorted(v.sources for v in victims) == [((1, 7),), ((2, 1),)]
        # six sources, robot 1's origin and status, the action, the default origin
        assert len(reg.bad_rows) == 10
