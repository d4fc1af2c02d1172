"""Which telemetry the autopilot sends the companion, and how it was asked.

ATTITUDE, LOCAL_POSITION_NED, GLOBAL_POSITION_INT, GPS_GLOBAL_ORIGIN and
HOME_POSITION are requested with MAV_CMD_SET_MESSAGE_INTERVAL (mavlink_io/vehicle.py
says when: the first heartbeat, and whenever the autopilot may have forgotten them).
Requests are idempotent, so a needless one costs five small commands. If no
COMMAND_ACK accepts it within ``ack_timeout_s`` (twice), or it is refused, the old
REQUEST_DATA_STREAM is used instead, and stays in use for later fresh requests.
While the EKF origin is unknown, a fresh request also asks for it at once.

``StreamRequester`` runs on the vehicle link's reader thread; ``method`` may be
read from any thread.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from types import ModuleType
from typing import TYPE_CHECKING

from mavlink_io.codec import MavMessage
from mavlink_io.telemetry import AUTOPILOT_COMPONENT

if TYPE_CHECKING:
    from mavlink_io.vehicle import VehicleCounters, VehicleSettings

log = logging.getLogger(__name__)

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_RESULT_ACCEPTED = 0
MSG_ATTITUDE = 30
MSG_LOCAL_POSITION_NED = 32
MSG_GLOBAL_POSITION_INT = 33
MSG_GPS_GLOBAL_ORIGIN = 49
MSG_HOME_POSITION = 242
# REQUEST_DATA_STREAM groups (MAV_DATA_STREAM): EXTRA1 carries ATTITUDE, POSITION
# carries LOCAL_POSITION_NED and GLOBAL_POSITION_INT on ArduPilot.
MAV_DATA_STREAM_POSITION = 6
MAV_DATA_STREAM_EXTRA1 = 10


class StreamRequester:
    """See the module docstring."""

    def __init__(
        self,
        settings: VehicleSettings,
        send: Callable[[MavMessage], bool],
        module: ModuleType,
        sysid: Callable[[], int],
        origin_known: Callable[[], bool],
        counters: VehicleCounters,
    ) -> None:
        self._settings = settings
        self._send = send
        self._module = module
        self._sysid = sysid
        self._origin_known = origin_known
        self._counters = counters
        self._lock = threading.Lock()  # guards _method, read by status on other threads
        self._method = ""  # "", "interval" or "data_stream"
        self._sent_s: float | None = None  # an interval request awaiting its COMMAND_ACK
        self._attempts = 0
        self.last_fresh_s = 0.0  # when streams were last requested from scratch

    @property
    def method(self) -> str:
        with self._lock:
            return self._method

    def check_timeout(self, now: float) -> None:
        """Retry or fall back when a request's COMMAND_ACK is overdue."""
        sent = self._sent_s
        if sent is not None and now - sent > self._settings.ack_timeout_s:
            self._on_timeout(now)

    def _rates(self) -> list[tuple[int, float]]:
        s = self._settings
        return [
            (MSG_ATTITUDE, s.attitude_rate_hz),
            (MSG_LOCAL_POSITION_NED, s.local_position_rate_hz),
            (MSG_GLOBAL_POSITION_INT, s.global_position_rate_hz),
            (MSG_GPS_GLOBAL_ORIGIN, s.origin_rate_hz),
            (MSG_HOME_POSITION, s.origin_rate_hz),
        ]

    def request(self, now: float, fresh: bool) -> None:
        """Ask for the streams; ``fresh``: the autopilot may have forgotten them."""
        if fresh:
            self._attempts = 0
            self.last_fresh_s = now
            if not self._origin_known():
                self._request_origin_once()
            with self._lock:
                if self._method == "data_stream":
                    self._send_data_stream_requests()
                    return
                self._method = ""
        confirmation = min(self._attempts, 255)  # 0 first, then 1, 2 on retries
        self._counters.stream_requests += 1  # before sending: a peer may answer at once
        for msg_id, rate_hz in self._rates():
            interval_us = round(1e6 / rate_hz) if rate_hz > 0 else -1  # -1: stop it
            self._command(
                MAV_CMD_SET_MESSAGE_INTERVAL, confirmation, float(msg_id), float(interval_us)
            )
        self._attempts += 1
        self._sent_s = now

    def _request_origin_once(self) -> None:
        """Ask for the EKF origin now: its slow stream (origin_rate_hz) may take seconds.

        Victims confirmed before the origin is known go out without lat/lon and get
        no map marker until it arrives, so the first seconds after connecting matter.
        """
        for msg_id in (MSG_GPS_GLOBAL_ORIGIN, MSG_HOME_POSITION):
            self._command(MAV_CMD_REQUEST_MESSAGE, 0, float(msg_id))

    def _command(self, command: int, confirmation: int, *params: float) -> None:
        """COMMAND_LONG to the autopilot; unused params are 0."""
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self._send(
            self._module.MAVLink_command_long_message(
                self._sysid(), AUTOPILOT_COMPONENT, command, confirmation, *p
            )
        )

    def on_interval_ack(self, msg: MavMessage) -> None:
        if self._sent_s is None and self._method:
            return
        if msg.result == MAV_RESULT_ACCEPTED:
            with self._lock:
                self._method = "interval"
            self._sent_s = None
            return
        log.info("SET_MESSAGE_INTERVAL refused (result %d): REQUEST_DATA_STREAM", msg.result)
        self._fall_back()

    def _on_timeout(self, now: float) -> None:
        if self._attempts < 2:
            self.request(now, fresh=False)
            return
        log.info("no COMMAND_ACK to SET_MESSAGE_INTERVAL: falling back to REQUEST_DATA_STREAM")
        self._fall_back()

    def _fall_back(self) -> None:
        self._sent_s = None
        with self._lock:
            self._method = "data_stream"
            self._send_data_stream_requests()

    def _send_data_stream_requests(self) -> None:
        m = self._module
        s = self._settings
        position_hz = max(s.local_position_rate_hz, s.global_position_rate_hz)
        self._counters.stream_requests += 1
        for stream_id, rate_hz in (
            (MAV_DATA_STREAM_EXTRA1, s.attitude_rate_hz),
            (MAV_DATA_STREAM_POSITION, position_hz),
        ):
            self._send(
                m.MAVLink_request_data_stream_message(
                    self._sysid(), AUTOPILOT_COMPONENT, stream_id, max(1, round(rate_hz)), 1
                )
            )
