"""The saved state while the service runs: every commit of the processing thread.

The processing thread commits a frame's consequences (tracker, what was reported,
the new reports and their outbox entries, the new evidence pictures) in one SQLite
transaction; the outbox schedules the reports only after that commit, so the
reporter never sends what is not on disk, and after a crash nothing
unacknowledged is lost. Operator actions and a newly known EKF origin commit the
same way, and the service's stop commits once more (after joining the threads).
A commit that gives out report sequence numbers or picture IDs, or records an
applied operator action, is durable (synchronous=FULL): a power cut cannot undo
what the HQ may have heard. The ledger also keeps the newest operator action
applied to each victim (by the HQ's action_seq), saved with the tracker, so an
older action that arrives late is never applied over a newer one
(companion/service/ground.py), across restarts too. The coverage grid (where the robot has
looked, companion/coverage.py) is saved in the same commits, when it changed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

from companion.coverage import SharedGrid
from companion.reporting.announcements import Announcer
from companion.reporting.pictures import Candidate, PictureChooser, PictureSender
from companion.reporting.policy import Decision, ReportPolicy
from companion.storage.store import Store, StoredPicture, StoreError
from fusion.coverage import CoverageError
from fusion.tracker import VictimTracker
from mavlink_io import convert
from mavlink_io.reliable import Outbox
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)

APPLIED_ACTIONS_KEY = "applied_actions"  # {victim ID: action_seq of the newest applied}
COVERAGE_KEY = "coverage"  # fusion.coverage snapshot: where the robot has looked
_MAX_ACTION_SEQ = 0xFFFFFFFF  # RESCUE_OPERATOR_ACTION.action_seq is a uint32


class Ledger:
    """Owned by the processing thread (the service's stop uses it after the join).

    ``report_seq`` is the last report sequence number saved; ``floor_down_m`` the
    floor's depth (NED down, m) that reports give victims, which the processing
    thread moves with the vehicle's pose.
    """

    def __init__(
        self,
        *,
        store: Store,
        tracker: VictimTracker,
        policy: ReportPolicy,
        outbox: Outbox,
        chooser: PictureChooser,
        picture_sender: PictureSender,
        announcer: Announcer,
        vehicle: VehicleLink,
        robot_sysid: Callable[[], int],
        report_seq: int,
        floor_down_m: float,
        wake_reporter: threading.Event,
        m: ModuleType,
    ) -> None:
        self._store = store
        self._tracker = tracker
        self._policy = policy
        self._outbox = outbox
        self._chooser = chooser
        self._picture_sender = picture_sender
        self._announcer = announcer
        self._vehicle = vehicle
        self._robot_sysid = robot_sysid
        self.report_seq = report_seq
        self.floor_down_m = floor_down_m
        self._wake_reporter = wake_reporter
        self._m = m
        self._unsaved: dict[int, Decision] = {}  # by victim: reports not yet on disk
        self._store_failing = False
        self.applied_actions = _applied_actions(store)
        self._actions_unsaved = False
        self.coverage = load_coverage(store)  # the processing thread adds its looks
        self._coverage_saved = self.coverage.version

    def applied_action(self, victim_id: int) -> int | None:
        """The action_seq of the newest operator action applied to this victim."""
        return self.applied_actions.get(victim_id)

    def action_applied(self, victim_id: int, action_seq: int) -> None:
        """Record an applied operator action; saved (durably) by the next commit."""
        self.applied_actions[victim_id] = action_seq
        self._actions_unsaved = True

    @property
    def unsaved_victims(self) -> list[int]:
        """The victims whose newest report waits in memory for a writable disk."""
        return sorted(self._unsaved)

    def commit(self, decisions: list[Decision], candidates: Sequence[Candidate] = ()) -> None:
        """Persist the tracker, the policy, the new reports and the new evidence
        pictures in one transaction. A picture takes its number from the report
        sequence (never reused, increasing); one not saved is forgotten (a later
        frame gives another).

        When the database cannot be written (a full disk: recorded frames share it),
        the reports wait in memory (one per victim, the newest, its flags merged) and
        go into the next commit, the periodic save included; nothing unsaved is sent.
        The failure and the recovery are each said once, loudly. People hear about a
        victim at once, whatever the disk.
        """
        for d in decisions:
            kept = self._unsaved.get(d.victim.victim_id)
            self._unsaved[d.victim.victim_id] = (
                d if kept is None else Decision(d.victim, kept.flags | d.flags, False)
            )
        sysid = self._robot_sysid()
        origin = self._vehicle.origin
        now = time.time()
        for d in decisions:
            self._announcer.victim(d, d.victim.to_report(sysid, self.floor_down_m, origin))
        seq = self.report_seq
        pictures: list[tuple[Candidate, StoredPicture]] = []
        # Durable when it gives out sequence numbers (reports, pictures) or records an
        # operator action: the HQ hears of them, so a power cut must not undo them.
        durable = bool(self._unsaved or candidates or self._actions_unsaved)
        try:
            with self._store.transaction(durable=durable):
                for d in self._unsaved.values():
                    seq += 1
                    report = d.victim.to_report(sysid, self.floor_down_m, origin)
                    msg = convert.victim_report_to_msg(
                        report, seq, d.flags, now, d.victim.merged_into, self._m
                    )
                    self._outbox.stage(msg)  # in this transaction; scheduled after it
                for c in candidates:
                    seq += 1
                    p = StoredPicture(
                        c.victim_id, seq, c.score, c.taken_unix_s, c.jpeg, kind=c.kind
                    )
                    self._store.put_picture(p)
                    pictures.append((c, p))
                self._store.set("tracker", self._tracker.snapshot())
                self._store.set("reported", self._policy.snapshot())
                self._store.set("report_seq", seq)
                if self._actions_unsaved:
                    self._store.set(
                        APPLIED_ACTIONS_KEY, {str(v): a for v, a in self.applied_actions.items()}
                    )
                coverage_version = self.coverage.version
                if coverage_version != self._coverage_saved:  # saved only when it changed
                    self._store.set(COVERAGE_KEY, self.coverage.snapshot())
        except StoreError as exc:
            self._outbox.discard()
            if not self._store_failing:
                self._store_failing = True
                log.error(
                    "cannot save: %s. The disk may be full; victims and %d reports are kept "
                    "in memory and saved (then sent) when it can be written again",
                    exc,
                    len(self._unsaved),
                )
                self._announcer.announce("Rescue companion: cannot save state, disk full?", 2)
            return
        except BaseException:
            self._outbox.discard()
            raise
        self.report_seq = seq
        self._actions_unsaved = False
        self._coverage_saved = coverage_version
        saved = len(self._unsaved)
        self._unsaved.clear()
        self._outbox.publish()  # committed: now the reporter may send them
        for c, p in pictures:
            self._chooser.keep(c)
            self._picture_sender.offer(p)
            log.info(
                "%s picture %d of victim %d: %d bytes, score %.3f",
                p.kind,
                p.picture_id,
                p.victim_id,
                len(p.jpeg),
                p.score,
            )
        if self._store_failing:
            self._store_failing = False
            log.warning("the state database can be written again; %d kept reports saved", saved)
            self._announcer.announce("Rescue companion: state saved again", 5)
        self._wake_reporter.set()


def _applied_actions(store: Store) -> dict[int, int]:
    """The newest operator action applied to each victim, as saved; an unusable value
    (a damaged or hand-edited file) is said and left out (its victim then takes the
    next action it is sent, as before this record existed)."""
    saved: Any = store.get(APPLIED_ACTIONS_KEY)
    if saved is None:
        return {}
    if not isinstance(saved, dict):
        log.warning("%s: saved %s is not a table: ignored", store.path, APPLIED_ACTIONS_KEY)
        return {}
    out: dict[int, int] = {}
    for key, seq in saved.items():
        if (
            isinstance(key, str)
            and key.isdigit()
            and isinstance(seq, int)
            and not isinstance(seq, bool)
            and 0 <= seq <= _MAX_ACTION_SEQ
        ):
            out[int(key)] = seq
        else:
            log.warning(
                "%s: saved %s entry %r: %r unusable: ignored",
                store.path,
                APPLIED_ACTIONS_KEY,
                str(key)[:20],
                str(seq)[:20],
            )
    return out


def load_coverage(store: Store) -> SharedGrid:
    """The coverage grid as saved (companion/coverage.py adds to it), or an empty one;
    a saved grid that cannot be used (a damaged or hand-edited file) is said in one
    line and the mission's map starts again empty: the victims are kept regardless."""
    try:
        saved: Any = store.get(COVERAGE_KEY)
        if saved is None:
            return SharedGrid()
        grid = SharedGrid.restore(saved)
    except (CoverageError, StoreError) as exc:
        log.warning(
            "%s: saved %s unusable, the map starts empty: %s", store.path, COVERAGE_KEY, exc
        )
        return SharedGrid()
    assert isinstance(grid, SharedGrid)
    log.info(
        "coverage restored: %d looks, %.0f m2 looked at",
        grid.looks,
        grid.summary().looked_at_m2,
    )
    return grid
