"""The running HQ: receive, store, acknowledge, resend operator actions, show, export.

Threads: one reader per link puts (link, peer, bytes) on a queue; the main thread
owns the registry (SQLite) and does everything else, waking on the queue or on the
next timer (HEARTBEAT at 1 Hz, action resends, the table at <= 2 Hz, exports).

Order of work for victim reports, which is what makes "acknowledged" mean
"stored": decode a burst of datagrams, store all their reports in one SQLite
transaction (synchronous=FULL), and only after the commit returned send the
RESCUE_ACKs. A locked or failing database means no acknowledgement: the robots
resend and the HQ stores them when it can.

Replies travel the way the message came: the same link, the same peer address,
and, when the report arrived inside a TUNNEL (through an autopilot or MAVProxy),
wrapped in a TUNNEL addressed to the robot.
"""

from __future__ import annotations

import logging
import queue
import sqlite3
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from fusion.types import GlobalOrigin
from hq import export, table, wire
from hq.registry import (
    IncomingReport,
    Registry,
    RegistryBusy,
    RegistryError,
    StoreResult,
)
from hq.transport import Endpoint, Peer
from hq.view import hq_victims
from hq.web.state import LiveRobots
from mavlink_io.codec import Codec
from mavlink_io.dialect import (
    RESCUE_MESSAGE_IDS,
    RESCUE_OPERATOR_ACTION_ID,
    RESCUE_VICTIM_REPORT_ID,
)
from mavlink_io.errors import LinkError
from mavlink_io.reliable import Outbox
from mavlink_io.signing import Signing

log = logging.getLogger(__name__)

HQ_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER: a ground station component
COMPANION_COMPONENT_ID = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: where robots' reports come from
_HEARTBEAT_PERIOD_S = 1.0
_REDRAW_MIN_PERIOD_S = 0.5  # the table and the exports: at most 2 Hz
_AGE_REFRESH_S = 1.0  # redraw the live table this often even without news (ages tick)
_DB_CHECK_PERIOD_S = 0.25  # how often to look for actions written by `rescue-hq mark`
_ACTION_FIRST_RETRY_S = 0.5
_ACTION_MAX_RETRY_S = 4.0
_READ_TIMEOUT_S = 0.2  # how long a reader may take to notice the stop
_MAX_BATCH = 256  # datagrams decoded into one database transaction
_ACK_ACCEPTED = 0
_ACK_DUPLICATE = 1
_ACK_REJECTED = 2


@dataclass(frozen=True)
class HqOptions:
    sysid: int = 245
    export_dir: Path | None = None
    signing: Signing | None = None
    live_table: bool = False
    duration_s: float | None = None
    origin: GlobalOrigin | None = None
    live: LiveRobots | None = None  # for the console: who was heard, where robots are


@dataclass(frozen=True)
class Route:
    """How to reach a robot: the link and peer it spoke from, and the envelope it used."""

    endpoint: int
    peer: Peer
    tunnel: bool
    sysid: int  # the outer sender (the TUNNEL's sender when tunnelled)
    compid: int


@dataclass
class Counters:
    reports: int = 0
    duplicates: int = 0
    rejected: int = 0
    acks_sent: int = 0
    store_failures: int = 0
    actions_sent: int = 0
    actions_acked: int = 0
    foreign_tunnels: int = 0
    exports: int = 0


class HqApp:
    def __init__(
        self,
        registry: Registry,
        endpoints: Sequence[Endpoint],
        options: HqOptions,
        out: TextIO,
    ) -> None:
        self.registry = registry
        self.endpoints = list(endpoints)
        self.options = options
        self.out = out
        self.counters = Counters()
        self._signing = _hq_signing(options.signing)
        self._encoder = Codec(options.sysid, HQ_COMPONENT_ID, self._signing)
        self._m = self._encoder.module
        self._decoders: dict[tuple[int, Peer], Codec] = {}
        self._inbox: queue.Queue[tuple[int, Peer, bytes]] = queue.Queue()
        self._routes: dict[int, Route] = {}
        self._outbox = Outbox(
            self._send_action, initial_s=_ACTION_FIRST_RETRY_S, max_s=_ACTION_MAX_RETRY_S
        )
        self._queued: set[int] = set()  # action_seqs handed to the outbox
        self._stop = threading.Event()
        self._readers: list[threading.Thread] = []
        self._dirty = True
        self._last_draw_mono_s = 0.0
        self._db_version = -1

    # -- lifecycle -------------------------------------------------------------

    def stop(self) -> None:
        self._stop.set()

    def run(self, stop: threading.Event | None = None) -> None:
        """Run until ``stop`` (or self.stop()) is set or the duration is over."""
        outer = stop or threading.Event()
        for i, ep in enumerate(self.endpoints):
            t = threading.Thread(target=self._reader, args=(i, ep), name=f"hq-rx-{i}", daemon=True)
            t.start()
            self._readers.append(t)
        deadline = (
            None if self.options.duration_s is None else time.monotonic() + self.options.duration_s
        )
        next_heartbeat = 0.0
        next_db_check = 0.0
        try:
            while not (self._stop.is_set() or outer.is_set()):
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                if now >= next_heartbeat:
                    self._send_heartbeat()
                    next_heartbeat = now + _HEARTBEAT_PERIOD_S
                if now >= next_db_check:
                    self._refresh_actions()
                    next_db_check = now + _DB_CHECK_PERIOD_S
                self._outbox.poll()
                self._refresh_output(now)
                due = self._outbox.seconds_until_due()
                wake = min(next_heartbeat, next_db_check, now + (0.5 if due is None else due))
                if deadline is not None:
                    wake = min(wake, deadline)
                self._process(self._collect(max(0.0, wake - time.monotonic())))
        finally:
            self._stop.set()
            for t in self._readers:
                t.join(timeout=2 * _READ_TIMEOUT_S)
            self._dirty = True
            self._refresh_output(time.monotonic(), force=True)

    def _reader(self, index: int, endpoint: Endpoint) -> None:
        while not self._stop.is_set():
            try:
                data, peer = endpoint.receive(_READ_TIMEOUT_S)
            except LinkError as exc:
                if self._stop.is_set():
                    return
                log.error("%s: %s; this link stops receiving", endpoint.name, exc)
                return
            if data:
                self._inbox.put((index, peer, data))

    def _collect(self, timeout_s: float) -> list[tuple[int, Peer, bytes]]:
        try:
            first = self._inbox.get(timeout=timeout_s)
        except queue.Empty:
            return []
        batch = [first]
        while len(batch) < _MAX_BATCH:
            try:
                batch.append(self._inbox.get_nowait())
            except queue.Empty:
                break
        return batch

    # -- receiving -------------------------------------------------------------

    def _decoder(self, index: int, peer: Peer) -> Codec:
        key = (index, peer)
        codec = self._decoders.get(key)
        if codec is None:
            codec = Codec(self.options.sysid, HQ_COMPONENT_ID, self._signing, self._m)
            self._decoders[key] = codec
        return codec

    def _process(self, batch: list[tuple[int, Peer, bytes]]) -> None:
        reports: list[tuple[IncomingReport, Any, Route]] = []
        for index, peer, data in batch:
            decoder = self._decoder(index, peer)
            messages = decoder.feed(data)
            if self.endpoints[index].datagram:
                decoder.reset()  # a tail after a whole datagram is garbage
            for msg in messages:
                route = Route(index, peer, False, msg.get_srcSystem(), msg.get_srcComponent())
                if msg.get_msgId() == self._m.MAVLINK_MSG_ID_TUNNEL:
                    inner = wire.unwrap_tunnel(decoder, msg)
                    if inner is None:
                        self.counters.foreign_tunnels += 1
                        continue
                    route = Route(index, peer, True, route.sysid, route.compid)
                    msg = inner
                if self.options.live is not None:
                    self.options.live.heard(msg.get_srcSystem(), time.time())
                self._dispatch(msg, route, reports)
        if reports:
            self._store_and_ack(reports)

    def _dispatch(self, msg: Any, route: Route, reports: list[Any]) -> None:
        msg_id = msg.get_msgId()
        if msg_id in RESCUE_MESSAGE_IDS:
            if msg.get_srcSystem() not in self._routes and self._outbox.pending_count:
                self._outbox.resend_all_now()  # actions waiting for this robot to be heard
            self._routes[msg.get_srcSystem()] = route
        if msg_id == RESCUE_VICTIM_REPORT_ID:
            self._on_report(msg, route, reports)
        elif msg_id == self._m.MAVLINK_MSG_ID_RESCUE_STATUS:
            self._on_status(msg)
        elif msg_id == self._m.MAVLINK_MSG_ID_RESCUE_ACK:
            self._on_ack(msg)
        elif msg_id == self._m.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            self._on_origin(msg)
        elif msg_id == self._m.MAVLINK_MSG_ID_LOCAL_POSITION_NED and self.options.live is not None:
            # The robot's autopilot, heard through the same radio/router as its reports.
            self.options.live.position(msg.get_srcSystem(), msg.x, msg.y, time.time())

    def _on_report(self, msg: Any, route: Route, reports: list[Any]) -> None:
        try:
            report = wire.report_from_msg(msg)
        except wire.BadReport as exc:
            self.counters.rejected += 1
            log.warning(
                "rejected report seq %d from system %d: %s",
                msg.report_seq,
                msg.get_srcSystem(),
                exc,
            )
            self._send_ack(msg, route, _ACK_REJECTED)
            return
        if report.robot_sysid != msg.get_srcSystem():
            log.warning(
                "report from system %d names robot %d; filed under robot %d",
                msg.get_srcSystem(),
                report.robot_sysid,
                report.robot_sysid,
            )
        item = IncomingReport(
            report=report,
            report_seq=int(msg.report_seq),
            report_time_usec=int(msg.time_usec),
            merged_into_id=int(msg.merged_into_id),
            src_compid=int(msg.get_srcComponent()),
            received_unix_s=time.time(),
        )
        reports.append((item, msg, route))

    def _store_and_ack(self, reports: list[tuple[IncomingReport, Any, Route]]) -> None:
        try:
            results = self.registry.store_reports([item for item, _, _ in reports])
        except (RegistryBusy, RegistryError) as exc:
            self.counters.store_failures += 1
            log.warning(
                "%d report(s) not stored, not acknowledged (robots resend): %s", len(reports), exc
            )
            return
        for (item, msg, route), result in zip(reports, results, strict=True):
            code = _ACK_DUPLICATE if result is StoreResult.DUPLICATE else _ACK_ACCEPTED
            self._send_ack(msg, route, code)
            if result is StoreResult.DUPLICATE:
                self.counters.duplicates += 1
                continue
            self.counters.reports += 1
            self._dirty = True
            self._event(_report_line(item, result))

    def _send_ack(self, msg: Any, route: Route, result: int) -> None:
        ack = self._m.MAVLink_rescue_ack_message(
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            RESCUE_VICTIM_REPORT_ID,
            int(msg.report_seq),
            result,
        )
        self._send(ack, route)
        self.counters.acks_sent += 1

    def _on_status(self, msg: Any) -> None:
        status = {
            "uptime_s": float(msg.uptime_s),
            "fps": float(msg.fps),
            "drop_pct": float(msg.drop_pct),
            "vision_ms": float(msg.vision_ms),
            "flags": float(msg.flags),
            "victims_confirmed": float(msg.victims_confirmed),
            "victims_tentative": float(msg.victims_tentative),
            "outbox_pending": float(msg.outbox_pending),
        }
        try:
            self.registry.store_status(
                msg.get_srcSystem(), msg.get_srcComponent(), status, time.time()
            )
        except RegistryError as exc:
            log.debug("status of robot %d not stored: %s", msg.get_srcSystem(), exc)
            return
        self._dirty = True

    def _on_ack(self, msg: Any) -> None:
        if msg.acked_msgid != RESCUE_OPERATOR_ACTION_ID or msg.target_system != self.options.sysid:
            return
        seq = int(msg.seq)
        try:
            fresh = self.registry.ack_action(seq, time.time())
        except RegistryError as exc:
            log.warning("acknowledgement of action %d not stored (sent again): %s", seq, exc)
            return
        self._outbox.on_ack(msg)
        if fresh:
            self.counters.actions_acked += 1
            self._dirty = True
            self._event(f"action {seq} acknowledged by robot {msg.get_srcSystem()}")

    def _on_origin(self, msg: Any) -> None:
        origin = wire.origin_from_msg(msg)
        if origin is None:
            return
        known = {r.sysid: r.origin for r in self.registry.robots()}.get(msg.get_srcSystem())
        if known == origin:
            return
        try:
            self.registry.set_robot_origin(msg.get_srcSystem(), msg.get_srcComponent(), origin)
        except RegistryError as exc:
            log.warning("origin of system %d not stored: %s", msg.get_srcSystem(), exc)
            return
        self._dirty = True
        self._event(f"EKF origin of robot {msg.get_srcSystem()}: {origin}")

    # -- sending ---------------------------------------------------------------

    def _send(self, msg: Any, route: Route) -> None:
        if route.tunnel:
            msg = wire.wrap_tunnel(self._encoder, msg, route.sysid, route.compid)
        data = self._encoder.encode(msg)
        self.endpoints[route.endpoint].send_to(data, route.peer)

    def _send_heartbeat(self) -> None:
        m = self._m
        hb = m.MAVLink_heartbeat_message(
            m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3
        )
        data = self._encoder.encode(hb)
        for ep in self.endpoints:
            ep.broadcast(data)

    def _refresh_actions(self) -> None:
        """Hand actions recorded by `rescue-hq mark` (another process) to the outbox."""
        try:
            version = self.registry.data_version()
            if version == self._db_version:
                return
            pending = self.registry.actions(pending_only=True)
        except (RegistryError, sqlite3.Error) as exc:  # busy: try again at the next tick
            log.debug("cannot read actions: %s", exc)
            return
        self._db_version = version
        self._dirty = True
        for action in pending:
            if action.action_seq in self._queued:
                continue
            self._queued.add(action.action_seq)
            self._event(
                f"action {action.action_seq}: {action.action.name} robot "
                f"{action.robot_sysid} victim {action.victim_id} (sending until acknowledged)"
            )
            route = self._routes.get(action.robot_sysid)
            self._outbox.submit(
                self._m.MAVLink_rescue_operator_action_message(
                    action.robot_sysid,
                    route.compid if route else COMPANION_COMPONENT_ID,
                    action.victim_id,
                    action.action_seq,
                    action.action.value,
                )
            )

    def _send_action(self, msg: Any) -> None:
        """The outbox's sender: to the robot's last route, or nowhere until it is heard."""
        route = self._routes.get(msg.target_system)
        if route is None:
            return
        self._send(msg, route)
        self.counters.actions_sent += 1
        try:
            self.registry.note_action_sent(int(msg.action_seq), time.time())
        except RegistryError as exc:
            log.debug("send count of action %d not stored: %s", msg.action_seq, exc)

    # -- output ----------------------------------------------------------------

    def _event(self, line: str) -> None:
        log.info("%s", line)
        if not self.options.live_table:
            self.out.write(f"{time.strftime('%H:%M:%S')} {line}\n")
            self.out.flush()

    def _refresh_output(self, now: float, *, force: bool = False) -> None:
        since = now - self._last_draw_mono_s
        live_tick = self.options.live_table and since >= _AGE_REFRESH_S
        if not force and (since < _REDRAW_MIN_PERIOD_S or not (self._dirty or live_tick)):
            return
        self._last_draw_mono_s = now
        dirty, self._dirty = self._dirty, False
        try:
            victims = hq_victims(self.registry)
            robots = self.registry.robots()
            stored = self.registry.report_count()
        except RegistryError as exc:
            log.warning("cannot read the registry: %s", exc)
            return
        if dirty and self.options.export_dir is not None:
            self._export(victims)
        if self.options.live_table:
            header = table.Header(
                self.options.sysid,
                [ep.name for ep in self.endpoints],
                stored,
                self._signing is not None,
            )
            text = table.render(header, victims, robots, time.time(), colour=True)
            self.out.write(table.CLEAR_SCREEN + text)
            self.out.flush()

    def _export(self, victims: list[Any]) -> None:
        assert self.options.export_dir is not None
        origin = self.options.origin or self.registry.default_origin()
        try:
            export.export_all(victims, self.options.export_dir, origin)
        except OSError as exc:
            log.error("export to %s failed: %s", self.options.export_dir, exc)
            return
        self.counters.exports += 1


def _hq_signing(signing: Signing | None) -> Signing | None:
    """The HQ demands signatures on every dialect message (a forged report misleads rescuers)."""
    if signing is None:
        return None
    return Signing(signing.key, signing.link_id, must_sign_ids=frozenset(RESCUE_MESSAGE_IDS))


def _report_line(item: IncomingReport, result: StoreResult) -> str:
    r = item.report
    where = (
        f"{r.lat_deg:.6f},{r.lon_deg:.6f}"
        if r.lat_deg is not None
        else f"N{r.north_m:+.1f} E{r.east_m:+.1f}"
    )
    note = " (older than what the HQ holds; kept in the log)" if result is StoreResult.STALE else ""
    return (
        f"report robot {r.robot_sysid} victim {r.victim_id} seq {item.report_seq}: "
        f"{r.urgency.name} {r.visibility_pct:.0f}% {r.state.name} {where} ±{r.sigma_m:.1f} m{note}"
    )
