"""Closer looks: the steps of one look, from leaving the route to resuming it. Pure
decision logic, no I/O (the adapter is companion/looks/run.py; what to look at and
from where: companion/looks/choose.py).

``LookMachine``: idle -> guided (GUIDED asked) -> driving -> looking -> returning
(to where the route was left, the way it came) -> resuming (the interrupted
mission item, then AUTO) -> idle. ``step`` takes what the
autopilot last said (``mavlink_io.guided.AutopilotView``) and returns the commands
to send and the lines to announce. Safety: a look starts only when looks are on,
the link is up, the vehicle is an ArduPilot Rover, armed and in AUTO, and the
budgets allow; during a look, a mode the companion did not ask for ends it at once
and switches looks off (``switched_off``) until the operator switches them on
again; link loss, no progress (``stuck_s``), the look's time budget, or looks
switched off abort it and resume the mission; no candidate is looked at twice. The
time on the route (armed, in AUTO, no look under way) is counted: a look of the
companion's own starts only while the looks so far took at most ``route_share_pct``
of it, so a mission takes about that share longer (one look more at most).
``ask`` is the HQ operator's "look closer at victim N": that victim is the next
look, ahead of the companion's own candidates, under the same rules.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from companion.config import LooksConfig
from companion.looks.choose import (
    LIVE_STATES,
    Candidate,
    DrivenPath,
    Kind,
    PointNE,
    Viewpoint,
    compass,
    settlement,
    viewpoint,
)
from companion.looks.steps import (
    Command,
    Face,
    GoTo,
    LookCounts,
    RequestMissionCurrent,
    Rover,
    Say,
    SetCurrent,
    SetMode,
)
from fusion.registry import Victim
from mavlink_io.guided import (
    MAV_CMD_DO_SET_MODE,
    MAV_RESULT_ACCEPTED,
    ROVER_AUTO,
    ROVER_GUIDED,
    AutopilotView,
    mode_name,
)

_ARRIVED_M = 0.3
_PROGRESS_M = 0.2  # progress that counts for the stuck check
_FACED_RAD = math.radians(15.0)
_RESEND_S = 2.0  # the position target again (UDP may lose it; ArduPilot takes it again)
_RESUME_TRIES = 3
_HEARTBEAT_FRESH_S = 1.5  # a mode command only on a heartbeat this recent
_SEVERITY_NOTICE = 5
_SEVERITY_WARNING = 4
_SEVERITY_CRITICAL = 2
_TURN_MAX_S = 10.0  # facing the candidate takes at most this; then the look starts anyway
_ROUTE_GAP_MAX_S = 1.0  # a longer gap between steps counts this much route time at most


# -- the steps ---------------------------------------------------------------------------


class Phase(Enum):
    IDLE = "idle"
    GUIDED = "requesting GUIDED"
    DRIVING = "driving"
    LOOKING = "looking"
    RETURNING = "returning"
    RESUMING = "resuming AUTO"
    LINK_LOST = "link lost"


@dataclass
class _Request:
    """The operator asked for a closer look at a victim (RESCUE_OPERATOR_ACTION)."""

    track_id: int
    victim_id: int
    waiting_s: float  # since when it waits with no look under way


@dataclass
class _Look:
    candidate: Candidate
    view: Viewpoint
    start: PointNE  # where the rover left its route: it returns there before AUTO
    started_s: float
    phase_s: float
    sent_s: float = -math.inf  # when the phase's last command went
    asked_s: float | None = None  # when MISSION_CURRENT was asked for in GUIDED
    seq: int | None = None  # the mission item to resume
    best_m: float = math.inf
    progress_s: float = 0.0
    faced: bool = False
    tries: int = 0
    outcome: str | None = None  # what it settled, or why it was aborted


Step = tuple[list[Command], list[Say]]


class LookMachine:
    """See the module docstring. ``step`` is called a few times a second."""

    def __init__(self, settings: LooksConfig) -> None:
        self.settings = settings
        self.enabled = settings.enabled
        self.switched_off = False  # the operator took over: off until switched on again
        self.phase = Phase.IDLE
        self.path = DrivenPath()
        self.looked: set[int] = set()  # track IDs
        self.counts = LookCounts()
        self.look: _Look | None = None
        self.last: _Look | None = None  # the last look that ended
        self.request: _Request | None = None  # the operator's victim, ahead of all others
        self.route_s = 0.0  # time on the route: armed, in AUTO, no look under way
        self._stepped_s: float | None = None
        self._said_not_ardupilot = False

    def set_enabled(self, enabled: bool) -> None:
        """RC_LOOK_ON or the config: switching on also ends a previous take-over;
        switching off also drops the operator's request."""
        self.enabled = enabled
        if enabled:
            self.switched_off = False
        else:
            self.request = None

    @property
    def allowed(self) -> bool:
        """Looks are on and no take-over switched them off."""
        return self.enabled and not self.switched_off

    def ask(self, track_id: int, victim_id: int, now_s: float) -> None:
        """The operator asked for a closer look at this victim: it is the next look,
        ahead of the companion's own candidates, under the same safety rules and
        budgets (it may be looked at again). One that cannot start within
        ``look_budget_s`` of waiting (no look under way) is dropped, and said so."""
        self.request = _Request(track_id, victim_id, now_s)

    @property
    def expected_modes(self) -> frozenset[int]:
        """The modes the companion may see while it drives (empty: it does not drive)."""
        if self.phase in (Phase.IDLE, Phase.LINK_LOST):
            return frozenset()
        if self.phase in (Phase.GUIDED, Phase.RESUMING):
            return frozenset({ROVER_AUTO, ROVER_GUIDED})
        return frozenset({ROVER_GUIDED})

    def step(
        self,
        now_s: float,
        rover: Rover,
        ap: AutopilotView,
        found: Sequence[Candidate],
        victims: dict[int, Victim],
    ) -> Step:
        """``found``: this moment's candidates; ``victims``: every track by track ID."""
        if rover.ne is not None and self.phase == Phase.IDLE:
            self.path.add(*rover.ne)
        if self._stepped_s is not None and self.phase == Phase.IDLE and _on_route(ap, now_s):
            self.route_s += min(max(now_s - self._stepped_s, 0.0), _ROUTE_GAP_MAX_S)
        self._stepped_s = now_s
        if self.look is None:
            return self._idle(now_s, rover, ap, found, victims)
        if self.request is not None:  # it waits for this look to end
            self.request.waiting_s = now_s
        return self._active(now_s, rover, ap, self.look, victims)

    # -- starting ----------------------------------------------------------------------

    def _idle(
        self,
        now_s: float,
        rover: Rover,
        ap: AutopilotView,
        found: Sequence[Candidate],
        victims: dict[int, Victim],
    ) -> Step:
        s = self.settings
        if not self.allowed:
            self.request = None
        asked, said = self._asked(now_s, victims)
        if asked is not None:
            found = [asked]  # the operator's victim first, and alone until it goes
        if not (self.allowed and rover.connected and found):
            return [], said
        if ap.heartbeat_s is not None and not ap.ardupilot_rover:
            if self._said_not_ardupilot:
                return [], said
            self._said_not_ardupilot = True
            return [], [*said, Say("closer looks need ArduPilot Rover: not supported here", 4)]
        here = rover.ne
        if (
            here is None
            or not _on_route(ap, now_s)
            or self.counts.spent_s + s.look_s >= s.mission_budget_s
        ):
            return [], said
        if asked is None and self.counts.spent_s > s.route_share_pct / 100.0 * self.route_s:
            return [], said  # the operator's look is theirs to spend; the companion's wait
        avoid = [(v.north_m, v.east_m) for v in victims.values() if v.state in LIVE_STATES]
        for c in found:
            again = c.track_id in self.looked and c is not asked  # the operator may ask again
            if again or math.dist(c.ne, here) > s.max_detour_m:
                continue
            view = viewpoint(c.ne, list(self.path.points), avoid, here, s)
            if view is None:
                continue
            self.looked.add(c.track_id)
            self.request = None
            self.look = _Look(c, view, here, now_s, now_s, sent_s=now_s)
            self.phase = Phase.GUIDED
            self.counts.started += 1
            if c is asked:
                what = f"victim {c.victim_id} (the operator asked)"
            elif c.victim_id == 0:
                what = f"a {c.kind.value}"
            else:
                what = f"a {c.kind.value} (victim {c.victim_id})"
            line = f"looking closer at {what} {compass(here, c.ne)} of here"
            return [SetMode(ROVER_GUIDED)], [*said, Say(line, _SEVERITY_NOTICE)]
        return [], said

    def _asked(
        self, now_s: float, victims: dict[int, Victim]
    ) -> tuple[Candidate | None, list[Say]]:
        """The operator's victim as a candidate (None: no request, or dropped: said why)."""
        r = self.request
        if r is None:
            return None, []
        v = victims.get(r.track_id)
        why = None
        if v is None or v.state not in LIVE_STATES:
            why = "it is no longer tracked" if v is None else f"it is {v.state.name}"
        elif now_s - r.waiting_s > self.settings.look_budget_s:
            why = (
                f"it could not start within {self.settings.look_budget_s:.0f} s (it needs "
                f"the rover armed in AUTO, within {self.settings.max_detour_m:.0f} m, and a "
                "viewpoint beside the path driven)"
            )
        if why is not None:
            self.request = None
            line = f"closer look at victim {r.victim_id} the operator asked for dropped: {why}"
            return None, [Say(line, _SEVERITY_WARNING)]
        assert v is not None
        kind = Kind.ASKED
        c = Candidate(
            v.track_id, r.victim_id, kind, v.north_m, v.east_m, v.state, v.urgency, v.cues
        )
        return c, []

    # -- during a look -----------------------------------------------------------------

    def _active(
        self, now_s: float, rover: Rover, ap: AutopilotView, look: _Look, victims: dict[int, Victim]
    ) -> Step:
        s = self.settings
        if self.phase == Phase.LINK_LOST:
            return self._link_back(now_s, rover, ap, look)
        if not rover.connected:
            self.phase = Phase.LINK_LOST
            return [], [self._aborted(look, "vehicle link lost")]
        heard = ap.heartbeat_s is not None and ap.heartbeat_s >= look.started_s
        if heard and (not ap.armed or ap.mode not in self.expected_modes):
            return self._taken_over(now_s, look, ap)
        if self.phase == Phase.RESUMING:
            return self._resuming(now_s, ap, look)
        if self.phase == Phase.RETURNING:
            return self._returning(now_s, rover, look)
        if not self.enabled:
            return self._abort_and_return(now_s, look, "looks switched off")
        if now_s - look.started_s > s.look_budget_s:
            return self._abort_and_return(now_s, look, "time budget spent")
        if self.phase == Phase.GUIDED:
            return self._guided(now_s, ap, look)
        outcome = settlement(look.candidate, victims.get(look.candidate.track_id))
        if outcome is not None:
            return self._settled(now_s, look, outcome)
        if self.phase == Phase.DRIVING:
            return self._driving(now_s, rover, look)
        return self._looking(now_s, rover, look)

    def _guided(self, now_s: float, ap: AutopilotView, look: _Look) -> Step:
        ack = ap.acks.get(MAV_CMD_DO_SET_MODE)
        acked = ack is not None and ack[1] >= look.sent_s
        if ack is not None and acked and ack[0] != MAV_RESULT_ACCEPTED:
            self._end(now_s)
            return [], [self._aborted(look, "the autopilot refused GUIDED")]
        in_guided = ap.mode == ROVER_GUIDED and (ap.heartbeat_s or -math.inf) >= look.sent_s
        if acked and in_guided:
            # The mission item to resume, asked for now that GUIDED has frozen it.
            if look.asked_s is None or now_s - look.asked_s > self.settings.ack_timeout_s:
                look.asked_s = now_s
                return [RequestMissionCurrent()], []
            if ap.mission_s is not None and ap.mission_s >= look.asked_s and ap.mission_seq:
                look.seq = ap.mission_seq
                self.phase = Phase.DRIVING
                look.phase_s = look.progress_s = look.sent_s = now_s
                return [GoTo(look.view.north_m, look.view.east_m)], []
            return [], []
        if now_s - look.sent_s > self.settings.ack_timeout_s:
            if ap.mode == ROVER_GUIDED:  # the acknowledgement was lost, not the command
                look.sent_s = now_s
                return [SetMode(ROVER_GUIDED)], []
            self._end(now_s)
            return [], [self._aborted(look, "no answer to GUIDED")]
        return [], []

    def _driving(self, now_s: float, rover: Rover, look: _Look) -> Step:
        here = rover.ne
        if here is None:
            return [], []
        d = math.dist(here, look.view.ne)
        if d < look.best_m - _PROGRESS_M:
            look.best_m = d
            look.progress_s = now_s
        if d <= _ARRIVED_M:
            self.phase = Phase.LOOKING
            look.phase_s = look.sent_s = now_s
            return [Face(look.view.yaw_rad)], []
        if now_s - look.progress_s > self.settings.stuck_s:
            return self._abort_and_return(now_s, look, "stuck on the way")
        if now_s - look.sent_s > _RESEND_S:
            look.sent_s = now_s
            return [GoTo(look.view.north_m, look.view.east_m)], []
        return [], []

    def _looking(self, now_s: float, rover: Rover, look: _Look) -> Step:
        if not look.faced:
            yaw = rover.yaw_rad
            facing = yaw is not None and (
                abs(math.remainder(yaw - look.view.yaw_rad, math.tau)) <= _FACED_RAD
            )
            if facing or now_s - look.phase_s > _TURN_MAX_S:
                look.faced = True
                look.phase_s = now_s
            return [], []
        if now_s - look.phase_s >= self.settings.look_s:
            return self._settled(now_s, look, "still unsettled")
        return [], []

    # -- ending ------------------------------------------------------------------------

    def _settled(self, now_s: float, look: _Look, outcome: str) -> Step:
        look.outcome = outcome
        key = outcome.split(" to ")[0]
        self.counts.settled[key] = self.counts.settled.get(key, 0) + 1
        cmds, _ = self._back(now_s, look)
        line = f"closer look: the {look.candidate.kind.value} is {outcome}; resuming the mission"
        return cmds, [Say(line, _SEVERITY_NOTICE)]

    def _aborted(self, look: _Look, reason: str) -> Say:
        look.outcome = f"aborted: {reason}"
        self.counts.aborted[reason] = self.counts.aborted.get(reason, 0) + 1
        return Say(f"closer look aborted: {reason}", _SEVERITY_WARNING)

    def _abort_and_return(self, now_s: float, look: _Look, reason: str) -> Step:
        line = self._aborted(look, reason)
        # Still asking for GUIDED: the rover has not left its route, AUTO at once.
        back = self._resume if self.phase == Phase.GUIDED else self._back
        cmds, _ = back(now_s, look)
        return cmds, [Say(f"{line.text}; resuming the mission", line.severity)]

    def _back(self, now_s: float, look: _Look) -> Step:
        """Drive back to where the route was left, the way the rover came (known free),
        so that AUTO goes on from there along the mission's own leg."""
        self.phase = Phase.RETURNING
        look.best_m = math.inf
        look.phase_s = look.progress_s = look.sent_s = now_s
        return [GoTo(*look.start)], []

    def _returning(self, now_s: float, rover: Rover, look: _Look) -> Step:
        here = rover.ne
        late = now_s - look.started_s > self.settings.look_budget_s + self.settings.stuck_s
        if here is None:
            return self._resume(now_s, look) if late else ([], [])
        d = math.dist(here, look.start)
        if d < look.best_m - _PROGRESS_M:
            look.best_m = d
            look.progress_s = now_s
        if d <= _ARRIVED_M or late or now_s - look.progress_s > self.settings.stuck_s:
            return self._resume(now_s, look)  # back, or AUTO from here rather than wait
        if now_s - look.sent_s > _RESEND_S:
            look.sent_s = now_s
            return [GoTo(*look.start)], []
        return [], []

    def _resume(self, now_s: float, look: _Look) -> Step:
        self.phase = Phase.RESUMING
        look.phase_s = look.sent_s = now_s
        look.tries += 1
        cmds: list[Command] = []
        if look.seq is not None:
            cmds.append(SetCurrent(look.seq))
        cmds.append(SetMode(ROVER_AUTO))
        return cmds, []

    def _resuming(self, now_s: float, ap: AutopilotView, look: _Look) -> Step:
        ack = ap.acks.get(MAV_CMD_DO_SET_MODE)
        auto_since = ap.mode == ROVER_AUTO and (ap.heartbeat_s or -math.inf) >= look.sent_s
        if auto_since and ack is not None and ack[1] >= look.sent_s:
            self._end(now_s)
            return [], []
        if now_s - look.sent_s <= self.settings.ack_timeout_s:
            return [], []
        if auto_since:  # the acknowledgement was lost, not the command
            self._end(now_s)
            return [], []
        if look.tries >= _RESUME_TRIES:
            self.switched_off = True
            self._end(now_s)
            line = "could not resume the mission after a closer look: the operator must"
            return [], [Say(line, _SEVERITY_CRITICAL)]
        if ap.mode == ROVER_GUIDED and _fresh(ap, now_s):
            return self._resume(now_s, look)
        return [], []

    def _link_back(self, now_s: float, rover: Rover, ap: AutopilotView, look: _Look) -> Step:
        if not rover.connected or not _fresh(ap, now_s):
            return [], []
        if ap.mode == ROVER_GUIDED and ap.armed:  # still ours: give the mission back
            cmds, _ = self._back(now_s, look)
            return cmds, [Say("vehicle link back: resuming the mission", _SEVERITY_NOTICE)]
        if ap.mode == ROVER_AUTO:
            self._end(now_s)
            return [], []
        return self._taken_over(now_s, look, ap)

    def _taken_over(self, now_s: float, look: _Look, ap: AutopilotView) -> Step:
        reason = (
            "vehicle disarmed" if not ap.armed else f"operator switched to {mode_name(ap.mode)}"
        )
        self.switched_off = True
        line = self._aborted(look, reason)
        self._end(now_s)
        return [], [Say(f"{line.text}; no more looks until RC_LOOK_ON is set again", 4)]

    def operator_took_over(self) -> None:
        """A heartbeat showed a mode the companion did not ask for (the vehicle link's
        thread saw it first): no look starts again until switched on."""
        self.switched_off = True
        self.request = None

    def _end(self, now_s: float) -> None:
        if self.look is not None:
            self.counts.spent_s += now_s - self.look.started_s
        self.last = self.look
        self.look = None
        self.phase = Phase.IDLE


def _on_route(ap: AutopilotView, now_s: float) -> bool:
    return ap.armed and ap.mode == ROVER_AUTO and _fresh(ap, now_s)


def _fresh(ap: AutopilotView, now_s: float) -> bool:
    return ap.heartbeat_s is not None and now_s - ap.heartbeat_s <= _HEARTBEAT_FRESH_S
