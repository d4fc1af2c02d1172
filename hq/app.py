"""The running HQ: receive, store, acknowledge, resend operator actions, show, export.

Threads: one reader per link puts (link, peer, bytes) on a queue; the main thread
owns the registry (SQLite) and does everything else, waking on the queue or on the
next timer (HEARTBEAT at 1 Hz, action resends, the table at <= 2 Hz, exports).

Order of work for victim reports, which is what makes "acknowledged" mean
"stored": decode a burst of datagrams, store all their reports in one SQLite
transaction (synchronous=FULL), and only after the commit returned send the
RESCUE_ACKs. A locked or failing database (a full disk) means no acknowledgement:
the reports are held in memory and written again every second, the robots keep
resending, and a full disk is said loudly (ERROR and a STATUSTEXT every 30 s, a
line on the table) until it is over; then the held reports are stored and acked.

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

from hq import export, table, wire
from hq.pictures import PictureIntake
from hq.ratelog import RateLimitedLog
from hq.records import (
    ACK_RESULT_ACCEPTED,
    ACK_RESULT_DUPLICATE,
    ACK_RESULT_REJECTED,
    IncomingReport,
    StoreResult,
)
from hq.registry import Registry
from hq.registry_file import RegistryBusy, RegistryError, RegistryFull
from hq.sbs import SbsServer
from hq.sources import SourceTable
from hq.unstored import UnstoredReports
from hq.view import hq_victims
from hq.web.state import LiveRobots
from mavlink_io import picture
from mavlink_io.codec import Codec
from mavlink_io.dialect import (
    RESCUE_MESSAGE_IDS,
    RESCUE_OPERATOR_ACTION_ID,
    RESCUE_PICTURE_CHUNK_ID,
    RESCUE_VICTIM_REPORT_ID,
)
from mavlink_io.errors import LinkError
from mavlink_io.hub import Endpoint, Peer
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
_MAX_INBOX = 8192  # datagrams waiting for the main thread
MAX_SOURCES = 256  # sources (link, address) with a decoder; a fleet, not the Internet
_MAX_BATCH = 256  # datagrams decoded into one database transaction
_STORE_RETRY_S = 1.0  # how often reports held from a failed write are tried again
_STORE_NOTICE_PERIOD_S = 30.0  # repeat the "cannot store" ERROR and STATUSTEXT this often
_MAX_UNSTORED = 10_000  # reports held in memory; beyond, the oldest wait for the robots' resend
MAV_SEVERITY_CRITICAL = 2
_REFUSAL_LOG_PERIOD_S = 5.0
_MAX_LOG_KEYS = 1024  # at most one refusal line per sender and kind this often
GPS_GLOBAL_ORIGIN_ID = 49
HQ_MUST_SIGN_IDS = RESCUE_MESSAGE_IDS | {GPS_GLOBAL_ORIGIN_ID}


@dataclass(frozen=True)
class HqOptions:
    sysid: int = 245
    export_dir: Path | None = None
    signing: Signing | None = None
    live_table: bool = False
    duration_s: float | None = None
    source_idle_s: float = 120.0  # a source (link, address) silent this long is forgotten
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
    rejected: int = 0  # reports refused for unusable values (acknowledged REJECTED)
    refused: int = 0  # other messages refused for unusable values
    signature_refused: int = 0  # unsigned or badly signed where a signature is required
    acks_sent: int = 0
    store_failures: int = 0
    actions_sent: int = 0
    actions_acked: int = 0
    actions_rejected: int = 0
    foreign_tunnels: int = 0
    exports: int = 0
    inbox_dropped: int = 0  # datagrams dropped because the main thread was behind
    sources_forgotten: int = 0  # decoders dropped: silent too long, or too many sources


class HqApp:
    def __init__(
        self,
        registry: Registry,
        endpoints: Sequence[Endpoint],
        options: HqOptions,
        out: TextIO,
        sbs: SbsServer | None = None,
    ) -> None:
        self.registry = registry
        self.sbs = sbs  # the victims as ADS-B traffic for QGC (hq/sbs.py)
        self.endpoints = list(endpoints)
        self.options = options
        self.out = out
        self.counters = Counters()
        self._refusals = RateLimitedLog(_REFUSAL_LOG_PERIOD_S)
        self._signing = _hq_signing(options.signing)
        self._encoder = Codec(options.sysid, HQ_COMPONENT_ID, self._signing)
        self._m = self._encoder.module
        self._sources = SourceTable(
            lambda: Codec(options.sysid, HQ_COMPONENT_ID, self._signing, self._m),
            MAX_SOURCES,
            options.source_idle_s,
        )
        self._inbox: queue.Queue[tuple[int, Peer, bytes]] = queue.Queue(_MAX_INBOX)
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
        self._unstored = UnstoredReports(_MAX_UNSTORED)
        self.pictures = PictureIntake(registry, self._refusals, self._event)
        self._store_failing_since: float | None = None
        self._next_store_notice = 0.0

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
        next_store_retry = 0.0
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
                self._sources.forget_silent(now)
                self.pictures.assembler.forget_idle(now)
                self.counters.sources_forgotten = self._sources.forgotten
                if self._unstored and now >= next_store_retry:
                    self._store_and_ack([])  # reports held from a failed write
                    next_store_retry = now + _STORE_RETRY_S
                self._outbox.poll()
                self._refresh_output(now)
                due = self._outbox.seconds_until_due()
                wake = min(next_heartbeat, next_db_check, now + (0.5 if due is None else due))
                if self._unstored:
                    wake = min(wake, next_store_retry)
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
                try:
                    self._inbox.put_nowait((index, peer, data))
                except queue.Full:  # a flood: dropped like a full UDP buffer; robots resend
                    self.counters.inbox_dropped += 1

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

    @property
    def tracked_sources(self) -> int:
        """How many sources (link, address) the HQ keeps a decoder for."""
        return len(self._sources)

    def _decoder(self, index: int, peer: Peer) -> Codec:
        codec = self._sources.decoder((index, peer), time.monotonic())
        self.counters.sources_forgotten = self._sources.forgotten
        return codec

    def _process(self, batch: list[tuple[int, Peer, bytes]]) -> None:
        reports: list[tuple[IncomingReport, Any, Route]] = []
        for index, peer, data in batch:
            decoder = self._decoder(index, peer)
            refused_before = decoder.counters.signature_rejected
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
            refused = decoder.counters.signature_rejected - refused_before
            if refused:
                self.counters.signature_refused += refused
                self._refusals.say(
                    ("signature", index),
                    f"{self.endpoints[index].name}: refused {refused} message(s) from "
                    f"{_peer_text(peer)} unsigned or with a bad signature "
                    f"({self.counters.signature_refused} in all)",
                )
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
        elif msg_id == RESCUE_PICTURE_CHUNK_ID:
            self._on_picture_chunk(msg, route)
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
            item = wire.incoming_report(msg, time.time())
        except wire.BadMessage as exc:
            self.counters.rejected += 1
            self._refusals.say(
                ("report", msg.get_srcSystem()),
                f"rejected report seq {msg.report_seq} from system {msg.get_srcSystem()} "
                f"(not stored, acknowledged REJECTED): {exc}",
            )
            self._send_ack(msg, route, ACK_RESULT_REJECTED)
            return
        report = item.report
        if report.robot_sysid != msg.get_srcSystem():
            log.warning(
                "report from system %d names robot %d; filed under robot %d",
                msg.get_srcSystem(),
                report.robot_sysid,
                report.robot_sysid,
            )
        reports.append((item, msg, route))

    def _store_and_ack(self, reports: list[tuple[IncomingReport, Any, Route]]) -> None:
        """Store the new reports and those held from a failed write; ack only what is stored."""
        self._unstored.add(reports)
        reports = self._unstored.entries()
        try:
            results = self.registry.store_reports([item for item, _, _ in reports])
        except RegistryBusy as exc:
            self.counters.store_failures += 1
            log.warning(
                "%d report(s) not stored, not acknowledged (held, robots resend): %s",
                len(reports),
                exc,
            )
            return
        except RegistryError as exc:  # RegistryFull, or the file cannot be written
            self.counters.store_failures += 1
            self._say_cannot_store(exc)
            return
        self._unstored.clear()
        if self._store_failing_since is not None:
            log.warning(
                "database %s writable again: %d held report(s) stored and acknowledged",
                self.registry.path,
                len(reports),
            )
            self._store_failing_since = None
            self._dirty = True
        for (item, msg, route), result in zip(reports, results, strict=True):
            code = ACK_RESULT_DUPLICATE if result is StoreResult.DUPLICATE else ACK_RESULT_ACCEPTED
            self._send_ack(msg, route, code)
            if result is StoreResult.DUPLICATE:
                self.counters.duplicates += 1
                continue
            self.counters.reports += 1
            self._dirty = True
            self._event(_report_line(item, result))

    def _say_cannot_store(self, exc: RegistryError) -> None:
        """Loudly, when writing starts failing and then every _STORE_NOTICE_PERIOD_S."""
        now = time.monotonic()
        if self._store_failing_since is None:
            self._store_failing_since = now
            self._next_store_notice = now
            self._dirty = True
        if now < self._next_store_notice:
            return
        self._next_store_notice = now + _STORE_NOTICE_PERIOD_S
        full = isinstance(exc, RegistryFull)
        log.error(
            "%s: %d report(s) held in memory, NOT stored and NOT acknowledged; "
            "retrying every %.0f s (robots keep resending; nothing acknowledged is lost): %s",
            "DISK FULL" if full else "DATABASE WRITE FAILED",
            len(self._unstored),
            _STORE_RETRY_S,
            exc,
        )
        text = f"rescue-hq: {'disk full' if full else 'db write failed'}, {len(self._unstored)} unstored"
        self._broadcast(
            self._m.MAVLink_statustext_message(MAV_SEVERITY_CRITICAL, text.encode()[:50])
        )

    def storage_warning(self) -> str | None:
        """A line for the table while reports cannot be stored."""
        if self._store_failing_since is None:
            return None
        return f"CANNOT STORE: {len(self._unstored)} report(s) held in memory, not acknowledged"

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

    def _on_picture_chunk(self, msg: Any, route: Route) -> None:
        def answer(picture_id: int, result: int, received: frozenset[int]) -> None:
            ack = picture.ack_msg(
                self._m, msg.get_srcSystem(), msg.get_srcComponent(), picture_id, result, received
            )
            self._send(ack, route)

        if self.pictures.on_chunk(msg, answer):
            self._dirty = True

    def _on_status(self, msg: Any) -> None:
        try:
            status = wire.status_from_msg(msg)
        except wire.BadMessage as exc:
            self._refuse("RESCUE_STATUS", msg, exc)
            return
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
        seq, result, robot = int(msg.seq), int(msg.result), msg.get_srcSystem()
        try:
            fresh = self.registry.ack_action(seq, time.time(), result)
        except RegistryError as exc:
            log.warning("answer to action %d not stored (the action is sent again): %s", seq, exc)
            return
        self._outbox.on_ack(msg)
        self._queued.discard(seq)
        if not fresh:
            return
        self._dirty = True
        if result == ACK_RESULT_ACCEPTED:
            self.counters.actions_acked += 1
            self._event(f"action {seq} acknowledged by robot {robot}")
        elif result == ACK_RESULT_DUPLICATE:
            self.counters.actions_acked += 1
            self._event(f"action {seq} acknowledged by robot {robot} (it had applied it already)")
        else:
            self.counters.actions_rejected += 1
            what = (
                "REJECTED"
                if result == ACK_RESULT_REJECTED
                else f"answered with unknown result {result}"
            )
            self._event(
                f"action {seq} {what} by robot {robot}: not applied "
                "(the robot does not know that victim or cannot do it)",
                level=logging.WARNING,
            )

    def _on_origin(self, msg: Any) -> None:
        try:
            origin = wire.origin_from_msg(msg)
        except wire.BadMessage as exc:
            self._refuse("GPS_GLOBAL_ORIGIN", msg, exc)
            return
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

    def _refuse(self, kind: str, msg: Any, exc: Exception) -> None:
        self.counters.refused += 1
        self._refusals.say(
            (kind, msg.get_srcSystem()),
            f"refused {kind} from system {msg.get_srcSystem()} (not stored): {exc}",
        )

    # -- sending ---------------------------------------------------------------

    def _send(self, msg: Any, route: Route) -> None:
        if route.tunnel:
            msg = wire.wrap_tunnel(self._encoder, msg, route.sysid, route.compid)
        data = self._encoder.encode(msg)
        self.endpoints[route.endpoint].send_to(data, route.peer)

    def _send_heartbeat(self) -> None:
        m = self._m
        self._broadcast(
            m.MAVLink_heartbeat_message(
                m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3
            )
        )

    def _broadcast(self, msg: Any) -> None:
        data = self._encoder.encode(msg)
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

    def _event(self, line: str, level: int = logging.INFO) -> None:
        log.log(level, "%s", line)
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
        if dirty and self.sbs is not None:
            self.sbs.publish(victims)
        if self.options.live_table:
            header = table.Header(
                self.options.sysid,
                [ep.name for ep in self.endpoints],
                stored,
                self._signing is not None,
                self.storage_warning(),
            )
            text = table.render(header, victims, robots, time.time(), colour=True)
            self.out.write(table.CLEAR_SCREEN + text)
            self.out.flush()

    def _export(self, victims: list[Any]) -> None:
        assert self.options.export_dir is not None
        try:
            export.export_all(victims, self.options.export_dir)
        except OSError as exc:
            log.error("export to %s failed: %s", self.options.export_dir, exc)
            return
        self.counters.exports += 1


def _hq_signing(signing: Signing | None) -> Signing | None:
    """With a key, every message that changes the HQ's state must be signed.

    That is every dialect message (a forged report misleads rescuers) and
    GPS_GLOBAL_ORIGIN (a forged origin moves a robot's victims on the map).
    """
    if signing is None:
        return None
    return Signing(signing.key, signing.link_id, must_sign_ids=HQ_MUST_SIGN_IDS)


def _peer_text(peer: Peer) -> str:
    return "the link" if peer is None else f"{peer[0]}:{peer[1]}"


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
        f"{r.urgency.name} {r.visibility_pct:.0f}% visible {r.state.name} {where} ±{r.sigma_m:.1f} m{note}"
    )
