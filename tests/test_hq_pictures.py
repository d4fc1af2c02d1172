"""Evidence pictures at a real rescue-hq: chunks in (direct and in TUNNEL, lost,
reordered, repeated), the bitmap acknowledgements, the stored JPEG on the console,
refusals of bad chunks with a line and no traceback, and the bounded partials."""

from __future__ import annotations

import json
import random
import sqlite3
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from hqproc import HqProcess, ack_for, hq_starter

from hq.pictures import PictureAssembler
from hq.registry import Registry
from hq.simrobot import SimRobot
from mavlink_io import picture

STORED, PARTIAL, REJECTED = 0, 1, 2


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[object]:
    yield from hq_starter(tmp_path)


def _jpeg(size: int, seed: int = 1) -> bytes:
    return b"\xff\xd8" + random.Random(seed).randbytes(size - 4) + b"\xff\xd9"


def _picture_ack(robot: SimRobot, picture_id: int, timeout_s: float = 3.0) -> object:
    return robot.wait_for("RESCUE_PICTURE_ACK", timeout_s, picture_id=picture_id).msg


def _get(url: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as resp:
            kind = resp.headers.get("Content-Type", "")
            if resp.headers.get("X-Content-Type-Options") == "nosniff":
                kind += "; nosniff"
            return resp.status, resp.read(), kind
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read(), exc.headers.get("Content-Type", "")


@pytest.mark.parametrize("tunnel", [False, True])
def test_a_picture_in_chunks_is_stored_acknowledged_and_served(start_hq, tunnel: bool) -> None:
    hq: HqProcess = start_hq("--web", "127.0.0.1:0")
    url = hq.wait_line("console on", 15.0).split("console on ", 1)[1].strip()
    data = _jpeg(1500)
    m = None
    with SimRobot(3, hq.address, tunnel=tunnel) as robot:
        m = robot.codec.module
        report = robot.report_msg(robot.victim(7, 2.0, 1.0))
        robot.send(report)
        assert ack_for(robot, report.report_seq).result == 0
        chunks = picture.split(50, 7, data)
        order = list(range(len(chunks)))
        random.Random(2).shuffle(order)
        sent = [i for i in order if i not in (3, 11)]  # two lost
        for i in sent[:-1]:
            robot.send(chunks[i].to_msg(m))
        robot.send(chunks[sent[-1]].asking().to_msg(m))
        ack = _picture_ack(robot, 50)
        assert ack.result == PARTIAL and ack.target_system == 3
        assert picture.from_bitmap(bytes(ack.received), len(chunks)) == frozenset(sent)
        robot.send(chunks[3].to_msg(m))  # one of the two lost ones
        robot.send(chunks[5].to_msg(m))  # a duplicate
        robot.send(chunks[11].to_msg(m))  # the last missing one: stored, said at once
        ack = _picture_ack(robot, 50)
        assert ack.result == STORED
        line = hq.wait_line("picture robot 3 victim 7", 5.0)
        assert "1500 bytes" in line
        robot.send(chunks[0].asking().to_msg(m))  # the robot missed the STORED: told again
        assert _picture_ack(robot, 50).result == STORED
        # An older picture of the same victim is not wanted any more: not kept, so
        # never answered STORED.
        robot.send(picture.split(49, 7, _jpeg(300, 5))[0].asking().to_msg(m))
        assert _picture_ack(robot, 49).result == REJECTED
        # The console shows it on the victim's card, at a versioned address.
        deadline = time.monotonic() + 10.0
        while True:
            state = json.loads(_get(url + "api/state")[1])
            card = next(v for v in state["victims"] if (3, 7) in [
                (s["robot"], s["victim_id"]) for s in v["sources"]])  # fmt: skip
            if card["picture"] or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert card["picture"] == f"/victims/{card['id']}/picture?v=3-7-50"
        status, body, kind = _get(url + card["picture"].lstrip("/"))
        assert (status, kind, body) == (200, "image/jpeg; nosniff", data)
        status, body, _ = _get(url + "victims/999/picture")
        assert status == 404 and b"no robot has sent one" in body
        assert _get(url + f"victims/{card['id']}/picture?v=../x")[0] == 400
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        assert reg.picture(3, 7) == data
        assert reg.picture_versions()[(3, 7)][0] == 50


def test_bad_chunks_are_refused_with_a_line_and_the_hq_goes_on(start_hq) -> None:
    hq: HqProcess = start_hq()
    with SimRobot(4, hq.address) as robot:
        m = robot.codec.module
        bad = picture.split(60, 2, _jpeg(400))[0].to_msg(m)
        bad.chunk_index = 9  # beyond the 5 chunks of 400 bytes
        robot.send(bad)
        assert "chunk_index 9" in hq.wait_line("refused RESCUE_PICTURE_CHUNK", 5.0, stderr=True)
        # A whole picture whose bytes do not match its CRC: REJECTED, not stored.
        chunks = picture.split(61, 2, _jpeg(200))
        forged = picture.Chunk(61, 2, chunks[0].crc32, 200, 1, bytes(len(chunks[1].data)))
        for c in (chunks[0], forged, chunks[2].asking()):
            robot.send(c.to_msg(m))
        assert _picture_ack(robot, 61).result == REJECTED
        # Still serving: a good picture is stored.
        good = picture.split(62, 2, _jpeg(200, 9))
        for c in good:
            robot.send(c.to_msg(m))
        assert _picture_ack(robot, 62).result == STORED
    assert hq.stop() == 0
    assert not any("Traceback" in line for line in hq.stderr), hq.stderr
    with Registry(hq.db) as reg:
        assert reg.picture(4, 2) == _jpeg(200, 9)


def test_partial_pictures_are_bounded_per_robot_in_all_and_in_time() -> None:
    a = PictureAssembler(max_per_robot=2, max_total=3, idle_s=10.0)
    first = [picture.split(pid, 1, _jpeg(300))[0] for pid in (1, 2, 3)]
    for i, c in enumerate(first):
        a.add(1, c, float(i))
    assert len(a) == 2 and a.counters.dropped == 1  # robot 1's oldest went
    a.add(2, picture.split(9, 1, _jpeg(300))[0], 3.0)
    a.add(3, picture.split(9, 1, _jpeg(300))[0], 4.0)
    assert len(a) == 3 and a.counters.dropped == 2  # the total bound
    a.forget_idle(13.5)
    assert len(a) == 1 and a.counters.expired == 2
    with pytest.raises(picture.BadChunk):  # contradicts the held picture: nothing changes
        a.add(3, picture.split(9, 2, _jpeg(300))[1], 5.0)
    assert len(a) == 1


def test_a_version_2_registry_gains_the_pictures_table(tmp_path: Path) -> None:
    path = tmp_path / "v2.sqlite"
    Registry(path).close()
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("DROP TABLE pictures")  # what version 2 wrote
    db.execute("UPDATE meta SET value='2' WHERE key='schema_version'")
    db.close()
    with Registry(path) as reg:
        assert reg.store_picture(1, 2, 3, _jpeg(100), 0.0)
        assert not reg.store_picture(1, 2, 2, _jpeg(100, 2), 0.0)  # older
        assert not reg.store_picture(1, 2, 3, _jpeg(100), 0.0)  # this very one
        assert reg.picture(1, 2) == _jpeg(100)
    db = sqlite3.connect(path, isolation_level=None)
    assert db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0] == "3"
    db.execute("UPDATE pictures SET jpeg = x'00'")  # damaged on disk
    db.close()
    with Registry(path) as reg:
        assert reg.picture(1, 2) is None  # skipped, said once
        assert "pictures robot 1 victim 2" in next(iter(reg.bad_rows))
