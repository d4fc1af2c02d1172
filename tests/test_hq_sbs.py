"""rescue-hq's SBS-1 feed as a stock QGroundControl reads it.

``QgcAdsbClient`` connects over TCP on 127.0.0.1 and parses each line the way
QGC's ADS-B link does (src/ADSB in QGC's source): lines split on LF, ``MSG`` at
the start, the message type at character 4, fields split on ``,``; MSG,3 creates a
track from the hex address (field 4), altitude in feet (11, an integer), latitude
(14), longitude (15) and the alert flag (19, exactly ``1``); MSG,1/5/6 set the
callsign (10) of a track that exists. The real `rescue-hq` process runs with three
simulated robots (hq.simrobot) and the registry decides what the truth is.
"""

from __future__ import annotations

import queue
import re
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from fusion.geodesy import ned_to_geodetic
from fusion.types import GlobalOrigin, TrackState, Urgency
from hq import sbs
from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.view import hq_victims
from mavlink_io.statustext import callsign

REPO = Path(__file__).resolve().parents[1]
ORIGIN = GlobalOrigin(47.397742, 8.545594, 488.0)  # the operator's --origin
APPEAR_LIMIT_S = 2.0  # the goal: a confirmed victim on QGC's map within 2 s
_INT = re.compile(r"^\s*[+-]?\d+\s*$")  # what QString::toInt accepts


@dataclass
class Track:
    icao: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    alert: bool
    callsign: str = ""
    updates: list[float] = field(default_factory=list)  # monotonic times of MSG,3


class QgcAdsbClient:
    """An ADS-B client that keeps what QGC's ADSBVehicleManager would keep."""

    def __init__(self, address: tuple[str, int]) -> None:
        self.sock = socket.create_connection(address, timeout=5.0)
        self.tracks: dict[int, Track] = {}
        self.bad_lines: list[str] = []
        self._buffer = b""

    def close(self) -> None:
        self.sock.close()

    def poll(self, timeout_s: float) -> None:
        readable, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        if not readable:
            return
        data = self.sock.recv(65536)
        if not data:
            raise ConnectionError("the SBS-1 server closed the connection")
        self._buffer += data
        *whole, self._buffer = self._buffer.split(b"\n")
        for raw in whole:
            self._parse(raw.decode("ascii") + "\n")

    def _parse(self, line: str) -> None:
        if not line.endswith("\r\n"):
            self.bad_lines.append(line)  # dump1090 (and we) end lines in CRLF
        if not line.startswith("MSG") or len(line) <= 4 or not line[4].isdigit():
            self.bad_lines.append(line)
            return
        msg_type = int(line[4])
        values = line.split(",")
        if msg_type == 2 or msg_type > 6 or len(values) <= 19:
            self.bad_lines.append(line)
            return
        icao = int(values[4], 16)
        if msg_type in (1, 5, 6):
            callsign = values[10].strip()
            if callsign and icao in self.tracks:  # QGC ignores it for an unknown track
                self.tracks[icao].callsign = callsign
        elif msg_type == 3:
            alt = values[11].removesuffix("H")
            if not _INT.match(alt) or not _INT.match(values[19]):
                self.bad_lines.append(line)
                return
            lat, lon = float(values[14]), float(values[15])
            track = self.tracks.setdefault(icao, Track(icao, lat, lon, 0.0, False))
            track.lat_deg, track.lon_deg = lat, lon
            track.alt_m = int(alt) * 0.3048
            track.alert = int(values[19]) == 1
            track.updates.append(time.monotonic())

    def wait(self, predicate: Callable[[dict[int, Track]], bool], timeout_s: float) -> float:
        """Seconds until ``predicate(self.tracks)`` holds; TimeoutError after timeout_s."""
        start = time.monotonic()
        while not predicate(self.tracks):
            left = start + timeout_s - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"tracks now: {self.tracks}")
            self.poll(min(left, 0.05))
        return time.monotonic() - start

    def by_callsign(self, callsign: str) -> Track | None:
        return next((t for t in self.tracks.values() if t.callsign == callsign), None)


class Hq:
    """A running `rescue-hq` with an SBS-1 feed on a free loopback port."""

    def __init__(self, tmp: Path, *extra: str) -> None:
        self.db = tmp / "hq.sqlite"
        cmd = [
            sys.executable, "-m", "hq.cli", "--listen", "udpin:127.0.0.1:0",
            "--db", str(self.db), "--no-table", "--duration-s", "120",
            "--sbs", "127.0.0.1:0", *extra,
        ]  # fmt: skip
        self.proc = subprocess.Popen(
            cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self._pump = threading.Thread(target=self._read, daemon=True)
        self._pump.start()
        self.address = ("127.0.0.1", int(self.wait_line("listening on").rsplit(":", 1)[1]))
        self.sbs_address = ("127.0.0.1", int(self.wait_line("SBS-1 feed").rsplit(":", 1)[1]))

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))

    def wait_line(self, text: str, timeout_s: float = 15.0) -> str:
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                break
            if text in line:
                return line
        raise TimeoutError(f"no line with {text!r} from rescue-hq")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.communicate(timeout=15)


@pytest.fixture
def hq(tmp_path: Path) -> Iterator[Hq]:
    origin = f"{ORIGIN.lat_deg},{ORIGIN.lon_deg},{ORIGIN.alt_m}"
    server = Hq(tmp_path, "--origin", origin)
    yield server
    server.close()


def _ack(robot: SimRobot, seq: int) -> None:
    robot.wait_for("RESCUE_ACK", 5.0, acked_msgid=43100, seq=seq)


def test_three_robots_every_victim_a_labelled_track_within_2_s(hq: Hq) -> None:
    client = QgcAdsbClient(hq.sbs_address)
    robots = [SimRobot(sysid, hq.address) for sysid in (1, 2, 3)]
    try:
        # (robot index, victim id, north, east, urgency, reported lat/lon?) in mission order.
        # Robot 3 knows its EKF origin and reports lat/lon; 1 and 2 report NED only and
        # are placed with the operator's --origin.
        mission = [
            (0, 1, 4.0, 1.0, Urgency.LIGHT, False),
            (1, 1, -3.0, 6.0, Urgency.CRITICAL, False),
            (2, 4, 10.0, -2.0, Urgency.MEDIUM, True),
            (0, 2, 12.0, 8.0, Urgency.MEDIUM, False),
            (1, 2, 20.0, -5.0, Urgency.LIGHT, False),
            (2, 5, -8.0, -9.0, Urgency.CRITICAL, True),
        ]
        delays = []
        for index, victim_id, north, east, urgency, with_geo in mission:
            robot = robots[index]
            geo = ned_to_geodetic(ORIGIN, north, east, 0.0) if with_geo else None
            report = robot.victim(victim_id, north, east, urgency=urgency, geo=geo)
            msg = robot.report_msg(report)
            known = set(client.tracks)
            robot.send(msg)  # the robot confirms the victim now
            delays.append(
                client.wait(
                    lambda t, k=known: any(x.callsign for i, x in t.items() if i not in k), 5.0
                )
            )
            _ack(robot, msg.report_seq)
        with Registry(hq.db) as reg:
            victims = hq_victims(reg)
        assert len(victims) == len(mission) == len(client.tracks)
        labels = {Urgency.CRITICAL: "CRIT", Urgency.MEDIUM: "MED", Urgency.LIGHT: "LIGHT"}
        for v in victims:
            track = client.by_callsign(f"{labels[v.urgency]}{v.hq_id:02d}")
            assert track is not None, f"no track for HQ victim {v.hq_id}"
            assert len(track.callsign) <= 8
            # 1e-7 deg is 1 cm; the feed carries 7 decimals
            assert track.lat_deg == pytest.approx(v.lat_deg, abs=2e-7)
            assert track.lon_deg == pytest.approx(v.lon_deg, abs=2e-7)
            assert track.alt_m == pytest.approx(v.alt_m, abs=0.3048)  # whole feet
            assert track.alert == (v.urgency is Urgency.CRITICAL)
        print(f"confirmation to labelled track: max {max(delays) * 1e3:.0f} ms")
        assert max(delays) < APPEAR_LIMIT_S, f"delays {delays}"
        assert client.bad_lines == []
    finally:
        client.close()
        for robot in robots:
            robot.close()


def test_tracks_are_refreshed_and_a_late_client_gets_them_at_once(hq: Hq) -> None:
    with SimRobot(5, hq.address) as robot:
        msg = robot.report_msg(robot.victim(3, 2.0, 2.0, urgency=Urgency.MEDIUM))
        robot.send(msg)
        _ack(robot, msg.report_seq)
    client = QgcAdsbClient(hq.sbs_address)  # connects after the victim was confirmed
    try:
        assert client.wait(lambda t: len(t) == 1, 2.0) < 1.0
        track = next(iter(client.tracks.values()))
        client.wait(lambda _t: len(track.updates) >= 4, 6.0)
        gaps = [b - a for a, b in zip(track.updates, track.updates[1:], strict=False)]
        # refreshed every second: far inside QGC's expiry (120 s; 25 s in older QGC)
        assert max(gaps) < 2.0, gaps
    finally:
        client.close()


def test_marked_rescued_is_relabelled_once_then_no_longer_refreshed(hq: Hq) -> None:
    client = QgcAdsbClient(hq.sbs_address)
    try:
        with SimRobot(6, hq.address) as robot:
            for victim_id, urgency in ((1, Urgency.CRITICAL), (2, Urgency.LIGHT)):
                msg = robot.report_msg(
                    robot.victim(victim_id, 3.0 * victim_id, 0.0, urgency=urgency)
                )
                robot.send(msg)
                _ack(robot, msg.report_seq)
            client.wait(lambda t: sum(1 for x in t.values() if x.callsign) == 2, 5.0)
            crit = next(t for t in client.tracks.values() if t.callsign.startswith("CRIT"))
            assert crit.alert
            hq_id = int(crit.callsign[4:])
            done = subprocess.run(
                [sys.executable, "-m", "hq.cli", "mark", "--db", str(hq.db), "--id", str(hq_id),
                 "--rescued"],
                cwd=REPO, capture_output=True, text=True, timeout=30,
            )  # fmt: skip
            assert done.returncode == 0, done.stderr
            client.wait(lambda _t: crit.callsign == f"RESC{hq_id:02d}", 3.0)
            assert not crit.alert
            seen = len(crit.updates)
            light = next(t for t in client.tracks.values() if t.callsign.startswith("LIGHT"))
            light_seen = len(light.updates)
            end = time.monotonic() + 2.5
            while time.monotonic() < end:
                client.poll(0.1)
            assert len(crit.updates) == seen  # not refreshed: QGC drops it at its expiry
            assert len(light.updates) >= light_seen + 2  # the others still are
    finally:
        client.close()


def test_sbs_lines_field_positions() -> None:
    track = sbs.SbsTrack(0xF00007, "CRIT07", 47.3977421, -8.5455942, 1601, True)
    data = sbs.lines(track, 1_700_000_000.0)
    position, ident, tail = data.split(b"\r\n")
    assert tail == b""
    p = position.decode().split(",")
    assert len(p) == 22 and p[:2] == ["MSG", "3"] and p[4] == "F00007"
    assert (p[10], p[11], p[14], p[15], p[19]) == (
        "CRIT07",
        "1601",
        "47.3977421",
        "-8.5455942",
        "1",
    )
    i = ident.decode().split(",")
    assert len(i) == 22 and i[:2] == ["MSG", "1"] and i[10] == "CRIT07"


def test_callsign_fits_eight_characters() -> None:
    assert callsign("CRIT", 7) == "CRIT07"
    assert callsign("LIGHT", 123) == "LIGHT123"
    assert callsign("LIGHT", 1234) == "L1234"
    assert all(len(callsign(w, 10**7 - 1)) <= 8 for w in ("CRIT", "MED", "LIGHT", "FALSE"))


def test_not_placed_or_not_confirmed_victims_are_not_tracks() -> None:
    from hq.view import HqVictim

    def victim(hq_id: int, state: TrackState, geo: bool) -> HqVictim:
        return HqVictim(
            hq_id, ((1, hq_id),), Urgency.MEDIUM, 30.0, state, 1.0, 1.0, 0.0,
            ((0.25, 0.0), (0.0, 0.25)), 0.5,
            47.0 if geo else None, 8.0 if geo else None, 400.0 if geo else None,
            0.0, 1.0, 3, 0,
        )  # fmt: skip

    live, retired = sbs.tracks(
        [
            victim(1, TrackState.CONFIRMED, True),
            victim(2, TrackState.CONFIRMED, False),  # no lat/lon: cannot be placed
            victim(3, TrackState.TENTATIVE, True),
            victim(4, TrackState.FALSE_ALARM, True),
            victim(5, TrackState.NOT_SEEN_RECENTLY, True),
        ]
    )
    assert [t.callsign for t in live] == ["MED01", "MED05"]
    assert [t.callsign for t in retired] == ["FALSE04"]


def test_explicit_sbs_port_in_use_is_a_clear_error(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "hq.cli", "--listen", "udpin:127.0.0.1:0", "--db",
             str(tmp_path / "hq.sqlite"), "--no-table", "--duration-s", "5",
             "--sbs", f"127.0.0.1:{port}"],
            cwd=REPO, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
    assert done.returncode == 1
    assert f"SBS-1 feed on 127.0.0.1:{port}" in done.stderr
    assert "Traceback" not in done.stderr
