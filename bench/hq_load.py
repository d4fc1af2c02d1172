"""rescue-hq under load: ack latency with the console open and closed, memory over time

A real `rescue-hq` process (UDP on 127.0.0.1, SQLite registry with
synchronous=FULL, the console on a loopback port, the SBS-1 feed on) is fed by 50
hq.simrobot robots with 20 victims each (1000 victims), one report per robot
every 0.5 s (100 reports/s; every 5 s each robot also sends its status and a
position). A probe robot sends one report every 0.1 s and times each until its
RESCUE_ACK. The run alternates four rounds: console closed (no page, no request)
and console open (one SSE client reading every state as a browser would, and a
GET /api/state every 2 s). Target: the open console costs the acks less than 2x
at the median. Memory: rescue-hq's resident set (VmRSS) sampled every 5 s over
the whole run; target flat: the first open console adds its page state (the
1000 victims as JSON and as records), after which the rounds' medians stay
within a few percent. The run lasts RESCUE_BENCH_HQ_LOAD_S seconds (default 600, the
10 minutes of the target; a shorter run for a quick look). rescue-hq, the robots
and the clients share the one core the bench is pinned to.
"""

from __future__ import annotations

import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from hq.simrobot import SimRobot

ROOT = Path(__file__).resolve().parents[1]
DURATION_ENV = "RESCUE_BENCH_HQ_LOAD_S"
_ROBOTS = 50
_VICTIMS_PER_ROBOT = 20
_REPORT_PERIOD_S = 0.5  # per robot: 50 robots -> 100 reports/s
_PROBE_PERIOD_S = 0.1
_STATE_PERIOD_S = 2.0
_RSS_PERIOD_S = 5.0
_ROUNDS = ("closed", "open", "closed", "open")
_ORIGIN = "47.397742,8.545594,488"


class _Hq:
    """rescue-hq with its log lines in files (a pipe nobody reads would stall it)."""

    def __init__(self, workdir: Path) -> None:
        self.out_path, self.err_path = workdir / "hq.out", workdir / "hq.err"
        cmd = [
            sys.executable, "-m", "hq.cli",
            "--listen", "udpin:127.0.0.1:0", "--db", str(workdir / "hq.sqlite"),
            "--sbs", "127.0.0.1:0", "--web", "127.0.0.1:0", "--no-table",
            "--origin", _ORIGIN, "--link-timeout-s", "30",
        ]  # fmt: skip
        with self.out_path.open("w") as out, self.err_path.open("w") as err:
            self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=err)
        deadline = time.monotonic() + 30.0
        while True:
            text = self.out_path.read_text()
            udp = re.search(r"listening on udpin:([\d.]+):(\d+)", text)
            web = re.search(r"console on (http://[\d.]+:\d+/)", text)
            if udp and web:
                self.udp, self.url = (udp[1], int(udp[2])), web[1]
                return
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.stop()
                raise RuntimeError(f"rescue-hq did not start: {self.err_path.read_text()[-500:]}")
            time.sleep(0.1)

    def rss_mib(self) -> float:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
        raise RuntimeError("no VmRSS")

    def cpu_s(self) -> float:
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            self.proc.wait(15.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class _Fleet(threading.Thread):
    """50 robots, 20 victims each, one report per robot every 0.5 s (round robin)."""

    def __init__(self, hq_udp: tuple[str, int]) -> None:
        super().__init__(name="bench-fleet", daemon=True)
        self.robots = [SimRobot(1 + i, hq_udp) for i in range(_ROBOTS)]
        self.stop_event = threading.Event()
        self.sent = self.acked = 0

    def run(self) -> None:
        cycle = 0
        while not self.stop_event.is_set():
            t0 = time.monotonic()
            for i, robot in enumerate(self.robots):
                v = 1 + cycle % _VICTIMS_PER_ROBOT
                north, east = i * 30.0 + (v % 5) * 5.0, (v // 5) * 5.0
                robot.send(robot.report_msg(robot.victim(v, north, east)))
                self.sent += 1
                if cycle % 10 == 0:
                    robot.status(confirmed=_VICTIMS_PER_ROBOT)
                    robot.position(north, east + cycle % 7)
            for robot in self.robots:
                for rx in robot.receive(0.0):
                    self.acked += rx.msg.get_type() == "RESCUE_ACK"
            cycle += 1
            self.stop_event.wait(max(0.0, _REPORT_PERIOD_S - (time.monotonic() - t0)))

    def close(self) -> None:
        self.stop_event.set()
        self.join(5.0)
        for robot in self.robots:
            robot.close()


class _Console:
    """An open page: an SSE client reading every state, and /api/state every 2 s."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.stop_event = threading.Event()
        self.states = 0
        self.state_s: list[float] = []
        host, port = url.split("//", 1)[1].rstrip("/").rsplit(":", 1)
        self._sock = socket.create_connection((host, int(port)), timeout=30.0)
        self._sock.sendall(b"GET /api/events HTTP/1.1\r\nHost: hq\r\n\r\n")
        self._threads = [
            threading.Thread(target=self._read, name="bench-sse", daemon=True),
            threading.Thread(target=self._poll, name="bench-state", daemon=True),
        ]
        for t in self._threads:
            t.start()

    def _read(self) -> None:
        with self._sock.makefile("rb") as stream:
            for line in stream:  # ends when close() shuts the socket down
                self.states += line.startswith(b"data: ")

    def _poll(self) -> None:
        while not self.stop_event.wait(_STATE_PERIOD_S):
            t0 = time.perf_counter()
            with urllib.request.urlopen(self.url + "api/state", timeout=30.0) as resp:
                resp.read()
            self.state_s.append(time.perf_counter() - t0)

    def close(self) -> None:
        self.stop_event.set()
        self._sock.shutdown(socket.SHUT_RDWR)
        for t in self._threads:
            t.join(5.0)
        self._sock.close()


def _probe(hq_udp: tuple[str, int], seconds: float, lost: list[int]) -> list[float]:
    """Ack latency (s) of one report at a time from a robot of its own."""
    out = []
    with SimRobot(200, hq_udp) as robot:
        end = time.monotonic() + seconds
        i = 0
        while time.monotonic() < end:
            i += 1
            msg = robot.report_msg(robot.victim(1 + i % 5, 10.0 * (i % 5), 2000.0))
            t0 = time.perf_counter()
            robot.send(msg)
            try:
                robot.wait_for("RESCUE_ACK", 5.0, seq=msg.report_seq)
                out.append(time.perf_counter() - t0)
            except TimeoutError:
                lost[0] += 1
            time.sleep(_PROBE_PERIOD_S)
    return out


def _ms(values: list[float], q: float) -> float | str:
    if not values:
        return "none measured"
    ordered = sorted(values)
    return round(1000 * ordered[min(len(ordered) - 1, int(q * len(ordered)))], 1)


def run() -> dict[str, object]:
    duration_s = float(os.environ.get(DURATION_ENV, "600"))
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    load_before = os.getloadavg()[0]
    victims = _ROBOTS * _VICTIMS_PER_ROBOT
    with tempfile.TemporaryDirectory(prefix="bench-hq-load-") as tmp:
        hq = _Hq(Path(tmp))
        fleet = _Fleet(hq.udp)
        rss: list[tuple[float, float]] = []
        sampling = threading.Event()

        def sample() -> None:
            start = time.monotonic()
            while not sampling.wait(_RSS_PERIOD_S):
                rss.append((time.monotonic() - start, hq.rss_mib()))

        sampler = threading.Thread(target=sample, name="bench-rss", daemon=True)
        latency: dict[str, list[float]] = {"closed": [], "open": []}
        cpu: dict[str, float] = {"closed": 0.0, "open": 0.0}
        lost = [0]
        console = None
        states, requests = 0, []
        try:
            fleet.start()
            time.sleep(victims / (_ROBOTS / _REPORT_PERIOD_S) + 2.0)  # every victim reported
            sampler.start()
            for phase in _ROUNDS:
                console = _Console(hq.url) if phase == "open" else None
                cpu0 = hq.cpu_s()
                latency[phase] += _probe(hq.udp, duration_s / len(_ROUNDS), lost)
                cpu[phase] += hq.cpu_s() - cpu0
                if console is not None:
                    console.close()
                    states, requests = console.states, list(console.state_s)
                    console = None
        finally:
            if console is not None:
                console.close()
            sampling.set()
            fleet.close()
            hq.stop()
        errors = hq.err_path.read_text().count("Traceback")
    phase_s = duration_s / 2
    first = [m for t, m in rss if 60.0 <= t < 120.0] or [m for _, m in rss[:12]]
    last = [m for t, m in rss if t >= rss[-1][0] - 60.0]
    round_s = duration_s / len(_ROUNDS)
    by_round = [
        statistics.median([m for t, m in rss if k * round_s <= t < (k + 1) * round_s] or [0.0])
        for k in range(len(_ROUNDS))
    ]
    closed_med, open_med = _ms(latency["closed"], 0.5), _ms(latency["open"], 0.5)
    return {
        "started": started,
        "load average (1 min) before / after": f"{load_before:.1f} / {os.getloadavg()[0]:.1f}",
        "victims": victims,
        "reports sent by the robots / acknowledged": f"{fleet.sent} / {fleet.acked}",
        "run (s)": round(duration_s),
        "ack latency, console closed: median (ms)": closed_med,
        "ack latency, console closed: p99 (ms)": _ms(latency["closed"], 0.99),
        "ack latency, console open: median (ms)": open_med,
        "ack latency, console open: p99 (ms)": _ms(latency["open"], 0.99),
        "open / closed at the median (target < 2)": (
            round(open_med / closed_med, 2)
            if isinstance(open_med, float) and isinstance(closed_med, float)
            else "none measured"
        ),
        "probe reports without an ack in 5 s": lost[0],
        "rescue-hq CPU, console closed (% of a core)": round(100 * cpu["closed"] / phase_s, 1),
        "rescue-hq CPU, console open (% of a core)": round(100 * cpu["open"] / phase_s, 1),
        "states received by the page in its last round": states,
        "GET /api/state median (ms)": _ms(requests, 0.5),
        "rescue-hq RSS, first full minute, median (MiB)": round(statistics.median(first), 1),
        "rescue-hq RSS, last minute, median (MiB)": round(statistics.median(last), 1),
        "rescue-hq RSS, max (MiB)": round(max(m for _, m in rss), 1),
        f"rescue-hq RSS median per round, {'/'.join(_ROUNDS)} (MiB)": " / ".join(
            f"{m:.1f}" for m in by_round
        ),
        "tracebacks in rescue-hq's log": errors,
    }


if __name__ == "__main__":
    print(run())
