"""Operator actions to the robots: sent until acknowledged, the answers recorded.

Actions are written to the registry's action table by `rescue-hq mark`, `look`,
`looks` or the console (another process or thread): decisions about a victim, a
closer look at one, and closer looks off or on for a whole robot (victim_id 0); ``refresh`` hands new ones to the outbox,
which resends each with backoff until its robot answers. An action goes the way
its robot last spoke to the HQ, and waits until the robot is heard at all.
"""

from __future__ import annotations

import logging
import sqlite3
import time
from collections.abc import Callable
from typing import Any

from hq.counters import Counters
from hq.records import ACK_RESULT_ACCEPTED, ACK_RESULT_DUPLICATE, ACK_RESULT_REJECTED
from hq.registry import Registry
from hq.registry_file import RegistryError
from hq.sending import Route, Sender
from mavlink_io.dialect import RESCUE_OPERATOR_ACTION_ID
from mavlink_io.reliable import Outbox

log = logging.getLogger(__name__)

COMPANION_COMPONENT_ID = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: where robots' reports come from
_ACTION_FIRST_RETRY_S = 0.5
_ACTION_MAX_RETRY_S = 4.0


class ActionSender:
    """The pending operator actions, resent until answered. The main thread."""

    def __init__(
        self,
        registry: Registry,
        sender: Sender,
        hq_sysid: int,
        counters: Counters,
        event: Callable[..., None],
        changed: Callable[[], None],
    ) -> None:
        self.registry = registry
        self._sender = sender
        self._m = sender.m
        self._hq_sysid = hq_sysid
        self.counters = counters
        self._event = event
        self._changed = changed  # what the table and the exports show has changed
        self._routes: dict[int, Route] = {}  # robot sysid -> the way it last spoke
        self._outbox = Outbox(
            self._send, initial_s=_ACTION_FIRST_RETRY_S, max_s=_ACTION_MAX_RETRY_S
        )
        self._queued: set[int] = set()  # action_seqs handed to the outbox
        self._db_version = -1

    def heard(self, sysid: int, route: Route) -> None:
        """A robot spoke (a dialect message): its actions go this way from now on."""
        if sysid not in self._routes and self._outbox.pending_count:
            self._outbox.resend_all_now()  # actions waiting for this robot to be heard
        self._routes[sysid] = route

    def poll(self) -> None:
        """Send what is due."""
        self._outbox.poll()

    def seconds_until_due(self) -> float | None:
        return self._outbox.seconds_until_due()

    def refresh(self) -> None:
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
        self._changed()
        for action in pending:
            if action.action_seq in self._queued:
                continue
            self._queued.add(action.action_seq)
            about = "" if action.action.whole_robot else f" victim {action.victim_id}"
            self._event(
                f"action {action.action_seq}: {action.action.name} robot "
                f"{action.robot_sysid}{about} (sending until acknowledged)"
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

    def _send(self, msg: Any) -> None:
        """The outbox's sender: to the robot's last route, or nowhere until it is heard."""
        route = self._routes.get(msg.target_system)
        if route is None:
            return
        self._sender.send(msg, route)
        self.counters.actions_sent += 1
        try:
            self.registry.note_action_sent(int(msg.action_seq), time.time())
        except RegistryError as exc:
            log.debug("send count of action %d not stored: %s", msg.action_seq, exc)

    def on_ack(self, msg: Any) -> None:
        """A RESCUE_ACK: the answer to one of our actions is recorded and the action stops."""
        if msg.acked_msgid != RESCUE_OPERATOR_ACTION_ID or msg.target_system != self._hq_sysid:
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
        self._changed()
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
                "(the robot does not know that victim, cannot do it, or already applied a newer decision for it)",
                level=logging.WARNING,
            )
