"""The running HQ: receive, store, acknowledge, resend operator actions, show, export.

Threads: one reader per link puts (link, peer, bytes) on a queue; the main thread
owns the registry (SQLite) and does everything else, waking on the queue or on the
next timer (HEARTBEAT at 1 Hz, action resends, the table at <= 2 Hz, exports).

``HqApp`` is the main loop and the receive path: it decodes each burst of
datagrams (a decoder per source, hq.sources), checks signatures, unwraps TUNNELs
and hands each message to the part that owns it: victim reports to hq.intake
(stored, then acknowledged), operator actions' answers to hq.actions, pictures to
hq.pictures, the searched-area maps to hq.coverage; a robot's status and EKF origin it stores itself. What is shown and
published (event lines, the table, exports, SBS) is hq.output; replies travel the
way their message came (hq.sending).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from hq import table, wire
from hq.actions import ActionSender
from hq.counters import Counters
from hq.coverage import CoverageIntake
from hq.intake import STORE_RETRY_S, Received, ReportIntake
from hq.output import Output
from hq.pictures import PictureIntake
from hq.ratelog import RateLimitedLog
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.sbs import SbsServer
from hq.sending import Route, Sender
from hq.sources import SourceTable
from hq.web.state import LiveRobots
from mavlink_io import picture
from mavlink_io.codec import Codec
from mavlink_io.dialect import (
    RESCUE_COVERAGE_ID,
    RESCUE_MESSAGE_IDS,
    RESCUE_PICTURE_CHUNK_ID,
    RESCUE_VICTIM_REPORT_ID,
)
from mavlink_io.errors import LinkError
from mavlink_io.hub import Endpoint, Peer
from mavlink_io.signing import Signing

log = logging.getLogger(__name__)

HQ_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER: a ground station component
_HEARTBEAT_PERIOD_S = 1.0
_DB_CHECK_PERIOD_S = 0.25  # how often to look for actions written by `rescue-hq mark`
_READ_TIMEOUT_S = 0.2  # how long a reader may take to notice the stop
_MAX_INBOX = 8192  # datagrams waiting for the main thread
MAX_SOURCES = 256  # sources (link, address) with a decoder; a fleet, not the Internet
_MAX_BATCH = 256  # datagrams decoded into one database transaction
_REFUSAL_LOG_PERIOD_S = 5.0
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
        self.endpoints = list(endpoints)
        self.options = options
        self.counters = Counters()
        self._refusals = RateLimitedLog(_REFUSAL_LOG_PERIOD_S)
        self._signing = _hq_signing(options.signing)
        encoder = Codec(options.sysid, HQ_COMPONENT_ID, self._signing)
        self._m = encoder.module
        self._sender = Sender(encoder, self.endpoints)
        self._sources = SourceTable(
            lambda: Codec(options.sysid, HQ_COMPONENT_ID, self._signing, self._m),
            MAX_SOURCES,
            options.source_idle_s,
        )
        self._inbox: queue.Queue[tuple[int, Peer, bytes]] = queue.Queue(_MAX_INBOX)
        self._stop = threading.Event()
        self._readers: list[threading.Thread] = []
        self.output = Output(
            registry,
            out,
            self.counters,
            self._table_header,
            live_table=options.live_table,
            export_dir=options.export_dir,
            sbs=sbs,
        )
        event, changed = self.output.event, self.output.changed
        self.reports = ReportIntake(
            registry, self._sender, self.counters, self._refusals, event, changed
        )
        self.actions = ActionSender(
            registry, self._sender, options.sysid, self.counters, event, changed
        )
        self.pictures = PictureIntake(registry, self._refusals, event)
        self.coverage = CoverageIntake(registry, self._refusals)

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
                    self.actions.refresh()
                    next_db_check = now + _DB_CHECK_PERIOD_S
                self._sources.forget_silent(now)
                self.pictures.assembler.forget_idle(now)
                self.counters.sources_forgotten = self._sources.forgotten
                if self.reports.held and now >= next_store_retry:
                    self.reports.store_and_ack([])  # reports held from a failed write
                    next_store_retry = now + STORE_RETRY_S
                self.actions.poll()
                self.output.refresh(now)
                due = self.actions.seconds_until_due()
                wake = min(next_heartbeat, next_db_check, now + (0.5 if due is None else due))
                if self.reports.held:
                    wake = min(wake, next_store_retry)
                if deadline is not None:
                    wake = min(wake, deadline)
                self._process(self._collect(max(0.0, wake - time.monotonic())))
        finally:
            self._stop.set()
            for t in self._readers:
                t.join(timeout=2 * _READ_TIMEOUT_S)
            self.output.changed()
            self.output.refresh(time.monotonic(), force=True)
            self.output.close()

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
        reports: list[Received] = []
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
            self.reports.store_and_ack(reports)

    def _dispatch(self, msg: Any, route: Route, reports: list[Received]) -> None:
        msg_id = msg.get_msgId()
        if msg_id in RESCUE_MESSAGE_IDS:
            self.actions.heard(msg.get_srcSystem(), route)
        if msg_id == RESCUE_VICTIM_REPORT_ID:
            self.reports.on_report(msg, route, reports)
        elif msg_id == RESCUE_PICTURE_CHUNK_ID:
            self._on_picture_chunk(msg, route)
        elif msg_id == RESCUE_COVERAGE_ID:
            self._on_coverage(msg, route)
        elif msg_id == self._m.MAVLINK_MSG_ID_RESCUE_STATUS:
            self._on_status(msg)
        elif msg_id == self._m.MAVLINK_MSG_ID_RESCUE_ACK:
            self.actions.on_ack(msg)
        elif msg_id == self._m.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            self._on_origin(msg)
        elif msg_id == self._m.MAVLINK_MSG_ID_LOCAL_POSITION_NED and self.options.live is not None:
            # The robot's autopilot, heard through the same radio/router as its reports.
            self.options.live.position(msg.get_srcSystem(), msg.x, msg.y, time.time())

    def _on_picture_chunk(self, msg: Any, route: Route) -> None:
        def answer(picture_id: int, result: int, received: frozenset[int]) -> None:
            ack = picture.ack_msg(
                self._m, msg.get_srcSystem(), msg.get_srcComponent(), picture_id, result, received
            )
            self._sender.send(ack, route)

        if self.pictures.on_chunk(msg, answer):
            self.output.changed()

    def _on_coverage(self, msg: Any, route: Route) -> None:
        def answer(seq: int, result: int) -> None:
            ack = self._m.MAVLink_rescue_ack_message(
                msg.get_srcSystem(), msg.get_srcComponent(), RESCUE_COVERAGE_ID, seq, result
            )
            self._sender.send(ack, route)

        m = self._m
        accepted, rejected = m.RESCUE_ACK_RESULT_ACCEPTED, m.RESCUE_ACK_RESULT_REJECTED
        if self.coverage.on_piece(msg, answer, accepted, rejected):
            self.output.changed()

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
        self.output.changed()

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
        self.output.changed()
        self.output.event(f"EKF origin of robot {msg.get_srcSystem()}: {origin}")

    def _refuse(self, kind: str, msg: Any, exc: Exception) -> None:
        self.counters.refused += 1
        self._refusals.say(
            (kind, msg.get_srcSystem()),
            f"refused {kind} from system {msg.get_srcSystem()} (not stored): {exc}",
        )

    # -- sending ---------------------------------------------------------------

    def _send_heartbeat(self) -> None:
        m = self._m
        self._sender.broadcast(
            m.MAVLink_heartbeat_message(
                m.MAV_TYPE_GCS, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3
            )
        )

    # -- output ----------------------------------------------------------------

    def _table_header(self, stored: int) -> table.Header:
        """The live table's title lines (hq.output draws the table)."""
        sbs = self.output.sbs
        warnings = (self.reports.storage_warning(), None if sbs is None else sbs.failure)
        return table.Header(
            self.options.sysid,
            [ep.name for ep in self.endpoints],
            stored,
            self._signing is not None,
            "; ".join(w for w in warnings if w) or None,
        )


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
