"""The simulated rover: a Trajectory, an Autopilot, and real transports, in real time.

    rover = SimRover(world, ["udpin:127.0.0.1:0", "udpin:127.0.0.1:0"], seed=1)
    rover.start()
    port = rover.local_address(0)[1]      # the companion connects here (udpout)
    ...
    rover.reboot(); rover.drop_link(3.0); rover.close()
    rover.operator_sets_mode(0); rover.block(4.0, 2.0, 0.5)   # tests of closer looks

Each link is a mavlink_io link (udpin, udpout, tcp, tcpin, serial) or "pty": a
pseudo-terminal pair whose slave path (``rover.pty_path(i)``) a serial client opens.
One reader thread per link puts received bytes on a queue; one loop thread waits on
that queue until the next packet is due, feeds the Autopilot and writes what it
returns. ``time_scale`` > 1 runs the simulation faster than real time.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pty
import queue
import select
import threading
import tty
from collections.abc import Callable, Sequence

from mavlink_io.errors import LinkError
from mavlink_io.link import Link
from mavlink_io.linkspec import LinkSpec, parse_link
from mavlink_io.reconnect import open_link
from scenarios.autopilot import Autopilot
from scenarios.motion import SimClock, Trajectory, TruePose, route_of
from scenarios.world import PointNE, World

log = logging.getLogger(__name__)

_READ_TIMEOUT_S = 0.2  # reader threads look at the stop flag this often
_MAX_WAIT_S = 0.5


class PtyLink:
    """The master side of a pseudo-terminal: the rover's end of a serial cable."""

    def __init__(self) -> None:
        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self.name = f"pty:{self.path}"
        os.set_blocking(self._master, False)
        self._closed = False

    def read(self, timeout_s: float) -> bytes:
        if self._closed:
            raise LinkError(f"{self.name}: closed")
        ready, _, _ = select.select([self._master], [], [], timeout_s)
        if not ready:
            return b""
        try:
            return os.read(self._master, 65536)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise LinkError(f"{self.name}: {exc}") from exc

    def write(self, data: bytes) -> None:
        try:
            os.write(self._master, data)
        except BlockingIOError:
            log.debug("%s: no reader, %d bytes dropped", self.name, len(data))
        except OSError as exc:
            raise LinkError(f"{self.name}: {exc}") from exc

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for fd in (self._master, self._slave):
                with contextlib.suppress(OSError):
                    os.close(fd)


def _open(link: str | LinkSpec | Link) -> Link:
    if isinstance(link, str) and link == "pty":
        return PtyLink()
    if isinstance(link, str):
        return open_link(parse_link(link))
    if isinstance(link, LinkSpec):
        return open_link(link)
    return link


class SimRover:
    """A rover driving its route and speaking MAVLink on its links (see module doc)."""

    def __init__(
        self,
        world: World,
        links: Sequence[str | LinkSpec | Link],
        *,
        route: tuple[PointNE, ...] | None = None,
        speed_m_s: float = 0.4,
        seed: int | None = None,
        time_scale: float = 1.0,
        sysid: int = 1,
        origin_at_boot: bool = True,
        rates_hz: dict[int, float] | None = None,
    ) -> None:
        self.world = world
        seed = world.seed if seed is None else seed
        self.trajectory = Trajectory(
            world.start_ne_m,
            world.start_heading_rad,
            route if route is not None else route_of(world),
            speed_m_s=speed_m_s,
            seed=seed,
        )
        self.clock = SimClock(time_scale)
        self.autopilot = Autopilot(
            self.trajectory,
            world.origin,
            n_links=len(links),
            sysid=sysid,
            seed=seed,
            unix_of=self.clock.unix_s,
            origin_at_boot=origin_at_boot,
            rates_hz=rates_hz,
        )
        self._links: list[Link] = []
        try:
            for spec in links:
                self._links.append(_open(spec))
        except Exception:
            self.close()
            raise
        self._inbox: queue.Queue[tuple[int, bytes] | Callable[[float], None]] = queue.Queue()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []

    # -- public --------------------------------------------------------------------

    def start(self) -> SimRover:
        for i, link in enumerate(self._links):
            t = threading.Thread(
                target=self._reader, args=(i, link), name=f"rover-rx{i}", daemon=True
            )
            t.start()
            self._threads.append(t)
        t = threading.Thread(target=self._loop, name="rover-loop", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def __enter__(self) -> SimRover:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the threads and close the links; safe to call twice."""
        self._stop.set()
        self._inbox.put(lambda _t: None)  # wake the loop
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()
        for link in self._links:
            with contextlib.suppress(Exception):
                link.close()

    def link(self, i: int) -> Link:
        return self._links[i]

    def local_address(self, i: int) -> tuple[str, int]:
        """The (host, port) a udpin/tcpin link is bound to (port 0 resolved)."""
        addr = getattr(self._links[i], "local_address", None)
        if addr is None:
            raise ValueError(f"link {i} ({self._links[i].name}) has no local address")
        value = addr() if callable(addr) else addr
        return (str(value[0]), int(value[1]))

    def pty_path(self, i: int) -> str:
        link = self._links[i]
        if not isinstance(link, PtyLink):
            raise ValueError(f"link {i} ({link.name}) is not a pty")
        return link.path

    def now_s(self) -> float:
        return self.clock.now_s()

    def true_pose(self, t_s: float | None = None) -> TruePose:
        with self._lock:
            return self.autopilot.drive.pose_at(self.now_s() if t_s is None else t_s)

    def camera_pose(self) -> tuple[TruePose, float]:
        """The true pose now and now on the wall clock (Unix s): a CameraServer's pose_now."""
        t = self.now_s()
        return self.true_pose(t), self.clock.unix_s(t)

    def reboot(self) -> None:
        """Reboot the autopilot now: silent for a while, then boot time restarts at 0."""
        self._inbox.put(lambda t: self.autopilot.reboot(t))

    def drop_link(self, duration_s: float, link: int | None = None) -> None:
        """Drop one link (or all) for duration_s of simulation time."""
        self._inbox.put(lambda t: self.autopilot.drop_link(t, duration_s, link))

    def operator_sets_mode(self, mode: int) -> None:
        """The operator flips the RC mode switch (0 MANUAL, 4 HOLD, 10 AUTO, 15 GUIDED)."""
        self._inbox.put(lambda t: self.autopilot.set_mode(mode, t))

    def block(self, north_m: float, east_m: float, radius_m: float) -> None:
        """An obstacle the rover cannot drive into after its next command (it gets stuck)."""
        self._inbox.put(lambda _t: self.autopilot.block(north_m, east_m, radius_m))

    def mode(self) -> int:
        """The autopilot's mode now (HEARTBEAT's custom_mode)."""
        with self._lock:
            return self.autopilot.drive.mode

    def mission_seq(self) -> int:
        """The mission item the autopilot is at now (MISSION_CURRENT's seq)."""
        with self._lock:
            return self.autopilot.drive.mission_seq(self.now_s())

    # -- threads -------------------------------------------------------------------

    def _reader(self, i: int, link: Link) -> None:
        while not self._stop.is_set():
            try:
                data = link.read(_READ_TIMEOUT_S)
            except LinkError as exc:
                if not self._stop.is_set():
                    log.warning("rover link %d (%s) failed: %s", i, link.name, exc)
                return
            if data:
                self._inbox.put((i, data))

    def _send(self, out: list[tuple[int, bytes]]) -> None:
        for i, packet in out:
            try:
                self._links[i].write(packet)
            except LinkError as exc:
                log.debug("rover link %d: write failed: %s", i, exc)

    def _loop(self) -> None:
        while not self._stop.is_set():
            now = self.now_s()
            with self._lock:
                self._send(self.autopilot.poll(now))
                due = self.autopilot.next_due_s()
            wait = min(_MAX_WAIT_S, max(0.0, self.clock.wall_delay_s(due - self.now_s())))
            try:
                item = self._inbox.get(timeout=wait)
            except queue.Empty:
                continue
            now = self.now_s()
            with self._lock:
                if callable(item):
                    item(now)
                else:
                    self._send(self.autopilot.handle(item[0], item[1], now))
