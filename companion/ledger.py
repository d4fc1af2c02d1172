"""The saved state while the service runs: every commit of the processing thread.

The processing thread commits a frame's consequences (tracker, what was reported,
the new reports and their outbox entries, the new evidence pictures) in one SQLite
transaction; the outbox schedules the reports only after that commit, so the
reporter never sends what is not on disk, and after a crash nothing
unacknowledged is lost. Operator actions and a newly known EKF origin commit the
same way, and the service's stop commits once more (after joining the threads).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from types import ModuleType

from companion.announcements import Announcer
from companion.pictures import Candidate, PictureChooser, PictureSender
from companion.reporting import Decision, ReportPolicy
from companion.store import Store, StoredPicture, StoreError
from fusion.tracker import VictimTracker
from mavlink_io import convert
from mavlink_io.reliable import Outbox
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)


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
        try:
            with self._store.transaction():
                for d in self._unsaved.values():
                    seq += 1
                    report = d.victim.to_report(sysid, self.floor_down_m, origin)
                    msg = convert.victim_report_to_msg(
                        report, seq, d.flags, now, d.victim.merged_into, self._m
                    )
                    self._outbox.stage(msg)  # in this transaction; scheduled after it
                for c in candidates:
                    seq += 1
                    p = StoredPicture(c.victim_id, seq, c.score, c.taken_unix_s, c.jpeg)
                    self._store.put_picture(p)
                    pictures.append((c, p))
                self._store.set("tracker", self._tracker.snapshot())
                self._store.set("reported", self._policy.snapshot())
                self._store.set("report_seq", seq)
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
        saved = len(self._unsaved)
        self._unsaved.clear()
        self._outbox.publish()  # committed: now the reporter may send them
        for c, p in pictures:
            self._chooser.keep(c)
            self._picture_sender.offer(p)
            log.info(
                "picture %d of victim %d: %d bytes, score %.3f",
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
