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

from fusion.types import Sensor
from hq.pictures import PictureAssembler
from hq.registry import Registry
from hq.registry_file import SCHEMA_VERSION
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
        assert reg.picture_versions()[(3, 7, Sensor.COLOUR)][0] == 50


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
    version = db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0]
    assert version == str(SCHEMA_VERSION)
    db.execute("UPDATE pictures SET jpeg = x'00'")  # damaged on disk
    db.close()
    with Registry(path) as reg:
        assert reg.picture(1, 2) is None  # skipped, said once
        assert "pictures robot 1 victim 2" in next(iter(reg.bad_rows))


def test_a_version_3_registry_keeps_its_pictures_as_colour_ones(tmp_path: Path) -> None:
    """A registry written before pictures had a kind: its pictures are the colour
    camera's, and a thermal picture of the same victim is kept beside them."""
    path = tmp_path / "v3.sqlite"
    Registry(path).close()
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("DROP TABLE pictures")
    db.execute(  # exactly what version 3 wrote
        "CREATE TABLE pictures (robot_sysid INTEGER NOT NULL, victim_id INTEGER NOT NULL,"
        " picture_id INTEGER NOT NULL, received_unix_s REAL NOT NULL, jpeg BLOB NOT NULL,"
        " PRIMARY KEY (robot_sysid, victim_id))"
    )
    db.execute("INSERT INTO pictures VALUES (1, 2, 30, 1.7e9, ?)", (_jpeg(120),))
    db.execute("INSERT INTO pictures VALUES (1, 5, 31, 1.7e9, x'00')")  # damaged before
    db.execute("UPDATE meta SET value='3' WHERE key='schema_version'")
    db.close()
    with Registry(path) as reg:
        assert reg.picture(1, 2) == _jpeg(120)
        assert reg.picture_id(1, 2, Sensor.COLOUR) == 30
        assert reg.picture(1, 2, Sensor.THERMAL) is None
        assert reg.store_picture(1, 2, 32, _jpeg(90, 3), 1.7e9 + 1, Sensor.THERMAL)
        assert not reg.store_picture(1, 2, 31, _jpeg(90, 4), 1.7e9 + 2, Sensor.THERMAL)  # older
        assert reg.picture(1, 2, Sensor.THERMAL) == _jpeg(90, 3)
        assert reg.picture(1, 2) == _jpeg(120)  # the colour one stays
        assert set(reg.picture_versions()) == {
            (1, 2, Sensor.COLOUR), (1, 2, Sensor.THERMAL), (1, 5, Sensor.COLOUR)
        }  # fmt: skip
        assert reg.picture(1, 5) is None and "victim 5" in " ".join(reg.bad_rows)
    db = sqlite3.connect(path, isolation_level=None)
    version = db.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0]
    assert version == str(SCHEMA_VERSION)
    db.execute("UPDATE pictures SET kind='infrared' WHERE kind='thermal'")  # edited by hand
    db.close()
    with Registry(path) as reg:
        assert (1, 2, Sensor.THERMAL) not in reg.picture_versions()
        assert any("infrared" in row for row in reg.bad_rows)


def test_a_thermal_picture_beside_the_colour_one_at_a_real_hq(start_hq) -> None:
    hq: HqProcess = start_hq("--web", "127.0.0.1:0")
    url = hq.wait_line("console on", 15.0).split("console on ", 1)[1].strip()
    colour, thermal = _jpeg(900, 1), _jpeg(700, 2)
    with SimRobot(3, hq.address, tunnel=True) as robot:
        m = robot.codec.module
        report = robot.report_msg(robot.victim(7, 2.0, 1.0))
        robot.send(report)
        assert ack_for(robot, report.report_seq).result == 0
        for pid, data, kind in ((40, colour, Sensor.COLOUR), (41, thermal, Sensor.THERMAL)):
            chunks = picture.split(pid, 7, data, kind)
            for c in chunks[:-1]:
                robot.send(c.to_msg(m))
            robot.send(chunks[-1].asking().to_msg(m))
            assert _picture_ack(robot, pid).result == STORED
        assert "thermal picture robot 3 victim 7 #41" in hq.wait_line("thermal picture", 5.0)
        # A newer colour picture does not replace the thermal one, nor the reverse.
        chunks = picture.split(42, 7, _jpeg(500, 3))
        for c in chunks[:-1]:
            robot.send(c.to_msg(m))
        robot.send(chunks[-1].asking().to_msg(m))
        assert _picture_ack(robot, 42).result == STORED
        # An older thermal one is not wanted: REJECTED.
        robot.send(picture.split(39, 7, _jpeg(300, 5), Sensor.THERMAL)[0].asking().to_msg(m))
        assert _picture_ack(robot, 39).result == REJECTED
        deadline = time.monotonic() + 10.0
        while True:
            state = json.loads(_get(url + "api/state")[1])
            card = state["victims"][0] if state["victims"] else {}
            if card.get("thermal_picture") and card.get("picture", "").endswith("-42"):
                break
            assert time.monotonic() < deadline, state
            time.sleep(0.2)
        assert card["picture"] == f"/victims/{card['id']}/picture?v=3-7-42"
        assert card["thermal_picture"] == f"/victims/{card['id']}/picture?kind=thermal&v=3-7-41"
        assert _get(url + card["thermal_picture"].lstrip("/"))[:2] == (200, thermal)
        assert _get(url + card["picture"].lstrip("/"))[:2] == (200, _jpeg(500, 3))
        status, body, _ = _get(url + f"victims/{card['id']}/picture?kind=sonar")
        assert status == 400 and b"colour or thermal" in body
    assert hq.stop() == 0
    assert not any("Traceback" in line for line in hq.stderr), hq.stderr


def test_the_companions_thermal_picture_is_chosen_sent_and_delivered_to_a_real_hq(
    start_hq, tmp_path: Path
) -> None:
    """The companion's chooser picks a warm victim's thermal view and its colour view,
    its store keeps both, its sender sends both through TUNNEL at its rate, and the
    real rescue-hq stores each as its kind and serves it; the sender hears STORED."""
    import cv2
    import numpy as np

    from companion.config import PicturesConfig
    from companion.reporting.pictures import resume
    from companion.sources.thermal import ThermalFrame
    from companion.storage.store import Store, StoredPicture
    from fusion.registry import Victim
    from fusion.types import Detection, Observation, TrackState, Urgency

    hq: HqProcess = start_hq("--web", "127.0.0.1:0")
    url = hq.wait_line("console on", 15.0).split("console on ", 1)[1].strip()
    victim = Victim(
        victim_id=7, state=TrackState.CONFIRMED, urgency=Urgency.CRITICAL, visibility_pct=6.0,
        north_m=2.0, east_m=1.0, cov_ne_m2=((0.09, 0.0), (0.0, 0.09)), observations=9,
        first_seen_unix_s=100.0, last_seen_unix_s=110.0, log_odds=3.0, merged_into=None,
    )  # fmt: skip
    obs = Observation(110.0, 2.05, 1.0, ((0.04, 0.0), (0.0, 0.04)), 6.0, 0.8, 4.0)
    rng = np.random.default_rng(5)
    temps = (18.0 + rng.random((120, 160)) * 0.5).astype(np.float32)
    temps[40:58, 70:84] = 33.5  # a head and a hand out of the rubble
    warm = Detection(0.0, 77.0, 49.0, (70, 40, 14, 18), 252.0, 0.8, source="thermal")
    image = cv2.resize(
        (rng.random((120, 160, 3)) * 255).astype(np.uint8), (640, 480), interpolation=0
    )
    seen = Detection(0.0, 300.0, 260.0, (260, 180, 80, 80), 3200.0, 0.7)
    store = Store(tmp_path / "companion.sqlite")
    cfg = PicturesConfig(rate_bytes_s=20_000.0)
    with SimRobot(3, hq.address, tunnel=True) as robot:
        report = robot.report_msg(robot.victim(7, 2.0, 1.0, urgency=Urgency.CRITICAL))
        robot.send(report)
        assert ack_for(robot, report.report_seq).result == 0
        m = robot.codec.module
        chooser, sender = resume(cfg, store, lambda c: robot.send(c.to_msg(m)), signed=False)
        (thermal,) = chooser.consider_thermal(
            ThermalFrame(temps, 1.0, 110.0, 1), [(warm, obs)], [victim]
        )
        (colour,) = chooser.consider(image, [(seen, obs)], [victim], 110.0)
        for pid, c in ((20, colour), (21, thermal)):
            p = StoredPicture(7, pid, c.score, c.taken_unix_s, c.jpeg, kind=c.kind)
            store.put_picture(p)
            sender.offer(p)
        deadline = time.monotonic() + 20.0
        while sender.counters.delivered < 2:
            assert time.monotonic() < deadline, sender.counters
            sender.poll()
            for rx in robot.receive(0.05):
                if rx.msg.get_type() == "RESCUE_PICTURE_ACK":
                    sender.on_ack(picture.Ack.from_msg(rx.msg))
    assert [p.delivered for p in store.pictures()] == [True, True]
    store.close()
    deadline = time.monotonic() + 10.0
    while True:
        state = json.loads(_get(url + "api/state")[1])
        card = state["victims"][0]
        if card["picture"] and card["thermal_picture"]:
            break
        assert time.monotonic() < deadline, state
        time.sleep(0.2)
    assert _get(url + card["thermal_picture"].lstrip("/"))[:2] == (200, thermal.jpeg)
    assert _get(url + card["picture"].lstrip("/"))[:2] == (200, colour.jpeg)
    assert hq.stop() == 0
    with Registry(hq.db) as reg:
        assert reg.picture(3, 7, Sensor.THERMAL) == thermal.jpeg
        assert reg.picture(3, 7) == colour.jpeg
