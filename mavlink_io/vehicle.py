"""The companion's side of the vehicle link: identity, streams, pose, health.

``VehicleLink`` owns a Link and one reader thread. The thread reads and decodes the
link, and on the same loop (every ``_TICK_S`` at most) sends our HEARTBEAT, checks
the autopilot's heartbeat and retries stream requests, so a stalled transport can
delay but never stop it.

Identity: the vehicle's system ID is learned from the autopilot's HEARTBEAT
(component 1, a MAV_TYPE that is neither a GCS nor an onboard controller, an
autopilot other than MAV_AUTOPILOT_INVALID), unless ``system_id`` is configured. We
send as (vehicle sysid, ``component_id``), and our HEARTBEAT at 1 Hz says
MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID and the health callback's
MAV_STATE. Before the sysid is known only that HEARTBEAT goes out, as the configured
system ID or 1: a UDP or TCP peer that answers only who spoke first (an autopilot's
udpin, mavlink-router's UDP server) must hear us to start sending.

Streams (mavlink_io/streams.py asks for them): requested on the first heartbeat,
and again whenever the autopilot may have forgotten them (ArduPilot does at every
reboot): after a link loss, on the first heartbeat after a silence of
``_HEARTBEAT_GAP_S`` (a reboot shorter than the link-loss timeout), after a
confirmed new boot time, when the transport reopened (a TCP reconnect), and when
the heartbeat is heard but no ATTITUDE or LOCAL_POSITION_NED came for
``_stale_s`` (at most once per ``_stale_s``).

Messages for us: RESCUE_ACK, RESCUE_PICTURE_ACK and RESCUE_OPERATOR_ACTION addressed to our
(sysid, component) or broadcast, directly or inside our TUNNEL, and a ground
station's PARAM_REQUEST_LIST/READ, PARAM_SET and COMMAND_LONG addressed to our
component or to all, go to ``on_dialect`` (called on the reader thread) or,
without one, to the ``inbox`` queue.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from fusion.pose import PoseHistory
from fusion.types import GlobalOrigin, PoseSample
from mavlink_io import tunnel
from mavlink_io.codec import Codec, MavMessage
from mavlink_io.dialect import RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID, RESCUE_PICTURE_ACK_ID
from mavlink_io.errors import LinkError, LinkTimeout
from mavlink_io.link import Link
from mavlink_io.streams import (
    MAV_CMD_SET_MESSAGE_INTERVAL,
    MSG_ATTITUDE,
    MSG_GLOBAL_POSITION_INT,
    MSG_GPS_GLOBAL_ORIGIN,
    MSG_HOME_POSITION,
    MSG_LOCAL_POSITION_NED,
    StreamRequester,
)
from mavlink_io.telemetry import AUTOPILOT_COMPONENT, TelemetryDecoder, is_autopilot_heartbeat
from mavlink_io.tlog import TlogWriter

log = logging.getLogger(__name__)

MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4
_TELEMETRY_IDS = frozenset(
    {
        MSG_ATTITUDE,
        MSG_LOCAL_POSITION_NED,
        MSG_GLOBAL_POSITION_INT,
        MSG_GPS_GLOBAL_ORIGIN,
        MSG_HOME_POSITION,
    }
)

MAX_STREAM_RATE_HZ = 200.0  # no autopilot streams faster; REQUEST_DATA_STREAM's rate is uint16
_TICK_S = 0.05  # the reader loop's longest wait: bounds heartbeat and timeout jitter
_HEARTBEAT_GAP_S = 1.5  # autopilots beat at 1 Hz: a longer silence may be a reboot
_MIN_STALE_S = 1.0  # no telemetry for this long (or 3 periods) while connected: re-request
_DIALECT_IDS = frozenset({RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID, RESCUE_PICTURE_ACK_ID})
# PARAM_REQUEST_READ, PARAM_REQUEST_LIST, PARAM_SET, COMMAND_LONG: a ground station
# asking the companion's component for its parameters (mavlink_io/params.py) or its
# camera and video stream (mavlink_io/camera.py) also goes to on_dialect.
_GROUND_REQUEST_IDS = frozenset({20, 21, 23, 76})
_INBOX_MAX = 1000


@dataclass(frozen=True)
class VehicleSettings:
    """What VehicleLink needs from the [vehicle] config section (same field names)."""

    system_id: int = 0  # 0: learn from the autopilot's HEARTBEAT
    component_id: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    heartbeat_timeout_s: float = 3.0
    heartbeat_period_s: float = 1.0
    attitude_rate_hz: float = 20.0
    local_position_rate_hz: float = 20.0
    global_position_rate_hz: float = 5.0
    origin_rate_hz: float = 0.2  # GPS_GLOBAL_ORIGIN and HOME_POSITION
    ack_timeout_s: float = 1.0
    pose_history_s: float = 30.0

    def __post_init__(self) -> None:
        if not 0 <= self.system_id <= 255 or not 1 <= self.component_id <= 255:
            raise ValueError("system_id must be 0..255 and component_id 1..255")
        for name in ("heartbeat_timeout_s", "heartbeat_period_s", "ack_timeout_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} = {value!r}: must be a positive number")
        for name in (
            "attitude_rate_hz",
            "local_position_rate_hz",
            "global_position_rate_hz",
            "origin_rate_hz",
        ):
            value = getattr(self, name)
            if not 0 <= value <= MAX_STREAM_RATE_HZ:  # also refuses NaN
                raise ValueError(
                    f"{name} = {value!r}: must be in [0, {MAX_STREAM_RATE_HZ:g}] (0: stop it)"
                )


@dataclass
class VehicleCounters:
    messages_in: int = 0
    messages_out: int = 0
    sends_dropped: int = 0  # before the sysid is known, or the link refused
    poses: int = 0
    stream_requests: int = 0
    link_losses: int = 0
    reboots: int = 0
    inbox_dropped: int = 0
    handler_errors: int = 0
    read_errors: int = 0
    loop_errors: int = 0  # a bug in the loop itself, caught so the thread keeps going


@dataclass(frozen=True)
class VehicleState:
    """A consistent snapshot for status reports."""

    connected: bool
    sysid: int
    origin: GlobalOrigin | None
    clock_synced: bool
    clock_offset_s: float | None
    stream_method: str  # "", "interval" or "data_stream"
    last_pose: PoseSample | None
    counters: dict[str, int] = field(default_factory=dict)


class VehicleLink:
    """Talks to the autopilot over one Link from one reader thread."""

    def __init__(
        self,
        link: Link,
        settings: VehicleSettings | None = None,
        *,
        codec: Codec | None = None,
        pose_history: PoseHistory | None = None,
        health: Callable[[], int] = lambda: MAV_STATE_ACTIVE,
        tlog: TlogWriter | None = None,
        on_dialect: Callable[[MavMessage], None] | None = None,
        on_message: Callable[[MavMessage], None] | None = None,
    ) -> None:
        self.settings = settings or VehicleSettings()
        s = self.settings
        self.link = link
        self.codec = codec or Codec(s.system_id or 1, s.component_id)
        self.poses = pose_history or PoseHistory(s.pose_history_s)
        self.telemetry = TelemetryDecoder()
        self.clock = self.telemetry.clock
        self.origins = self.telemetry.origins
        self.inbox: queue.Queue[MavMessage] = queue.Queue(_INBOX_MAX)
        self.counters = VehicleCounters()
        self._health = health
        self._tlog = tlog
        self._on_dialect = on_dialect
        self._on_message = on_message
        self._listeners: tuple[Callable[[MavMessage, float], None], ...] = ()
        self._sysid = s.system_id
        # Other components this companion speaks for (its camera): requests addressed
        # to them also go to on_dialect; their replies go out through send_encoded.
        self.other_components: frozenset[int] = frozenset()
        self._connected = threading.Event()
        self._changed = threading.Condition()  # notified after every reader-loop pass
        self._stop = threading.Event()
        self._last_heartbeat_s = 0.0
        self._next_heartbeat_s = 0.0
        self._last_telemetry_s = 0.0
        self.streams = StreamRequester(
            self.settings,
            self.send,
            self.codec.module,
            lambda: self._sysid,
            lambda: self.origins.origin is not None,
            self.counters,
        )
        self._reopens_seen = self._link_reopens()
        rates = [r for r in (s.attitude_rate_hz, s.local_position_rate_hz) if r > 0]
        self._stale_s = max(_MIN_STALE_S, 3.0 / min(rates)) if rates else math.inf
        self._thread = threading.Thread(target=self._run, name="vehicle-link", daemon=True)
        self._thread.start()

    # ----------------------------------------------------------------- public API

    @property
    def sysid(self) -> int:
        """The vehicle's system ID (0 until learned)."""
        return self._sysid

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def origin(self) -> GlobalOrigin | None:
        return self.origins.origin

    def wait_connected(self, timeout_s: float) -> int:
        """Block until the autopilot's heartbeat is heard; its sysid, or LinkTimeout."""
        if not self._connected.wait(timeout_s):
            raise LinkTimeout(f"{self.link.name}: no autopilot heartbeat within {timeout_s} s")
        return self._sysid

    def wait_for_state(
        self, predicate: Callable[[VehicleState], bool], timeout_s: float
    ) -> VehicleState:
        """Block until ``predicate(state())`` holds; the state, or LinkTimeout."""
        end = time.monotonic() + timeout_s
        with self._changed:
            while True:
                state = self.state()
                if predicate(state):
                    return state
                remaining = end - time.monotonic()
                if remaining <= 0:
                    raise LinkTimeout(f"{self.link.name}: state not reached within {timeout_s} s")
                self._changed.wait(remaining)

    def state(self) -> VehicleState:
        method = self.streams.method
        return VehicleState(
            connected=self.connected,
            sysid=self._sysid,
            origin=self.origins.origin,
            clock_synced=self.clock.synced,
            clock_offset_s=self.clock.offset_s if self.clock.synced else None,
            stream_method=method,
            last_pose=self.poses.latest(),
            # refused: autopilot messages with bad fields or an off-timeline boot time
            counters={**vars(self.counters), "refused": self.telemetry.refused.total()},
        )

    def listen(self, callback: Callable[[MavMessage, float], None]) -> None:
        """Also give every decoded message, with its arrival time (monotonic s), to
        ``callback`` on the reader thread (the closer looks' AutopilotWatch)."""
        self._listeners = (*self._listeners, callback)

    def send(self, msg: MavMessage) -> bool:
        """Encode and send as (vehicle sysid, our component); False if dropped."""
        if self._sysid == 0:
            self.counters.sends_dropped += 1
            return False
        data = self.codec.encode(msg)
        try:
            self.link.write(data)
        except LinkError as exc:
            self.counters.sends_dropped += 1
            log.debug("%s: send failed: %s", self.link.name, exc)
            return False
        self.counters.messages_out += 1
        if self._tlog is not None:
            self._tlog.write(data)
        return True

    def send_encoded(self, data: bytes) -> bool:
        """Send a frame encoded by another of this companion's components; False if
        dropped (the vehicle's system ID is not known yet, or the link failed)."""
        if self._sysid == 0:
            self.counters.sends_dropped += 1
            return False
        try:
            self.link.write(data)
        except LinkError as exc:
            self.counters.sends_dropped += 1
            log.debug("%s: send failed: %s", self.link.name, exc)
            return False
        self.counters.messages_out += 1
        if self._tlog is not None:
            self._tlog.write(data)
        return True

    def send_tunnel(self, msg: MavMessage) -> bool:
        """Send a dialect message inside a TUNNEL (routed by the autopilot to the GCS)."""
        if self._sysid == 0:
            self.counters.sends_dropped += 1
            return False
        return self.send(tunnel.wrap(self.codec, msg))

    def close(self) -> None:
        """Stop the reader thread and close the link; safe twice."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        self.link.close()

    def __enter__(self) -> VehicleLink:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- the loop

    @property
    def alive(self) -> bool:
        """False once the reader thread has ended (after close(), or a bug)."""
        return self._thread.is_alive()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._pass()
            except Exception:  # a bug must not stop the vehicle link: nothing restarts it
                self.counters.loop_errors += 1
                log.exception("%s: vehicle link loop failed; continuing", self.link.name)
                self._stop.wait(_TICK_S)

    def _pass(self) -> None:
        """One pass of the reader loop: read, dispatch, tick, notify waiters."""
        try:
            data = self.link.read(_TICK_S)
        except LinkError as exc:
            if self._stop.is_set():
                return
            self.counters.read_errors += 1
            log.warning("%s: %s", self.link.name, exc)
            self._stop.wait(0.5)  # a non-reconnecting link that broke: do not spin
            data = b""
        now = time.monotonic()
        if data:
            for msg in self.codec.feed(data):
                self._dispatch(msg, now)
        self._tick(time.monotonic())
        with self._changed:
            self._changed.notify_all()

    def _dispatch(self, msg: MavMessage, now: float) -> None:
        self.counters.messages_in += 1
        if self._tlog is not None:
            self._tlog.write(bytes(msg.get_msgbuf()))
        try:
            self._handle(msg, now)
            if self._on_message is not None:
                self._on_message(msg)
            for listener in self._listeners:
                listener(msg, now)
        except Exception:  # a bug in one handler must not stop the vehicle link
            self.counters.handler_errors += 1
            log.exception("handling %s failed", msg.get_type())

    def _tick(self, now: float) -> None:
        if (
            self._connected.is_set()
            and now - self._last_heartbeat_s > self.settings.heartbeat_timeout_s
        ):
            self._connected.clear()
            self.counters.link_losses += 1
            log.warning(
                "%s: no autopilot heartbeat for %.1f s: link lost",
                self.link.name,
                now - self._last_heartbeat_s,
            )
        reopens = self._link_reopens()
        if reopens != self._reopens_seen:
            self._reopens_seen = reopens
            self._next_heartbeat_s = now  # a peer that answers who spoke first must hear us
            if self._connected.is_set():
                log.info("%s: link reopened: requesting streams again", self.link.name)
                self.streams.request(now, fresh=True)
        if now >= self._next_heartbeat_s:
            self._next_heartbeat_s = now + self.settings.heartbeat_period_s
            self._send_heartbeat()
        if (
            self._connected.is_set()
            and now - self._last_telemetry_s > self._stale_s
            and now - self.streams.last_fresh_s > self._stale_s
        ):
            level = (
                logging.INFO
                if self._last_telemetry_s >= self.streams.last_fresh_s
                else logging.DEBUG
            )
            log.log(
                level,
                "%s: heartbeat heard but no telemetry for %.1f s: requesting streams again",
                self.link.name,
                now - self._last_telemetry_s,
            )
            self.streams.request(now, fresh=True)
        self.streams.check_timeout(now)

    # ----------------------------------------------------------------- handlers

    def _handle(self, msg: MavMessage, now: float) -> None:
        msg_id = msg.get_msgId()
        if msg_id == 0:  # HEARTBEAT
            self._on_heartbeat(msg, now)
            return
        if msg_id in _DIALECT_IDS or msg_id in _GROUND_REQUEST_IDS:
            self._deliver(msg)
            return
        if tunnel.is_ours(msg):
            inner = tunnel.unpack_tunnel(msg, self.codec)
            if inner is not None and inner.get_msgId() in _DIALECT_IDS:
                self._deliver(inner)
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (self._sysid, AUTOPILOT_COMPONENT):
            return
        if msg_id in _TELEMETRY_IDS:
            if msg_id in (MSG_ATTITUDE, MSG_LOCAL_POSITION_NED):
                self._last_telemetry_s = now
            update = self.telemetry.handle(msg, now)
            if update.rebooted:
                self.counters.reboots += 1
                log.warning("%s: autopilot rebooted (boot time went backwards)", self.link.name)
                self.poses.clear()
                self.streams.request(now, fresh=True)
            self._add_pose(update.pose)
            if update.origin_changed:
                log.info("EKF origin: %s", self.origins.origin)
        elif msg.get_type() == "COMMAND_ACK" and msg.command == MAV_CMD_SET_MESSAGE_INTERVAL:
            self.streams.on_interval_ack(msg)

    def _on_heartbeat(self, msg: MavMessage, now: float) -> None:
        if not is_autopilot_heartbeat(msg, self.settings.system_id):
            return
        sysid = msg.get_srcSystem()
        if self._sysid not in (0, sysid):
            return  # another vehicle on the same link: we follow the first one
        if self._sysid == 0:
            self._sysid = sysid
            self.codec.src_system = sysid
            log.info("%s: vehicle system ID %d", self.link.name, sysid)
        gap_s = now - self._last_heartbeat_s
        self._last_heartbeat_s = now
        if self._connected.is_set() and gap_s > _HEARTBEAT_GAP_S:
            log.info(
                "%s: autopilot heartbeat after %.1f s of silence (a reboot?): "
                "requesting streams again",
                self.link.name,
                gap_s,
            )
            self.streams.request(now, fresh=True)
        if not self._connected.is_set():
            log.info("%s: autopilot heartbeat heard", self.link.name)
            self._connected.set()
            self.streams.request(now, fresh=True)

    def _link_reopens(self) -> int:
        """How often the transport reopened (a ReconnectingLink counts it), else 0."""
        return int(getattr(getattr(self.link, "counters", None), "reconnects", 0) or 0)

    def _add_pose(self, sample: PoseSample | None) -> None:
        if sample is not None:
            self.poses.add(sample)
            self.counters.poses += 1

    def _deliver(self, msg: MavMessage) -> None:
        target_sys = getattr(msg, "target_system", 0)
        target_comp = getattr(msg, "target_component", 0)
        if target_sys not in (0, self._sysid) or (
            target_comp not in (0, self.codec.src_component)
            and target_comp not in self.other_components
        ):
            return
        if self._on_dialect is not None:
            self._on_dialect(msg)
            return
        try:
            self.inbox.put_nowait(msg)
        except queue.Full:
            self.counters.inbox_dropped += 1

    # ----------------------------------------------------------------- outgoing

    def _send_heartbeat(self) -> None:
        m = self.codec.module
        try:
            status = int(self._health())
        except Exception:  # the health callback is someone else's code
            log.exception("health callback failed")
            status = 5  # MAV_STATE_CRITICAL
        heartbeat = m.MAVLink_heartbeat_message(
            MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, status, 3
        )
        if self._sysid:
            self.send(heartbeat)
            return
        try:  # provisional identity: see the module docstring
            self.link.write(self.codec.encode(heartbeat))
        except LinkError as exc:
            log.debug("%s: heartbeat failed: %s", self.link.name, exc)
