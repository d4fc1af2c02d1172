"""A minimal simulated ground station for tests and benchmarks.

It speaks to the rover's ground port like QGC plus rescue-hq would at their
simplest: a 1 Hz GCS HEARTBEAT (so the rover, like ArduPilot, routes to it),
everything that arrives recorded with its arrival time (TUNNEL unwrapped), and
RESCUE_VICTIM_REPORTs acknowledged while ``acking`` is set.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from mavlink_io import tunnel
from mavlink_io.codec import Codec
from mavlink_io.dialect import RESCUE_VICTIM_REPORT_ID
from mavlink_io.linkspec import parse_link
from mavlink_io.reconnect import open_link

MAV_TYPE_GCS = 6
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4


class GroundPeer:
    """The ground station (see the module docstring). ``close()`` stops it."""

    def __init__(self, url: str, sysid: int = 245) -> None:
        self.link = open_link(parse_link(url))
        self.codec = Codec(sysid, 190)
        self.m = self.codec.module
        self.acking = threading.Event()
        self.messages: list[tuple[float, Any]] = []  # (arrival, time.monotonic())
        self._cond = threading.Condition(threading.RLock())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                next_hb = now + 1.0
                self.link.write(
                    self.codec.encode(
                        self.m.MAVLink_heartbeat_message(
                            MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE, 3
                        )
                    )
                )
            data = self.link.read(0.1)
            for msg in self.codec.feed(data) if data else ():
                if tunnel.is_ours(msg):
                    inner = tunnel.unpack_tunnel(msg, self.codec)
                    if inner is None:
                        continue
                    msg = inner
                if msg.get_type() == "RESCUE_VICTIM_REPORT" and self.acking.is_set():
                    ack = self.m.MAVLink_rescue_ack_message(
                        msg.get_srcSystem(),
                        msg.get_srcComponent(),
                        RESCUE_VICTIM_REPORT_ID,
                        msg.report_seq,
                        0,
                    )
                    self.link.write(
                        self.codec.encode(tunnel.wrap(self.codec, ack, msg.get_srcSystem()))
                    )
                with self._cond:
                    self.messages.append((time.monotonic(), msg))
                    self._cond.notify_all()

    def received(self) -> list[tuple[float, Any]]:
        """Everything received so far: (arrival on time.monotonic(), message)."""
        with self._cond:
            return list(self.messages)

    def of_type(self, name: str, since_s: float = 0.0) -> list[Any]:
        with self._cond:  # re-entrant use from wait_until's condition is fine: RLock
            return [m for t, m in self.messages if m.get_type() == name and t >= since_s]

    def wait_for(self, pred: Callable[[Any], bool], timeout_s: float, since_s: float = 0.0) -> Any:
        end = time.monotonic() + timeout_s
        with self._cond:
            while True:
                for t, m in self.messages:
                    if t >= since_s and pred(m):
                        return m
                remaining = end - time.monotonic()
                if remaining <= 0:
                    types = sorted({m.get_type() for _, m in self.messages})
                    raise AssertionError(f"no matching message within {timeout_s} s; got {types}")
                self._cond.wait(remaining)

    def wait_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Wait, re-checking as messages arrive, until ``condition()`` holds."""
        with self._cond:
            return self._cond.wait_for(condition, timeout_s)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.link.close()
