"""The reporter thread, the one owner of the outbox and of the picture sender.

Each round it applies the acknowledgements the link threads queued (a SQLite write:
reports acknowledged, pictures delivered; the link reader threads never wait for
the database), sends what the outbox has due (first sends and resends with
backoff), then, only when no report is due, picture chunks within ``[pictures]
rate_bytes_s``, then, when no picture chunk could go either, the searched-area
map's pieces within ``[coverage] rate_bytes_s`` (companion/reporting/coverage_sender.py), and
the announcements the rate limit lets through as STATUSTEXT.
It notices the vehicle link's loss and return (both announced; on its return
every pending report is resent at once), and every ``status_period_s`` sends RESCUE_STATUS, checks the
HQ link and the disk (companion/service/status.py) and sends the camera component's
heartbeat. It sleeps until the next of these is due, or until woken: by a commit
(companion/storage/ledger.py, on the processing thread, which stages reports and publishes
them after the commit; only this thread sends them), an announcement or an
acknowledgement.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from types import ModuleType

from companion.reporting.announcements import Announcer
from companion.reporting.coverage_sender import CoverageSender
from companion.reporting.pictures import PictureSender
from companion.service.links import Links
from companion.service.livevideo import LiveVideo
from companion.service.status import Status
from mavlink_io import dialect, picture, statustext
from mavlink_io.codec import MavMessage
from mavlink_io.reliable import Outbox
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)

_SUMMARY_PERIOD_S = 30.0  # an INFO line for journald this often
_FIRST_WAIT_NOTE_S = 3.0  # no autopilot this long after start (or a loss): say so
_WAIT_NOTE_PERIOD_S = 30.0  # ... and again this often while it lasts


class Reporter:
    def __init__(
        self,
        *,
        acks: queue.Queue[MavMessage],
        outbox: Outbox,
        picture_sender: PictureSender,
        coverage_sender: CoverageSender,
        announcer: Announcer,
        status: Status,
        video: LiveVideo,
        vehicle: VehicleLink,
        links: Links,
        status_period_s: float,
        stop: threading.Event,
        wake: threading.Event,
        m: ModuleType,
    ) -> None:
        self._acks = acks
        self._outbox = outbox
        self._picture_sender = picture_sender
        self._coverage_sender = coverage_sender
        self._announcer = announcer
        self._status = status
        self._video = video
        self._vehicle = vehicle
        self._links = links
        self._status_period_s = status_period_s
        self._stop = stop
        self._wake = wake
        self._m = m
        self.chunk_ids = statustext.ChunkIds()

    def run(self) -> None:
        period = self._status_period_s
        next_status = 0.0
        next_summary = time.monotonic() + _SUMMARY_PERIOD_S
        was_connected = False
        next_wait_note = time.monotonic() + _FIRST_WAIT_NOTE_S
        while not self._stop.is_set():
            self.apply_acks()
            self._outbox.poll()
            if self._outbox.seconds_until_due() != 0.0:  # reports first, always
                self._picture_sender.poll()
                if self._picture_sender.seconds_until_due() != 0.0:  # then pictures
                    self._coverage_sender.poll()
            now = time.monotonic()
            for a in self._announcer.take(now):
                for msg in statustext.statustext_msgs(a.text, a.severity, self.chunk_ids, self._m):
                    self._links.send_plain(msg)
            connected = self._vehicle.connected
            if connected != was_connected:
                self._status.link_changed(connected)
                if connected:
                    self._outbox.resend_all_now()
                was_connected = connected
            if connected:
                next_wait_note = now + _FIRST_WAIT_NOTE_S
            elif now >= next_wait_note:
                next_wait_note = now + _WAIT_NOTE_PERIOD_S
                self._status.note_waiting(now)
            if now >= next_status:
                next_status = now + period
                self._status.send(now)
                self._status.check_health(now)
                self._video.heartbeat()  # the camera's own heartbeat: QGC finds it
            if now >= next_summary:
                next_summary = now + _SUMMARY_PERIOD_S
                self._status.log_summary()
            waits = [
                next_status - now,
                self._outbox.seconds_until_due(),
                self._picture_sender.seconds_until_due(),
                self._coverage_sender.seconds_until_due(),
                self._announcer.seconds_until_due(now),
            ]
            wait = min(w for w in waits if w is not None)
            self._wake.wait(max(0.01, wait))
            self._wake.clear()

    def apply_acks(self) -> None:
        """The acknowledgements queued so far (also at the stop, after the join)."""
        while True:
            try:
                ack = self._acks.get_nowait()
            except queue.Empty:
                return
            if ack.get_msgId() == dialect.RESCUE_PICTURE_ACK_ID:
                try:
                    self._picture_sender.on_ack(picture.Ack.from_msg(ack))
                except picture.BadChunk as exc:
                    log.warning("picture acknowledgement refused: %s", exc)
            elif ack.acked_msgid == dialect.RESCUE_COVERAGE_ID:
                self._coverage_sender.on_ack(int(ack.seq), int(ack.result))
            elif (acked := self._outbox.acknowledged(ack)) is not None:
                log.debug("report %d acknowledged", ack.seq)
                if acked.get_msgId() == dialect.RESCUE_VICTIM_REPORT_ID and ack.hq_victim_id:
                    self._announcer.hq_number(int(acked.victim_id), int(ack.hq_victim_id))
