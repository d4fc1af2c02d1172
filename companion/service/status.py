"""What the companion says about itself; the reporter thread calls it.

RESCUE_STATUS to the HQ (with the closer looks' counts and whether they are on,
from ``Looks.tally``) and a ``STATUS=`` line to systemd every
``status_period_s``, with the health checks of the direct HQ link and the state
disk at that period (each change announced once, companion/reporting/announcements.py); the
vehicle link's loss and return (announced); an INFO summary for journald every
30 s; and, while no autopilot answers, what the service waits for and on which
link. It reads the processing thread's figures only through ``FrameStats`` and
``Processing.counts`` (never the tracker), and the camera's state from the
``camera_ok`` event the camera thread sets.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from collections import Counter
from types import ModuleType

from companion.config import Config
from companion.looks.run import Looks
from companion.reporting.announcements import Announcer
from companion.reporting.pictures import PictureSender
from companion.service.links import Links
from companion.service.processing import Processing
from companion.service.sdnotify import Notifier
from mavlink_io.hqlink import HqLink
from mavlink_io.linkspec import parse_link
from mavlink_io.reliable import Outbox
from mavlink_io.tlog import TlogWriter
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)

_DISK_FULL_BYTES = 64 * 1024 * 1024  # less free space than this on the state disk is "full"


class Status:
    def __init__(
        self,
        *,
        config: Config,
        vehicle: VehicleLink,
        hq: HqLink | None,
        tlog: TlogWriter,
        signed: bool,
        camera_ok: threading.Event,
        processing: Processing,
        outbox: Outbox,
        picture_sender: PictureSender,
        announcer: Announcer,
        links: Links,
        notifier: Notifier,
        started_mono_s: float,
        m: ModuleType,
        looks: Looks,
    ) -> None:
        self._looks = looks
        self._config = config
        self._vehicle = vehicle
        self._hq = hq
        self._tlog = tlog
        self._signed = signed
        self._camera_ok = camera_ok
        self._processing = processing
        self._outbox = outbox
        self._picture_sender = picture_sender
        self._announcer = announcer
        self._links = links
        self._notifier = notifier
        self._started_mono_s = started_mono_s
        self._m = m

    def send(self, now: float) -> None:
        """RESCUE_STATUS, and the same news for systemd."""
        m = self._m
        fps, vision_ms = self._processing.stats.summary(now)
        mailbox = self._processing.mailbox
        drop_pct = 100.0 * mailbox.dropped / max(1, mailbox.received)
        camera_ok = self._camera_ok.is_set()
        flags = 0
        if self._vehicle.connected:
            flags |= m.RESCUE_STATUS_FLAGS_VEHICLE_LINK
        if camera_ok:
            flags |= m.RESCUE_STATUS_FLAGS_CAMERA
        if self._hq is not None and self._hq.heard_within(self._config.hq.hq_timeout_s):
            flags |= m.RESCUE_STATUS_FLAGS_HQ_LINK
        if self._vehicle.clock.synced:
            flags |= m.RESCUE_STATUS_FLAGS_CLOCK_SYNCED
        if self._vehicle.origin is not None:
            flags |= m.RESCUE_STATUS_FLAGS_GLOBAL_ORIGIN
        if self._tlog.recording:
            flags |= m.RESCUE_STATUS_FLAGS_RECORDING
        if self._signed:
            flags |= m.RESCUE_STATUS_FLAGS_SIGNING
        looks = self._looks.tally
        if looks.on:
            flags |= m.RESCUE_STATUS_FLAGS_LOOKS_ON
        confirmed, tentative = self._processing.counts
        pending = self._outbox.pending_count
        self._links.send_dialect(
            m.MAVLink_rescue_status_message(
                int(now - self._started_mono_s),
                fps,
                drop_pct,
                vision_ms,
                flags,
                min(confirmed, 0xFFFF),
                min(tentative, 0xFFFF),
                min(pending, 0xFFFF),
                min(looks.made, 0xFFFF),
                min(looks.confirmed, 0xFFFF),
                min(looks.rejected, 0xFFFF),
                min(looks.urgency_changed, 0xFFFF),
                min(looks.aborted, 0xFFFF),
            )
        )
        link = (
            "vehicle up"
            if self._vehicle.connected
            else f"waiting for the autopilot on {self._config.vehicle.url}"
        )
        camera = "ok" if camera_ok else "lost"
        made = f", {line}" if (line := self._processing.looks_line) else ""
        self._notifier.status(
            f"{link}, camera {camera}, {fps:.1f} fps ({drop_pct:.0f}% dropped), "
            f"{confirmed} victims, {pending} unacknowledged{made}"
        )

    def check_health(self, now: float) -> None:
        """The HQ link (when there is a direct one; heard within hq_timeout_s, judged
        from hq_timeout_s after start) and the state disk."""
        timeout_s = self._config.hq.hq_timeout_s
        if self._hq is not None and now - self._started_mono_s >= timeout_s:
            self._announcer.condition("hq", self._hq.heard_within(timeout_s), time.monotonic())
        state_dir = self._config.paths.state_dir
        try:
            free = shutil.disk_usage(state_dir).free
        except OSError as exc:
            log.debug("free space of %s: %s", state_dir, exc)
        else:
            self._announcer.condition("disk", free >= _DISK_FULL_BYTES, time.monotonic())
        self._announcer.settle(now)  # a flapping one settled

    def link_changed(self, connected: bool) -> None:
        if connected:
            known = self._processing.counts[0]
            self._announcer.announce(f"companion online, {known} victims known", 5)
        else:
            # The autopilot cannot hear this; the HQ link (if any) can.
            self._announcer.announce("companion: vehicle link lost", 3)

    def note_waiting(self, now: float) -> None:
        """Say what the service waits for, and where, while no autopilot is heard."""
        v = self._config.vehicle
        heard = self._vehicle.state().counters["messages_in"]
        spec = parse_link(v.url)
        where = spec.describe()
        bound = getattr(self._vehicle.link, "local_address", None)
        if spec.kind in ("udpin", "tcpin") and isinstance(bound, tuple) and spec.port == 0:
            where += f" (port {bound[1]} chosen by the system)"
        log.warning(
            "waiting for the autopilot: no HEARTBEAT from a flight controller%s on the "
            "vehicle link %s (%s) for %.0f s%s; pose, geolocation and reports to the HQ "
            "over the vehicle link wait for it",
            f" with system ID {v.system_id}" if v.system_id else "",
            v.url,
            where,
            now - self._started_mono_s,
            f", {heard} other messages heard" if heard else ", nothing heard",
        )

    def log_summary(self) -> None:
        c = self._processing.counters
        counts = Counter(dict(c.rejected))  # one C-level copy: processing adds keys meanwhile
        rejected = ", ".join(f"{k}: {n}" for k, n in counts.most_common(3)) or "none"
        log.info(
            "%d frames (%d without a pose, %d dropped), %d detections, %d observations "
            "(rejected: %s), %d confirmed victims, %d reports unacknowledged, "
            "%d pictures delivered, %d waiting",
            c.frames,
            c.frames_without_pose,
            self._processing.mailbox.dropped,
            c.detections,
            c.observations,
            rejected,
            self._processing.counts[0],
            self._outbox.pending_count,
            self._picture_sender.counters.delivered,
            self._picture_sender.pending,
        )
        if line := self._processing.looks_line:
            log.info("closer looks: %s", line)
