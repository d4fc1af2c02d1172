"""The operator's newest decision is what the robot ends with, and what the HQ shows.

Both sides are their real parts: the HQ's registry (actions numbered, answers
recorded, the state the console shows: hq.view) on a SQLite file, and the robot's
saved state (companion.storage.recovery), ledger, tracker and ``Ground`` on another. The radio
between them is modelled: each transmission of an action or of its acknowledgement
can be lost, the HQ resends what is unanswered in any order, and either side can
restart. The vehicle and the radio are absent hardware: the vehicle is an object
with no EKF origin, the radio a list.
"""

from __future__ import annotations

import queue
import threading
import time
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.config import PicturesConfig
from companion.reporting.announcements import Announcer
from companion.reporting.pictures import resume
from companion.reporting.policy import ReportPolicy
from companion.service.ground import Ground
from companion.storage.ledger import Ledger
from companion.storage.recovery import LoadedState, load_state
from fusion.params import TrackerParams
from fusion.types import Observation, TrackState
from hq import wire
from hq.records import OperatorAction
from hq.registry import Registry
from hq.view import hq_victims
from mavlink_io import convert, dialect
from mavlink_io.reliable import Outbox

ROBOT = 3
HQ_SYSID = 250
ACCEPTED, DUPLICATE, REJECTED = 0, 1, 2
DECISIONS = (OperatorAction.RESCUED, OperatorAction.FALSE_ALARM, OperatorAction.CONFIRMED)
M = dialect.load()


class _NoAutopilot:
    origin = None


class _Radio:
    """What the robot sends to the ground: the acknowledgements are kept."""

    def __init__(self) -> None:
        self.acks: list[Any] = []

    def send_dialect(self, msg: Any) -> None:
        if msg.get_type() == "RESCUE_ACK":
            self.acks.append(msg)


class Robot:
    """The companion's state directory, its tracker and the ground requests' handler."""

    def __init__(self, state_dir: Path) -> None:
        self.state_dir = state_dir
        self.radio = _Radio()
        self.start()

    def start(self) -> None:
        self.policy = ReportPolicy(2.0)
        state: LoadedState = load_state(self.state_dir, TrackerParams(), self.policy)
        self.store, self.tracker = state.store, state.tracker
        self.actions: queue.Queue[Any] = queue.Queue()
        outbox = Outbox(lambda _msg: None, store=self.store)
        chooser, sender = resume(PicturesConfig(), self.store, lambda _c: None, signed=False)
        wake = threading.Event()
        self.ledger = Ledger(
            store=self.store,
            tracker=self.tracker,
            policy=self.policy,
            outbox=outbox,
            chooser=chooser,
            picture_sender=sender,
            announcer=Announcer(
                enabled=False, announce_severity=4, robot_sysid=lambda: ROBOT, wake=wake
            ),
            vehicle=_NoAutopilot(),  # type: ignore[arg-type]
            robot_sysid=lambda: ROBOT,
            report_seq=state.report_seq,
            floor_down_m=0.0,
            wake_reporter=wake,
            m=M,
        )
        self.ground = Ground(
            actions=self.actions,
            requests=queue.Queue(),
            tracker=self.tracker,
            policy=self.policy,
            ledger=self.ledger,
            param_server=None,  # type: ignore[arg-type]
            video=None,  # type: ignore[arg-type]
            vehicle=None,  # type: ignore[arg-type]
            links=self.radio,  # type: ignore[arg-type]
            announcer=None,  # type: ignore[arg-type]
            m=M,
        )

    def restart(self) -> None:
        self.store.close()
        self.start()

    def confirm_a_victim(self) -> Any:
        """See one person until the tracker confirms them; their first report."""
        now = time.time()
        cov = ((0.04, 0.0), (0.0, 0.04))
        for k in range(6):
            t = now + k * 0.1
            self.tracker.update(
                [Observation(t, 5.0, 2.0, cov, 40.0, 1.0, 2.0)], t, lambda n, e: True
            )
        decisions = self.policy.decide([], self.tracker.victims(), now)
        self.ledger.commit(decisions)
        (victim,) = self.tracker.victims()
        report = victim.to_report(ROBOT, 0.0, None)
        return convert.victim_report_to_msg(report, self.ledger.report_seq, 0, now, 0, M)

    def receive(self, msg: Any) -> Any:
        """One RESCUE_OPERATOR_ACTION arrives; the acknowledgement it is answered with."""
        self.actions.put(msg)
        self.ground.handle_actions()
        return self.radio.acks.pop()

    def state(self, victim_id: int) -> TrackState:
        return self.tracker.victim(victim_id).state


class Hq:
    """The HQ's registry and the actions it resends until a robot answers."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.registry = Registry(path)

    def restart(self) -> None:
        self.registry.close()
        self.registry = Registry(self.path)

    def decide(self, victim_id: int, action: OperatorAction) -> int:
        return self.registry.add_action(ROBOT, victim_id, action)

    def pending(self) -> list[Any]:
        return [
            M.MAVLink_rescue_operator_action_message(
                ROBOT, 191, a.victim_id, a.action_seq, a.action.value
            )
            for a in self.registry.actions(pending_only=True)
        ]

    def answered(self, ack: Any) -> None:
        self.registry.ack_action(int(ack.seq), time.time(), int(ack.result))

    def state(self) -> TrackState:
        (victim,) = hq_victims(self.registry)
        return victim.state


def _set_up(tmp: Path) -> tuple[Hq, Robot, int]:
    hq, robot = Hq(tmp / "hq.sqlite"), Robot(tmp / "robot")
    first = robot.confirm_a_victim()
    hq.registry.store_reports([wire.incoming_report(_as_received(first), time.time())])
    return hq, robot, int(first.victim_id)


def _as_received(msg: Any) -> Any:
    """The message as the HQ decodes it from the radio (source system and component set)."""
    codec = M.MAVLink(None, ROBOT, 191)
    return codec.parse_buffer(msg.pack(codec))[0]


def test_a_lost_and_resent_rescued_does_not_undo_the_operators_confirmed(tmp_path: Path) -> None:
    """The operator mis-clicks "rescued", then clicks "confirmed"; the radio loses the
    first "rescued", which the HQ resends after "confirmed" arrived. Then the robot
    restarts and the HQ resends "rescued" once more (its answer was lost)."""
    hq, robot, victim = _set_up(tmp_path)
    try:
        rescued = hq.decide(victim, OperatorAction.RESCUED)
        confirmed = hq.decide(victim, OperatorAction.CONFIRMED)
        by_seq = {int(m.action_seq): m for m in hq.pending()}
        hq.answered(robot.receive(by_seq[confirmed]))  # "rescued" was lost on the radio
        late = robot.receive(by_seq[rescued])
        assert (late.seq, late.result) == (rescued, REJECTED)  # answered: not applied
        assert robot.state(victim) == TrackState.CONFIRMED
        robot.restart()
        again = robot.receive(by_seq[rescued])  # its answer lost: resent after a restart
        assert again.result == REJECTED
        assert robot.receive(by_seq[confirmed]).result == DUPLICATE
        hq.answered(late)
        assert hq.pending() == []
        assert robot.state(victim) == hq.state() == TrackState.CONFIRMED
    finally:
        robot.store.close()
        hq.registry.close()


# One step of the night: the operator decides, the HQ sends one pending action (lost
# or not, its answer lost or not), or a side restarts.
_step = st.one_of(
    st.tuples(st.just("decide"), st.sampled_from(DECISIONS)),
    st.tuples(st.just("send"), st.integers(0, 7), st.booleans(), st.booleans()),
    st.tuples(st.just("restart robot")),
    st.tuples(st.just("restart hq")),
)


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    steps=st.lists(_step, min_size=1, max_size=14), drain_order=st.randoms(use_true_random=False)
)
def test_hq_and_robot_end_in_the_same_state_whatever_the_radio_does(
    tmp_path_factory: Any, steps: list[tuple[Any, ...]], drain_order: Any
) -> None:
    hq, robot, victim = _set_up(tmp_path_factory.mktemp("night"))
    try:
        for step in steps:
            if step[0] == "decide":
                hq.decide(victim, step[1])
            elif step[0] == "send":
                pending = hq.pending()
                if not pending:
                    continue
                _, pick, lost, answer_lost = step
                if lost:
                    continue
                ack = robot.receive(pending[pick % len(pending)])
                if not answer_lost:
                    hq.answered(ack)
            elif step[0] == "restart robot":
                robot.restart()
            else:
                hq.restart()
        # The radio clears: the HQ resends what is unanswered (in any order) until answered.
        while pending := hq.pending():
            hq.answered(robot.receive(drain_order.choice(pending)))
        assert robot.state(victim) == hq.state()
        decided = [a for a in hq.registry.actions() if a.action in DECISIONS]
        if decided:  # what the operator clicked last is what both hold
            newest = max(decided, key=lambda a: a.action_seq)
            assert hq.state().name == newest.action.name
    finally:
        robot.store.close()
        hq.registry.close()
