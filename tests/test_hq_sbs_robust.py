"""The SBS-1 feed over a long night: many open connections, a failure, a big mission.

The real ``SbsServer`` on 127.0.0.1 with real client sockets. What an operator
relies on: QGC gets the victims however many file descriptors the HQ holds; the
feed's thread failing neither ends the feed nor stalls the HQ's main thread, which
publishes every change (it sends the acknowledgements); and hundreds of tracks
reach a client on a 1500-byte MTU link instead of it being dropped and reconnecting
over and over: as root, that one runs the real `rescue-hq` in a network namespace of
its own whose loopback has that MTU (this file run as a script is that child).
"""

from __future__ import annotations

import json
import logging
import os
import resource
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from fusion.types import TrackState, Urgency
from hq import sbs
from hq.simrobot import SimRobot
from hq.view import HqVictim

REPO = Path(__file__).resolve().parents[1]

_PUBLISH_LIMIT_S = 5.0  # 1000 publishes take milliseconds; a blocked one never returns


def _victim(hq_id: int, lat_deg: float = 47.0) -> HqVictim:
    return HqVictim(
        hq_id, ((1, hq_id),), Urgency.MEDIUM, 30.0, TrackState.CONFIRMED, 1.0, 1.0, 0.0,
        ((0.25, 0.0), (0.0, 0.25)), 0.5, lat_deg, 8.0, 488.0, 0.0, 1.0, 3, 0,
    )  # fmt: skip


class FeedReader:
    """Reads an SBS-1 feed; keeps the last MSG,3 latitude of each address."""

    def __init__(self, to: tuple[str, int] | socket.socket) -> None:
        """``to``: the feed's address, or a socket already connected to it."""
        self.sock = to if isinstance(to, socket.socket) else socket.create_connection(to)
        self.sock.settimeout(0.1)
        self.lat_deg: dict[str, float] = {}
        self.closed_by_server = False
        self._buffer = b""

    def read_for(self, seconds: float, until: object = None) -> None:
        """Read for ``seconds`` or until ``until()`` is true, or the server closes."""
        end = time.monotonic() + seconds
        while time.monotonic() < end and not self.closed_by_server:
            if callable(until) and until():
                return
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except ConnectionResetError:
                data = b""
            if not data:
                self.closed_by_server = True
                return
            *whole, self._buffer = (self._buffer + data).split(b"\r\n")
            for line in whole:
                fields = line.decode("ascii").split(",")
                if fields[:2] == ["MSG", "3"]:
                    self.lat_deg[fields[4]] = float(fields[14])

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def server() -> Iterator[sbs.SbsServer]:
    with sbs.SbsServer("127.0.0.1", 0, refresh_s=0.2) as feed:
        yield feed


@pytest.fixture
def many_descriptors() -> Iterator[list[socket.socket]]:
    """1100 open sockets, as rescue-hq holds with ~1100 console connections open."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = 1400
    if hard != resource.RLIM_INFINITY and hard < need:
        pytest.skip(f"the hard limit on open files is {hard}, below {need}")
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, need), hard))
    held = [socket.socket() for _ in range(1100)]
    try:
        yield held
    finally:
        for s in held:
            s.close()
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


def _publish_moves(feed: sbs.SbsServer, count: int) -> threading.Thread:
    """The HQ's main thread: one victim moved ``count`` times, each a change published."""

    def main_thread() -> None:
        for i in range(count):
            feed.publish([_victim(1, 47.0 + (i + 1) * 1e-6)])

    t = threading.Thread(target=main_thread, daemon=True)
    t.start()
    t.join(_PUBLISH_LIMIT_S)
    return t


def test_a_client_above_descriptor_1023_gets_the_feed(
    server: sbs.SbsServer, many_descriptors: list[socket.socket]
) -> None:
    client = FeedReader(server.address)  # the server's end of it is above 1023 too
    try:
        assert client.sock.fileno() >= 1024
        publisher = _publish_moves(server, 1000)
        assert not publisher.is_alive(), "publish() blocked the HQ's main thread"
        last = 47.0 + 1000 * 1e-6
        client.read_for(10.0, lambda: client.lat_deg.get("F00001") == pytest.approx(last, abs=1e-7))
        assert not client.closed_by_server
        assert client.lat_deg["F00001"] == pytest.approx(last, abs=1e-7)
    finally:
        client.close()


class ThreadCpu:
    """CPU time (user + system) of one thread of this process, from /proc; the file is
    opened once, so it can be read when no descriptor is left."""

    def __init__(self, thread: threading.Thread) -> None:
        self._fd = os.open(f"/proc/self/task/{thread.native_id}/stat", os.O_RDONLY)

    def seconds(self) -> float:
        fields = os.pread(self._fd, 4096, 0).decode().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def close(self) -> None:
        os.close(self._fd)


def test_no_descriptor_left_is_said_once_without_spinning_and_the_client_served_after(
    server: sbs.SbsServer, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="hq.sbs")
    server.publish([_victim(1)])
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    client = socket.socket(socket.AF_INET, socket.SOCK_STREAM)  # its descriptor, before none left
    cpu = ThreadCpu(server._thread)
    fillers: list[socket.socket] = []
    resource.setrlimit(resource.RLIMIT_NOFILE, (len(os.listdir("/proc/self/fd")) + 16, hard))
    try:
        try:
            while True:
                fillers.append(socket.socket())
        except OSError:
            pass  # no descriptor left in this process, the feed's included
        client.connect(server.address)  # queued by the kernel; accept() fails: EMFILE
        cpu_before = cpu.seconds()
        time.sleep(2.0)
        spent_s = cpu.seconds() - cpu_before
    finally:
        for s in fillers:
            s.close()
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))
    try:
        assert spent_s < 0.2, f"the feed's thread used {spent_s:.2f} s of CPU in 2 s"
        reader = FeedReader.__new__(FeedReader)  # the client connected above
        reader.sock, reader.lat_deg, reader.closed_by_server, reader._buffer = (
            client,
            {},
            False,
            b"",
        )
        client.settimeout(0.1)
        reader.read_for(3.0, lambda: "F00001" in reader.lat_deg)
        assert "F00001" in reader.lat_deg
    finally:
        client.close()
    said = [r.getMessage() for r in caplog.records if "cannot accept" in r.getMessage()]
    assert len(said) == 1 and "Too many open files" in said[0]
    assert "accepts clients again" in caplog.text


def test_a_failure_of_the_feed_thread_is_said_once_and_the_feed_goes_on(
    server: sbs.SbsServer, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    real_lines = sbs.lines
    failures = []

    def fails_once(track: sbs.SbsTrack, now_unix_s: float) -> bytes:
        if not failures:
            failures.append(track)
            raise RuntimeError("injected failure")
        return real_lines(track, now_unix_s)

    caplog.set_level(logging.INFO, logger="hq.sbs")
    client = FeedReader(server.address)
    try:
        server.publish([_victim(1)])
        client.read_for(3.0, lambda: "F00001" in client.lat_deg)
        monkeypatch.setattr(sbs, "lines", fails_once)
        server.publish([_victim(1, 47.5)])
        client.read_for(3.0)  # the thread fails and closes its clients
        assert client.closed_by_server
        publisher = _publish_moves(server, 1000)  # while it is down and after
        assert not publisher.is_alive(), "publish() blocked the HQ's main thread"
    finally:
        client.close()
    time.sleep(1.5)  # the thread serves again after a second
    again = FeedReader(server.address)
    try:
        last = 47.0 + 1000 * 1e-6
        again.read_for(3.0, lambda: "F00001" in again.lat_deg)
        assert again.lat_deg["F00001"] == pytest.approx(last, abs=1e-7)
    finally:
        again.close()
    assert server.failure is not None and "injected failure" in server.failure
    said = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(said) == 1 and said[0].exc_info is not None


def test_a_snapshot_bigger_than_the_socket_buffer_reaches_a_late_client() -> None:
    """A QGC that connects late gets every track, however many.

    The snapshot once had to fit the socket's send buffer in one call, or the client
    was dropped (and reconnected, and was dropped...). On a 1500-byte MTU link that
    buffer takes ~60 kB in one call, ~400 tracks (../shared/repro/sbs_net.py); on
    loopback it takes up to tcp_wmem's maximum (4 MiB here), so the test uses a
    mission whose snapshot is larger than that: 25,000 tracks, ~5 MB.
    """
    count = 25_000
    with sbs.SbsServer("127.0.0.1", 0, refresh_s=2.0) as feed:
        feed.publish([_victim(i, 47.0 + i * 1e-7) for i in range(1, count + 1)])
        client = FeedReader(feed.address)
        try:
            client.read_for(10.0, lambda: len(client.lat_deg) == count)
            assert not client.closed_by_server
            assert len(client.lat_deg) == count
            client.read_for(2.5)  # a whole refresh of every track follows
            assert not client.closed_by_server
        finally:
            client.close()


def test_a_client_that_does_not_read_is_dropped_and_said(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.INFO, logger="hq.sbs")
    bound = 256 * 1024
    with sbs.SbsServer("127.0.0.1", 0, refresh_s=0.05, max_client_buffer_bytes=bound) as feed:
        feed.publish([_victim(i, 47.0 + i * 1e-5) for i in range(1, 401)])
        stalled = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.connect(feed.address)  # and never reads
        reader = FeedReader(feed.address)
        try:
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and "not reading" not in caplog.text:
                reader.read_for(0.2)
            assert feed.client_count == 1
            reader.read_for(1.0)
            assert not reader.closed_by_server  # the one that reads keeps its feed
        finally:
            reader.close()
            stalled.close()
    dropped = [r.getMessage() for r in caplog.records if "not reading" in r.getMessage()]
    assert len(dropped) == 1 and f"more than {bound}" in dropped[0]


_MTU_VICTIMS = 400  # the review's QGC was dropped over and over from about here


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("unshare") is None or shutil.which("ip") is None,
    reason="needs root, unshare and ip for a network namespace with a 1500-byte MTU",
)
def test_four_hundred_victims_reach_qgc_over_a_1500_byte_mtu_link() -> None:
    done = subprocess.run(
        ["unshare", "-n", sys.executable, __file__],
        cwd=REPO, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["closed_by_server"] is False, result
    assert result["tracks"] == _MTU_VICTIMS, result
    assert "Traceback" not in result["hq_stderr"]


def _mtu_child() -> None:
    """In a fresh network namespace: loopback up at MTU 1500, the real rescue-hq with
    400 confirmed victims from a simulated robot, then a QGC-like client that reads
    the feed for 5 s. Prints the outcome as one JSON line."""
    subprocess.run(["ip", "link", "set", "lo", "up", "mtu", "1500"], check=True)
    with tempfile.TemporaryDirectory() as tmp:
        err_path = Path(tmp) / "hq.err"
        with open(err_path, "w") as err:
            proc = subprocess.Popen(
                [sys.executable, "-m", "hq.cli", "--listen", "udpin:127.0.0.1:0",
                 "--db", str(Path(tmp) / "hq.sqlite"), "--no-table", "--no-web",
                 "--duration-s", "60", "--sbs", "127.0.0.1:0",
                 "--origin", "47.397742,8.545594,488.0"],
                cwd=REPO, stdout=subprocess.PIPE, stderr=err, text=True,
            )  # fmt: skip
        try:
            assert proc.stdout is not None
            ports = {}
            while len(ports) < 2:
                line = proc.stdout.readline()
                for key in ("listening on", "SBS-1 feed"):
                    if key in line:
                        ports[key] = int(line.rsplit(":", 1)[1])
            robot_to_hq = ("127.0.0.1", ports["listening on"])
            with SimRobot(7, robot_to_hq) as robot:
                for first in range(1, _MTU_VICTIMS + 1, 50):
                    waiting = set()
                    for v in range(first, first + 50):
                        msg = robot.report_msg(robot.victim(v, (v // 30) * 4.0, (v % 30) * 4.0))
                        robot.send(msg)
                        waiting.add(msg.report_seq)
                    deadline = time.monotonic() + 10.0
                    while waiting and time.monotonic() < deadline:
                        for rx in robot.receive(0.5):
                            if rx.msg.get_type() == "RESCUE_ACK":
                                waiting.discard(rx.msg.seq)
                    assert not waiting, f"reports not acknowledged: {sorted(waiting)}"
            time.sleep(1.5)  # the victims published to the feed
            client = FeedReader(("127.0.0.1", ports["SBS-1 feed"]))
            try:
                client.read_for(5.0)
            finally:
                client.close()
        finally:
            proc.terminate()
            proc.wait(timeout=15)
        print(
            json.dumps(
                {
                    "tracks": len(client.lat_deg),
                    "closed_by_server": client.closed_by_server,
                    "hq_stderr": err_path.read_text()[-2000:],
                }
            )
        )


if __name__ == "__main__":
    _mtu_child()
