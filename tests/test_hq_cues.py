"""Which sensing saw a victim (colour body, colour part, warm) at the HQ: checked where
a report enters, stored, merged across robots, and shown wherever the operator meets
a victim (the console's state, the table, the exports); an older robot's or
registry's victims read as not known."""

from __future__ import annotations

import csv
import io
import json
import random
import sqlite3
import subprocess
import sys
import time
import urllib.request
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
from hqproc import ACCEPTED, REPO

from bench.hq_console import HqConsoleProcess
from fusion.types import Cue, TrackState, Urgency, VictimReport
from hq import export, records, wire
from hq.records import BadRecord, IncomingReport
from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.table import victim_rows
from hq.view import hq_victims
from mavlink_io.codec import Codec

ORIGIN = "47.397742,8.545594,488"
T_UNIX_S = 1_700_000_000.0


def _report(robot: int, victim: int, north_m: float, cues: Cue, **kw: Any) -> VictimReport:
    fields: dict[str, Any] = {
        "victim_id": victim, "robot_sysid": robot, "state": TrackState.CONFIRMED,
        "urgency": Urgency.CRITICAL, "visibility_pct": 5.0, "north_m": north_m, "east_m": 2.0,
        "down_m": 0.0, "cov_ne_m2": ((0.25, 0.0), (0.0, 0.25)), "observations": 3,
        "first_seen_unix_s": T_UNIX_S - 10.0, "last_seen_unix_s": T_UNIX_S, "cues": cues,
    }  # fmt: skip
    return VictimReport(**{**fields, **kw})


def _incoming(report: VictimReport, seq: int) -> IncomingReport:
    return IncomingReport(report, seq, int(T_UNIX_S * 1e6) + seq, 0, 191, T_UNIX_S)


def _wire(robot: int, victim: int, cues_byte: int) -> IncomingReport:
    """What the HQ's entry point makes of a radio report carrying ``cues_byte``."""
    tx, rx = Codec(robot, 191), Codec(245, 190)
    msg = wire.report_to_msg(tx, _report(robot, victim, 1.0, Cue(0)), victim, T_UNIX_S)
    msg.cues = cues_byte
    (back,) = rx.feed(tx.encode(msg))
    return wire.incoming_report(back, T_UNIX_S)


def test_every_cue_byte_at_the_entry_point_gives_known_cues_and_keeps_the_report(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level("WARNING")
    for value in range(256):
        got = _wire(9, value + 1, value).report
        assert got.cues == Cue(value & 7), value
        assert records.check_report(got) is got  # storable as it is
        assert got.victim_id == value + 1 and got.urgency is Urgency.CRITICAL
    said = [r.getMessage() for r in caplog.records if "cues" in r.getMessage()]
    assert said and "robot 9" in said[0] and "has bits no cue names" in said[0]
    assert len(said) == 1  # once a minute per robot, not per report


def test_fuzzed_stored_cues_are_refused_as_a_bad_row_never_a_crash() -> None:
    good = json.loads(records.report_payload(_report(1, 1, 1.0, Cue.WARM)))
    assert good["cues"] == 4
    assert records.report_from_payload(json.dumps(good)).cues == Cue.WARM
    rng = random.Random(41)
    values: list[Any] = [-1, 8, 255, 2**40, -(2**70), 1.5, 4.0, "4", None, True, [4], {"w": 1}]
    values += [rng.randint(-(2**63), 2**63) for _ in range(200)]
    for value in values:
        payload = json.dumps({**good, "cues": value})
        if isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= 7:
            assert records.report_from_payload(payload).cues == Cue(value)
        else:
            with pytest.raises(BadRecord, match="cues"):
                records.report_from_payload(payload)
    # A payload written before the cues were kept: not known.
    del good["cues"]
    assert records.report_from_payload(json.dumps(good)).cues == Cue(0)


def test_registry_merges_cues_and_reads_old_rows_as_not_known(tmp_path: Path) -> None:
    db = tmp_path / "hq.sqlite"
    with Registry(db) as reg:
        reg.store_reports(
            [
                _incoming(_report(1, 1, 1.0, Cue.COLOUR_BODY), 1),
                _incoming(_report(2, 1, 1.1, Cue.WARM), 1),  # the same person, robot 2
                _incoming(_report(1, 2, 30.0, Cue.WARM), 2),
                _incoming(_report(3, 1, 60.0, Cue(0)), 1),  # a robot that does not say
            ]
        )
        by_source = {v.sources: v for v in hq_victims(reg)}
    assert by_source[((1, 1), (2, 1))].cues == Cue.COLOUR_BODY | Cue.WARM
    assert by_source[((1, 2),)].cues == Cue.WARM
    assert by_source[((3, 1),)].cues == Cue(0)
    rows = "\n".join(victim_rows(list(by_source.values()), T_UNIX_S, colour=False))
    assert "CUES" in rows.splitlines()[0]
    lines = {line.split()[0]: line for line in rows.splitlines()[1:]}
    assert [line.split()[-1] for line in lines.values()] == ["body+warm", "warm", "-"]
    # Rows of an older rescue-hq: the payload has no cues at all.
    with sqlite3.connect(db) as raw:
        for table in ("sources", "reports"):
            for rowid, payload in raw.execute(f"SELECT rowid, payload FROM {table}").fetchall():
                d = json.loads(payload)
                del d["cues"]
                raw.execute(f"UPDATE {table} SET payload=? WHERE rowid=?", (json.dumps(d), rowid))
    with Registry(db) as reg:
        victims = hq_victims(reg)
        assert len(victims) == 3 and all(v.cues == Cue(0) for v in victims)
        assert not reg.bad_rows


def _get(url: str) -> Any:
    with urllib.request.urlopen(url, timeout=10) as resp:
        return json.loads(resp.read())


def test_cues_reach_the_console_table_and_exports_of_a_real_hq(tmp_path: Path) -> None:
    out = tmp_path / "exports"
    hq = HqConsoleProcess(tmp_path, "--origin", ORIGIN, "--export-dir", str(out))
    try:
        with SimRobot(1, hq.address) as r1, SimRobot(2, hq.address) as r2:
            sent = [
                (r1, r1.victim(1, 3.0, 4.0, cues=Cue.COLOUR_BODY)),
                (r2, r2.victim(7, 3.05, 4.0, cues=Cue.WARM)),  # the same person
                (r1, r1.victim(2, 20.0, -5.0, urgency=Urgency.CRITICAL, cues=Cue.WARM)),
                (r2, r2.victim(8, -30.0, 9.0, cues=Cue.COLOUR_PART)),
            ]
            for robot, report in sent:
                msg = robot.report_msg(report)
                robot.send(msg)
                ack = robot.wait_for("RESCUE_ACK", 5.0, seq=msg.report_seq).msg
                assert ack.result == ACCEPTED
            # A newer robot with a cue bit this HQ does not know: masked, said, stored.
            odd = r1.report_msg(r1.victim(3, -10.0, -10.0))
            odd.cues = 0x84
            r1.send(odd)
            assert r1.wait_for("RESCUE_ACK", 5.0, seq=odd.report_seq).msg.result == ACCEPTED
        deadline = time.monotonic() + 10.0
        while True:
            state = _get(hq.url + "api/state")
            if len(state["victims"]) == 4 or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        seen = {
            tuple((s["robot"], s["victim_id"]) for s in v["sources"]): (v["cues"], v["seen"])
            for v in state["victims"]
        }
        assert seen == {
            ((1, 1), (2, 7)): (["colour_body", "warm"], "colour body · warm"),
            ((1, 2),): (["warm"], "warm"),
            ((2, 8),): (["colour_part"], "colour part"),
            ((1, 3),): (["warm"], "warm"),
        }
    finally:
        assert hq.stop() == 0, hq.stderr
    assert any("cues 0x84 has bits no cue names" in line for line in hq.stderr), hq.stderr
    assert not any("Traceback" in line for line in hq.stderr)
    features = json.loads((out / export.GEOJSON_NAME).read_text())["features"]
    by_id = {
        tuple((s["robot"], s["victim_id"]) for s in f["properties"]["sources"]): f["properties"]
        for f in features
    }
    assert by_id[((1, 1), (2, 7))]["cues"] == ["colour_body", "warm"]
    assert by_id[((1, 2),)]["cues"] == ["warm"]
    rows = list(csv.DictReader(io.StringIO((out / export.CSV_NAME).read_text())))
    assert sorted(r["cues"] for r in rows) == ["colour_body warm", "colour_part", "warm", "warm"]
    ns = {"k": "http://www.opengis.net/kml/2.2"}
    descriptions = [
        d.text or ""
        for d in ET.parse(out / export.KML_NAME).getroot().iterfind(".//k:description", ns)
    ]
    assert sum("seen: colour body · warm" in d for d in descriptions) == 1
    listed = subprocess.run(
        [sys.executable, "-m", "hq.cli", "list", "--db", str(hq.db)],
        cwd=REPO, capture_output=True, text=True, timeout=60, check=True,
    ).stdout  # fmt: skip
    assert listed.count("body+warm") == 1 and listed.count(" warm\n") == 2
