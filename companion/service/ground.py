"""Requests from the ground, answered on the processing thread, which owns the
tracker, the policy, the detector and the store.

The link threads only queue what they hear (companion/service/run.py routes it):
operator actions from the HQ (RESCUE_OPERATOR_ACTION: applied and committed with
the reports they cause, then acknowledged; a duplicate is acknowledged again,
never applied twice; one that cannot be applied is acknowledged REJECTED), and
a decision about a victim (rescued, false alarm, confirmed) only when it is newer,
by the HQ's action_seq, than the last one applied to that person (the ledger keeps
that number with the tracker, across restarts): an older one that arrives late (a
lost frame resent) is acknowledged REJECTED, not applied, so the HQ, which shows
the newest action the robot did not refuse, ends where the robot is; the closer
looks' actions (docs/LOOKS.md): "no more looks" and "looks on" (victim_id 0) set
RC_LOOK_ON as QGC would, "look closer at victim N" makes it the next look, or, with
looks off, only says so (REJECTED, as for a victim unknown or resolved); and
PARAM_* and COMMAND_LONG: the parameter protocol of the companion's settings
(companion/service/params.py over mavlink_io/params.py) and the camera requests of QGC
(companion/service/livevideo.py).
"""

from __future__ import annotations

import logging
import queue
import time
from types import ModuleType

from companion.looks.choose import LIVE_STATES
from companion.looks.run import Looks
from companion.reporting.announcements import Announcer
from companion.reporting.policy import Decision, ReportPolicy
from companion.service.links import Links
from companion.service.livevideo import LiveVideo
from companion.storage.ledger import Ledger
from fusion.tracker import VictimTracker
from fusion.types import TrackState
from mavlink_io import dialect, statustext
from mavlink_io.codec import MavMessage
from mavlink_io.params import MAV_PARAM_TYPE_REAL32, ParamServer
from mavlink_io.reliable import Deduplicator
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)

_LOOK_PARAM = "RC_LOOK_ON"  # companion/service/params.py: the operator's switch of the looks


class Ground:
    def __init__(
        self,
        *,
        actions: queue.Queue[MavMessage],
        requests: queue.Queue[MavMessage],
        tracker: VictimTracker,
        policy: ReportPolicy,
        ledger: Ledger,
        param_server: ParamServer,
        video: LiveVideo,
        vehicle: VehicleLink,
        links: Links,
        announcer: Announcer,
        m: ModuleType,
        looks: Looks | None = None,
    ) -> None:
        self._actions = actions
        self._requests = requests
        self._tracker = tracker
        self._policy = policy
        self._ledger = ledger
        self._param_server = param_server
        self._video = video
        self._vehicle = vehicle
        self._links = links
        self._announcer = announcer
        self._m = m
        self.dedupe = Deduplicator()
        self._states = {
            m.RESCUE_OPERATOR_ACTION_RESCUED: TrackState.RESCUED,
            m.RESCUE_OPERATOR_ACTION_FALSE_ALARM: TrackState.FALSE_ALARM,
            m.RESCUE_OPERATOR_ACTION_CONFIRMED: TrackState.CONFIRMED,
        }
        self._looks = looks
        self._look_actions = {
            m.RESCUE_OPERATOR_ACTION_LOOK_CLOSER,
            m.RESCUE_OPERATOR_ACTION_LOOKS_OFF,
            m.RESCUE_OPERATOR_ACTION_LOOKS_ON,
        }

    def handle_actions(self) -> None:
        m = self._m
        while True:
            try:
                msg = self._actions.get_nowait()
            except queue.Empty:
                return
            result = m.RESCUE_ACK_RESULT_ACCEPTED
            older = self._superseded(msg)
            if older is not None:
                result = older
            elif self.dedupe.check(msg):
                result = m.RESCUE_ACK_RESULT_DUPLICATE
            elif msg.action in self._look_actions:
                if not self._look_action(msg):
                    result = m.RESCUE_ACK_RESULT_REJECTED
            else:
                decisions = self._apply_action(msg)
                if decisions is None:
                    result = m.RESCUE_ACK_RESULT_REJECTED
                else:
                    self._ledger.commit(decisions)
            ack = m.MAVLink_rescue_ack_message(
                msg.get_srcSystem(),
                msg.get_srcComponent(),
                dialect.RESCUE_OPERATOR_ACTION_ID,
                msg.action_seq,
                result,
            )
            self._links.send_dialect(ack)

    def _superseded(self, msg: MavMessage) -> int | None:
        """The answer to a decision about a victim that is not newer (by the HQ's
        action_seq) than the one applied last: DUPLICATE for that very action,
        REJECTED (not applied) for an older one; None for one to apply."""
        m = self._m
        if msg.action not in self._states:
            return None
        try:
            victim = self._tracker.resolve(msg.victim_id)
        except KeyError:
            return None  # _apply_action says so
        last = self._ledger.applied_action(victim)
        if last is None or msg.action_seq > last:
            return None
        if msg.action_seq == last:
            return int(m.RESCUE_ACK_RESULT_DUPLICATE)
        log.info(
            "operator action %d on victim %d not applied: action %d, newer, was",
            msg.action_seq,
            msg.victim_id,
            last,
        )
        return int(m.RESCUE_ACK_RESULT_REJECTED)

    def _apply_action(self, msg: MavMessage) -> list[Decision] | None:
        """The reports an operator action causes; None if it cannot be applied."""
        m = self._m
        now = time.time()
        if msg.action == m.RESCUE_OPERATOR_ACTION_RESEND:
            wanted = [v for v in self._tracker.victims() if msg.victim_id in (0, v.victim_id)]
            return self._policy.requested(wanted, now)
        state = self._states.get(msg.action)
        if state is None:
            log.warning("operator action %d: unknown action %d", msg.action_seq, msg.action)
            return None
        try:
            event = self._tracker.mark(msg.victim_id, state, now)
        except (KeyError, ValueError) as exc:
            log.warning("operator action %d: %s", msg.action_seq, exc)
            return None
        self._ledger.action_applied(event.victim.victim_id, msg.action_seq)
        log.info("operator marked victim %d %s", msg.victim_id, state.name)
        return self._policy.decide([event], self._tracker.victims(), now)

    def _look_action(self, msg: MavMessage) -> bool:
        """The operator's closer-look actions; whether applied. "No more looks" and
        "looks on" are RC_LOOK_ON set to 0 or 1, through the parameter protocol as
        QGC's PARAM_SET goes (validated, saved, applied: a look under way is aborted
        and the mission resumed), and its PARAM_VALUE goes out so QGC shows it. "Look
        closer at victim N" makes that victim the next look when looks are on."""
        m = self._m
        if msg.action == m.RESCUE_OPERATOR_ACTION_LOOK_CLOSER:
            return self._look_closer(msg)
        on = msg.action == m.RESCUE_OPERATOR_ACTION_LOOKS_ON
        if msg.victim_id != 0:
            log.warning(
                "operator action %d: looks %s is for the whole robot (victim 0), not victim %d",
                msg.action_seq,
                "on" if on else "off",
                msg.victim_id,
            )
            return False
        server = self._param_server
        handled = server.handle(
            m.MAVLink_param_set_message(
                self._vehicle.sysid,
                server.component_id,
                _LOOK_PARAM.encode("ascii"),
                1.0 if on else 0.0,
                MAV_PARAM_TYPE_REAL32,
            )
        )
        assert handled is not None  # a PARAM_SET addressed to our component
        for reply in handled.replies:
            self._vehicle.send(reply)
        if handled.refused:  # not expected: 0 and 1 are RC_LOOK_ON's values
            self._announcer.announce(handled.refused, statustext.MAV_SEVERITY_WARNING)
            return False
        log.info("operator action %d: closer looks %s", msg.action_seq, "on" if on else "off")
        return True

    def _look_closer(self, msg: MavMessage) -> bool:
        if self._looks is None:
            log.warning("operator action %d: closer looks are not run here", msg.action_seq)
            return False
        try:
            victim = self._tracker.victim(self._tracker.resolve(msg.victim_id))
        except KeyError as exc:
            log.warning("operator action %d: %s", msg.action_seq, exc.args[0])
            return False
        if victim.state not in LIVE_STATES:
            self._announcer.announce(
                f"no closer look at victim {victim.victim_id}: it is {victim.state.name}",
                statustext.MAV_SEVERITY_WARNING,
            )
            return False
        return self._looks.ask(victim)

    def handle_requests(self) -> None:
        """Answer parameter and camera requests (a setting changed here is applied
        here, on the processing thread)."""
        while True:
            try:
                msg = self._requests.get_nowait()
            except queue.Empty:
                return
            self._video.handle(msg)
            handled = self._param_server.handle(msg)
            if handled is None:
                continue
            for reply in handled.replies:
                self._vehicle.send(reply)
            if handled.refused:
                self._announcer.announce(handled.refused, statustext.MAV_SEVERITY_WARNING)
