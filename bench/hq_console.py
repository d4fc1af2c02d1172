"""rescue-hq console: page load, report-to-marker latency, memory with 3 robots and 200 victims

A real `rescue-hq` process (UDP on 127.0.0.1, SQLite registry, the console on a
loopback port) is fed by three hq.simrobot robots that drive, stream
LOCAL_POSITION_NED and RESCUE_STATUS, and report 200 victims in all (each report
acknowledged). Headless Chromium (Debian's chromium + chromium-driver, driven by
selenium) opens the console. Page load: navigation start to the first state drawn
(map markers and list), median of 5 loads. Update latency: a robot sends a report
of a new victim; time from the send to that victim's marker being on the page
(same machine, same clock), 20 reports, one at a time. Target: under 1 s.
Memory: the rescue-hq process' resident set (VmRSS, and VmHWM, its peak) with the
200 victims stored and one page open, and with --no-web for comparison. The
bench, rescue-hq and Chromium all run pinned to the same single core (python -m
bench pins itself; children inherit it).
"""

from __future__ import annotations

import queue
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from fusion.types import Urgency
from hq.records import ACK_RESULT_ACCEPTED
from hq.simrobot import SimRobot
from mavlink_io import picture
from mavlink_io.dialect import RESCUE_OPERATOR_ACTION_ID

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = ("chromium", "chromium-browser")
CHROMEDRIVER = "chromedriver"
_URGENCIES = (Urgency.CRITICAL, Urgency.MEDIUM, Urgency.LIGHT)
_VICTIMS = 200
_LATENCY_REPORTS = 20
_LOADS = 5


class BrowserUnavailable(Exception):
    """No Chromium or chromedriver here; the message says what is missing."""


class HqConsoleProcess:
    """A running `rescue-hq` with its console; stdout lines on a queue."""

    def __init__(
        self, workdir: Path, *extra: str, console: bool = True, fd_limit: int | None = None
    ) -> None:
        self.db = workdir / "hq.sqlite"
        web = ["--web", "127.0.0.1:0"] if console else ["--no-web"]
        cmd = [
            sys.executable, "-m", "hq.cli",
            "--listen", "udpin:127.0.0.1:0",
            "--db", str(self.db),
            "--no-table", *web, *extra,
        ]  # fmt: skip
        self.proc = subprocess.Popen(
            cmd,
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=None if fd_limit is None else lambda: _limit_fds(fd_limit),
        )
        self.sbs: tuple[str, int] | None = None  # the SBS-1 feed's address, when it has one
        self.lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        self._pumps = [
            threading.Thread(target=self._pump, daemon=True),
            threading.Thread(target=self._pump_err, daemon=True),
        ]
        for pump in self._pumps:
            pump.start()
        try:
            self.address = ("127.0.0.1", int(self.wait_line("listening on", 20.0).rsplit(":")[-1]))
            self.url = (
                self.wait_line("console on", 20.0).split("console on ", 1)[1].split()[0]
                if console
                else ""
            )
        except TimeoutError:
            self.stop()
            raise

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if "SBS-1 feed" in line:
                host, _, port = line.rsplit(" on ", 1)[1].strip().rpartition(":")
                self.sbs = (host, int(port))
            self.lines.put(line.rstrip("\n"))

    def _pump_err(self) -> None:
        assert self.proc.stderr is not None
        self.stderr.extend(self.proc.stderr)

    def wait_line(self, text: str, timeout_s: float) -> str:
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or (self.proc.poll() is not None and self.lines.empty()):
                raise TimeoutError(
                    f"rescue-hq printed no {text!r} (exit {self.proc.poll()}): "
                    + "".join(self.stderr[-5:])
                )
            try:
                line = self.lines.get(timeout=min(left, 0.2))
            except queue.Empty:
                continue
            if text in line:
                return line

    def rss_kib(self) -> dict[str, int]:
        out = {}
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                out[key] = int(value.split()[0])
        return out

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.terminate()
        try:
            code = self.proc.wait(10.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            code = self.proc.wait(5.0)
        for pump in self._pumps:
            pump.join(5.0)
        for pipe in (self.proc.stdout, self.proc.stderr):
            if pipe is not None:
                pipe.close()
        return code


def _limit_fds(soft: int) -> None:
    """In the child: at most ``soft`` open files, as on a laptop's default 1024."""
    _, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


class Mission:
    """Simulated robots that drive a lawnmower pattern and report victims to an HQ."""

    def __init__(self, hq_address: tuple[str, int], sysids: tuple[int, ...] = (1, 2, 3)) -> None:
        self.robots = {s: SimRobot(s, hq_address) for s in sysids}
        self.t_s = 0.0
        self.silent: set[int] = set()  # robots whose keep-alive stops (a lost link)
        self._lock = threading.Lock()  # one sender at a time per codec
        self._stop = threading.Event()
        self._keepalive: threading.Thread | None = None

    def close(self) -> None:
        self._stop.set()
        if self._keepalive is not None:
            self._keepalive.join(2.0)
        for r in self.robots.values():
            r.close()

    def keep_alive(self, period_s: float) -> None:
        """From now on, every robot not in ``silent`` sends HEARTBEAT and status each period."""

        def loop() -> None:
            while not self._stop.wait(period_s):
                self.status([s for s in self.robots if s not in self.silent])

        self._keepalive = threading.Thread(target=loop, name="mission-keepalive", daemon=True)
        self._keepalive.start()

    def where(self, sysid: int, t_s: float) -> tuple[float, float]:
        """A robot's position at mission time t: lanes 4 m apart, 20 m long, 1 m/s."""
        lane, along = divmod(t_s, 20.0)
        east = (sysid - 2) * 30.0 + 4.0 * lane
        north = along if int(lane) % 2 == 0 else 20.0 - along
        return north, east

    def drive(self, duration_s: float, *, step_s: float = 1.0, sysids: Any = None) -> None:
        """Move the robots (instantly, in steps) and send each one's position and status."""
        end = self.t_s + duration_s
        while self.t_s < end:
            self.t_s += step_s
            for s, r in self.robots.items():
                if sysids is None or s in sysids:
                    with self._lock:
                        r.position(*self.where(s, self.t_s))
        self.status(sysids)

    def status(self, sysids: Any = None) -> None:
        for s, r in self.robots.items():
            if sysids is None or s in sysids:
                with self._lock:
                    r.status(confirmed=3)
                    r.heartbeat()

    def report(
        self,
        sysid: int,
        victim_id: int,
        north_m: float,
        east_m: float,
        urgency: Urgency = Urgency.MEDIUM,
        *,
        wait_ack: bool = True,
        **kw: Any,
    ) -> float:
        """Send one report; the send time (Unix s). Waits for its RESCUE_ACK."""
        robot = self.robots[sysid]
        msg = robot.report_msg(robot.victim(victim_id, north_m, east_m, urgency=urgency, **kw))
        sent = time.time()
        with self._lock:
            robot.send(msg)
        if wait_ack:
            robot.wait_for("RESCUE_ACK", 5.0, seq=msg.report_seq)
        return sent

    def picture(self, sysid: int, victim_id: int, picture_id: int, jpeg: bytes) -> None:
        """Robot ``sysid`` sends an evidence picture in chunks inside TUNNEL, as the
        companion does through its autopilot, and waits until the HQ stored it."""
        robot = self.robots[sysid]
        chunks = picture.split(picture_id, victim_id, jpeg)
        with self._lock:
            for c in chunks[:-1]:
                robot.send(c.to_msg(robot.codec.module), tunnel=True)
            robot.send(chunks[-1].asking().to_msg(robot.codec.module), tunnel=True)
        ack = robot.wait_for("RESCUE_PICTURE_ACK", 5.0, picture_id=picture_id)
        if ack.msg.result != picture.RESULT_STORED or not ack.tunnelled:
            raise RuntimeError(f"picture {picture_id} not stored: {ack.msg}")

    def ack(self, sysid: int, action: Any, *, result: int = ACK_RESULT_ACCEPTED) -> None:
        """Robot ``sysid`` answers an operator action, as the companion does (ACCEPTED,
        or REJECTED when it no longer knows the victim)."""
        robot = self.robots[sysid]
        msg = robot.m.MAVLink_rescue_ack_message(
            action.get_srcSystem(),
            action.get_srcComponent(),
            RESCUE_OPERATOR_ACTION_ID,
            action.action_seq,
            result,
        )
        with self._lock:
            robot.send(msg)

    def populate(self, count: int) -> None:
        """``count`` victims spread over the robots' lanes, urgencies in turn."""
        sysids = sorted(self.robots)
        for i in range(count):
            s = sysids[i % len(sysids)]
            k = i // len(sysids)
            north = 2.0 + (k * 3.7) % 18.0
            east = (s - 2) * 30.0 + (k * 1.3) % 26.0
            self.report(s, 100 + k, north, east, _URGENCIES[i % 3], visibility_pct=10.0 + i % 80)


def chromium(window: tuple[int, int] = (1400, 900)) -> Any:
    """Headless Chromium under selenium, from the system packages only (never downloaded)."""
    browser = next((shutil.which(n) for n in CHROMIUM if shutil.which(n)), None)
    driver = shutil.which(CHROMEDRIVER)
    if browser is None or driver is None:
        raise BrowserUnavailable(
            "chromium and chromium-driver are not installed "
            "(tools/system-packages.sh installs them; `make` runs it)"
        )
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError as exc:
        raise BrowserUnavailable(f"selenium is not installed: {exc}") from None
    options = webdriver.ChromeOptions()
    options.binary_location = browser
    for arg in (
        "--headless=new",
        "--no-sandbox",  # root in a container has no user namespace for the sandbox
        "--disable-dev-shm-usage",
        "--disable-gpu",
        f"--window-size={window[0]},{window[1]}",
        "--no-first-run",
        "--disable-extensions",
    ):
        options.add_argument(arg)
    return webdriver.Chrome(service=Service(executable_path=driver), options=options)


@contextmanager
def console_mission(*extra: str) -> Iterator[tuple[HqConsoleProcess, Mission]]:
    with tempfile.TemporaryDirectory(prefix="hq-console-") as tmp:
        hq = HqConsoleProcess(Path(tmp), *extra)
        mission = Mission(hq.address)
        try:
            yield hq, mission
        finally:
            mission.close()
            hq.stop()


def wait_js(driver: Any, script: str, timeout_s: float, what: str) -> Any:
    """Poll a JavaScript expression until it is truthy; its value. TimeoutError naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = driver.execute_script(script)
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"the page did not show {what} within {timeout_s} s")
        time.sleep(0.02)


SEEN_JS = """
window.hqSeen = window.hqSeen || {};
window.addEventListener('hq-state', (ev) => {
  for (const v of ev.detail.victims) {
    if (!document.querySelector(`[data-victim="${v.id}"]`)) continue;
    for (const s of v.sources) {
      const key = `${s.robot}:${s.victim_id}`;
      if (!(key in window.hqSeen)) window.hqSeen[key] = Date.now();
    }
  }
});
return true;
"""


def _memory_without_console() -> float:
    """rescue-hq's VmRSS (MiB) with the same 200 victims and --no-web, for comparison."""
    with tempfile.TemporaryDirectory(prefix="hq-console-") as tmp:
        hq = HqConsoleProcess(Path(tmp), console=False)
        mission = Mission(hq.address)
        try:
            mission.drive(30.0)
            mission.populate(_VICTIMS)
            return round(hq.rss_kib()["VmRSS"] / 1024, 1)
        finally:
            mission.close()
            hq.stop()


def run() -> dict[str, object]:
    without = _memory_without_console()
    driver = chromium()
    try:
        with console_mission() as (hq, mission):
            mission.drive(30.0)
            mission.populate(_VICTIMS)
            loads = []
            for _ in range(_LOADS):
                driver.get(hq.url)
                loads.append(
                    wait_js(
                        driver,
                        "return window.hqFirstRenderMs && document.querySelectorAll("
                        "'[data-victim]').length >= 200 && window.hqFirstRenderMs",
                        30.0,
                        "200 victims",
                    )
                )
            driver.execute_script(SEEN_JS)
            latencies = []
            for i in range(_LATENCY_REPORTS):
                victim_id = 900 + i
                sent = mission.report(
                    1 + i % 3, victim_id, 25.0, 5.0 * i - 40.0, Urgency.CRITICAL, wait_ack=False
                )
                key = f"{1 + i % 3}:{victim_id}"
                seen_ms = wait_js(driver, f"return window.hqSeen['{key}']", 10.0, key)
                latencies.append(seen_ms / 1000.0 - sent)
                mission.drive(1.0)
            mem = hq.rss_kib()
    finally:
        driver.quit()
    latencies.sort()
    return {
        "page load, first state drawn, 200 victims, median (ms)": round(statistics.median(loads)),
        "report to marker on the page, median (ms)": round(1000 * statistics.median(latencies)),
        "report to marker on the page, max of 20 (ms)": round(1000 * latencies[-1]),
        "rescue-hq resident memory, 3 robots 200 victims, page open (MiB)": round(
            mem["VmRSS"] / 1024, 1
        ),
        "rescue-hq peak resident memory (MiB)": round(mem["VmHWM"] / 1024, 1),
        "rescue-hq resident memory, same, --no-web (MiB)": without,
    }
