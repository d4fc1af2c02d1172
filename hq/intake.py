"""Victim reports in: checked, stored, and only then acknowledged.

Order of work for victim reports, which is what makes "acknowledged" mean
"stored": the main loop decodes a burst of datagrams, ``store_and_ack`` stores all
their reports in one SQLite transaction (synchronous=FULL), and only after the
commit returned sends the RESCUE_ACKs (each naming the HQ's number for the person,
``hq_victim_id``): ACCEPTED for what is kept and shown,
DUPLICATE for what was stored before, REJECTED for a report that does not validate
or is older than the one held for that robot's victim (kept in the log, not shown). A locked or failing database (a full disk)
means no acknowledgement: the reports are held in memory and written again every
second, the robots keep resending, and a full disk is said loudly (ERROR and a
STATUSTEXT every 30 s, a line on the table) until it is over; then the held
reports are stored and acked.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from hq import wire
from hq.counters import Counters
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
from hq.sending import Route, Sender
from hq.unstored import UnstoredReports
from mavlink_io.dialect import RESCUE_VICTIM_REPORT_ID

log = logging.getLogger(__name__)

STORE_RETRY_S = 1.0  # how often reports held from a failed write are tried again
_STORE_NOTICE_PERIOD_S = 30.0  # repeat the "cannot store" ERROR and STATUSTEXT this often
_MAX_UNSTORED = 10_000  # reports held in memory; beyond, the oldest wait for the robots' resend
MAV_SEVERITY_CRITICAL = 2

Received = tuple[IncomingReport, Any, Route]  # the report, its message, the way back
# ACCEPTED only for what the HQ keeps and shows. A report older (by report_seq) than
# the one the HQ holds for that robot's victim is in the log but shown nowhere: it is
# REJECTED ("not applied"), never ACCEPTED, so a robot whose sequence went back (its
# state lost commits) is not told that a person it reports is at the HQ.
_ACK_RESULTS = {
    StoreResult.ACCEPTED: ACK_RESULT_ACCEPTED,
    StoreResult.DUPLICATE: ACK_RESULT_DUPLICATE,
    StoreResult.STALE: ACK_RESULT_REJECTED,
}


class ReportIntake:
    """RESCUE_VICTIM_REPORTs in, the registry written, RESCUE_ACKs out. The main thread."""

    def __init__(
        self,
        registry: Registry,
        sender: Sender,
        counters: Counters,
        refusals: RateLimitedLog,
        event: Callable[[str], None],
        changed: Callable[[], None],
    ) -> None:
        self.registry = registry
        self._sender = sender
        self._m = sender.m
        self.counters = counters
        self._refusals = refusals
        self._event = event
        self._changed = changed  # what the table and the exports show has changed
        self._unstored = UnstoredReports(_MAX_UNSTORED)
        self._store_failing_since: float | None = None
        self._next_store_notice = 0.0

    @property
    def held(self) -> int:
        """Reports held in memory from a failed write (not acknowledged)."""
        return len(self._unstored)

    def on_report(self, msg: Any, route: Route, reports: list[Received]) -> None:
        """Check one report: added to this burst's ``reports``, or acknowledged REJECTED."""
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

    def store_and_ack(self, reports: list[Received]) -> None:
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
            self._changed()
        for (item, msg, route), result in zip(reports, results, strict=True):
            hq_id = self.registry.hq_id_of(item.report.robot_sysid, item.report.victim_id)
            self._send_ack(msg, route, _ACK_RESULTS[result], hq_id or 0)
            if result is StoreResult.DUPLICATE:
                self.counters.duplicates += 1
                continue
            self.counters.reports += 1
            self._changed()
            self._event(_report_line(item, result))

    def _say_cannot_store(self, exc: RegistryError) -> None:
        """Loudly, when writing starts failing and then every _STORE_NOTICE_PERIOD_S."""
        now = time.monotonic()
        if self._store_failing_since is None:
            self._store_failing_since = now
            self._next_store_notice = now
            self._changed()
        if now < self._next_store_notice:
            return
        self._next_store_notice = now + _STORE_NOTICE_PERIOD_S
        full = isinstance(exc, RegistryFull)
        log.error(
            "%s: %d report(s) held in memory, NOT stored and NOT acknowledged; "
            "retrying every %.0f s (robots keep resending; nothing acknowledged is lost): %s",
            "DISK FULL" if full else "DATABASE WRITE FAILED",
            len(self._unstored),
            STORE_RETRY_S,
            exc,
        )
        text = f"rescue-hq: {'disk full' if full else 'db write failed'}, {len(self._unstored)} unstored"
        self._sender.broadcast(
            self._m.MAVLink_statustext_message(MAV_SEVERITY_CRITICAL, text.encode()[:50])
        )

    def storage_warning(self) -> str | None:
        """A line for the table while reports cannot be stored."""
        if self._store_failing_since is None:
            return None
        return f"CANNOT STORE: {len(self._unstored)} report(s) held in memory, not acknowledged"

    def _send_ack(self, msg: Any, route: Route, result: int, hq_id: int = 0) -> None:
        """``hq_id``: the HQ's number for the person (0: none), which the robot's
        announcements then use (docs/HQ.md "One number per victim")."""
        ack = self._m.MAVLink_rescue_ack_message(
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            RESCUE_VICTIM_REPORT_ID,
            int(msg.report_seq),
            result,
            hq_id & 0xFFFFFFFF,
        )
        self._sender.send(ack, route)
        self.counters.acks_sent += 1


def _report_line(item: IncomingReport, result: StoreResult) -> str:
    r = item.report
    where = (
        f"{r.lat_deg:.6f},{r.lon_deg:.6f}"
        if r.lat_deg is not None
        else f"N{r.north_m:+.1f} E{r.east_m:+.1f}"
    )
    note = (
        " (older than what the HQ holds: kept in the log, not shown, acknowledged REJECTED)"
        if result is StoreResult.STALE
        else ""
    )
    return (
        f"report robot {r.robot_sysid} victim {r.victim_id} seq {item.report_seq}: "
        f"{r.urgency.name} {r.visibility_pct:.0f}% visible {r.state.name} {where} ±{r.sigma_m:.1f} m{note}"
    )
