"""``rescue-companion run``: the service on the Pi.

Threads (docs/ARCHITECTURE.md):
- vehicle link (mavlink_io.VehicleLink): telemetry in, our HEARTBEAT out;
- HQ link (optional, mavlink_io.HqLink): acknowledgements and operator actions;
- camera: frames into a one-slot mailbox (a newer frame replaces an unprocessed
  one; the drop is counted);
- processing: pipeline, operator actions, persistence, systemd watchdog;
- reporter: outbox sends and resends, then evidence pictures at a bounded rate,
  announcements (rate-limited), health conditions (HQ link, disk), RESCUE_STATUS.

The processing thread commits a frame's consequences (tracker, what was reported,
the new reports and their outbox entries) in one SQLite transaction; the outbox
schedules the reports only after that commit, so the reporter never sends what is
not on disk, and after a crash nothing unacknowledged is lost. Acknowledgements
arrive on the link threads, which never write SQLite: they are queued to the
reporter, the one owner of the outbox.
"""

from __future__ import annotations

import logging
import queue
import shutil
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from companion import pictures
from companion.announcements import Announcer
from companion.calibration import camera_model
from companion.capture import Capture, FrameMailbox, recording_dir
from companion.config import Config
from companion.ground import Ground
from companion.ledger import Ledger
from companion.links import Links
from companion.livevideo import LiveVideo
from companion.params import Settings
from companion.pipeline import Pipeline
from companion.processing import FaultInjection, FrameStats, Processing
from companion.reporting import ReportPolicy
from companion.sdnotify import Notifier
from companion.sources import (
    open_camera,
)
from companion.state import load_state
from companion.vision import make_detector
from mavlink_io import dialect, picture, statustext
from mavlink_io.codec import MavMessage
from mavlink_io.linkspec import parse_link
from mavlink_io.params import PARAM_MESSAGE_TYPES, ParamServer
from mavlink_io.reliable import Outbox
from mavlink_io.signing import Signing, load_signing
from mavlink_io.tlog import TlogWriter

log = logging.getLogger(__name__)

MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
_STOP_POLL_S = 0.1  # how often the main thread looks for a stop signal
_SUMMARY_PERIOD_S = 30.0  # an INFO line for journald this often
_FIRST_WAIT_NOTE_S = 3.0  # no autopilot this long after start (or a loss): say so
_WAIT_NOTE_PERIOD_S = 30.0  # ... and again this often while it lasts
_DISK_FULL_BYTES = 64 * 1024 * 1024  # less free space than this on the state disk is "full"


class Service:
    """The companion's runtime. Build, ``run(stop)``, and it cleans up on return."""

    def __init__(
        self, config: Config, notifier: Notifier, faults: FaultInjection | None = None
    ) -> None:
        self.config = config
        self.notifier = notifier
        faults = faults or FaultInjection()
        self.stop = threading.Event()
        self.started_mono_s = time.monotonic()
        self.failure: str | None = None
        self._m = dialect.load()
        # Everything that can refuse to start does so here, before any thread runs.
        self.signing: Signing | None = (
            load_signing(config.signing.key_file, config.signing.link_id)
            if config.signing.enabled and config.signing.key_file is not None
            else None
        )
        rep = config.reporting
        self.policy = ReportPolicy(
            rep.move_threshold_sigma, rep.move_min_m, rep.update_min_interval_s
        )
        state = load_state(config.paths.state_dir, config.tracker, self.policy)
        self.store, self.tracker = state.store, state.tracker
        self._state_problem = state.problem  # announced once the threads run
        # Parameters set from the ground override the config file's values (companion/params.py).
        self.settings = Settings(
            config, self.store.get("params"), self._apply_settings, self._save_settings
        )
        config = self.config = self.settings.config
        self.policy.update_min_interval_s = config.reporting.update_min_interval_s
        self.param_server = ParamServer(self.settings, config.vehicle.component_id, self._m)
        self.ground_requests: queue.Queue[MavMessage] = queue.Queue(maxsize=64)
        self.camera_model = camera_model(config.camera)
        self.pipeline = Pipeline(
            config, self.camera_model, make_detector(config.detector), self.tracker, self.policy
        )
        self.tlog = TlogWriter(config.paths.tlogs, int(config.paths.tlog_max_mb * 1e6))
        frames_dir = recording_dir(config)
        self.mailbox = FrameMailbox()
        self.actions: queue.Queue[MavMessage] = queue.Queue(maxsize=256)
        self.acks: queue.Queue[MavMessage] = queue.Queue(maxsize=1024)
        self.chunk_ids = statustext.ChunkIds()
        self._wake_reporter = threading.Event()
        self.announcer = Announcer(
            enabled=config.reporting.statustext,
            announce_severity=config.reporting.announce_severity,
            robot_sysid=self._robot_sysid,
            wake=self._wake_reporter,
        )
        self.camera_ok = threading.Event()  # set by the camera thread while frames come
        self.stats = FrameStats()
        # Made before the links open (it reads the saved outbox); it sends through
        # them, and only from the reporter thread, which starts after they are open.
        self.outbox = Outbox(
            lambda msg: self.links.send_dialect(msg),
            store=self.store,
            initial_s=config.hq.resend_initial_s,
            max_s=config.hq.resend_max_s,
        )
        self.links = Links(
            config, self.signing, self.tlog, health=self._health, on_dialect=self._on_dialect
        )
        self.vehicle, self.hq = self.links.vehicle, self.links.hq
        self.capture = Capture(
            camera=open_camera(config.camera),
            mailbox=self.mailbox,
            frames_dir=frames_dir,
            camera_ok=self.camera_ok,
            announcer=self.announcer,
            stop=self.stop,
        )
        self.video = LiveVideo(config, self.camera_model, self.vehicle, self.signing, self._m)
        self.chooser, self.picture_sender = pictures.resume(
            config.pictures,
            self.store,
            lambda chunk: self.links.send_dialect(chunk.to_msg(self._m)),
            signed=self.signing is not None,
        )
        self.ledger = Ledger(
            store=self.store,
            tracker=self.tracker,
            policy=self.policy,
            outbox=self.outbox,
            chooser=self.chooser,
            picture_sender=self.picture_sender,
            announcer=self.announcer,
            vehicle=self.vehicle,
            robot_sysid=self._robot_sysid,
            report_seq=state.report_seq,
            floor_down_m=config.geolocation.floor_down_m,
            wake_reporter=self._wake_reporter,
            m=self._m,
        )
        ground = Ground(
            actions=self.actions,
            requests=self.ground_requests,
            tracker=self.tracker,
            policy=self.policy,
            ledger=self.ledger,
            param_server=self.param_server,
            video=self.video,
            vehicle=self.vehicle,
            links=self.links,
            announcer=self.announcer,
            m=self._m,
        )
        self.processing = Processing(
            config=config,
            pipeline=self.pipeline,
            mailbox=self.mailbox,
            stats=self.stats,
            vehicle=self.vehicle,
            ground=ground,
            ledger=self.ledger,
            chooser=self.chooser,
            video=self.video,
            notifier=notifier,
            faults=faults,
            started_mono_s=self.started_mono_s,
            stop=self.stop,
        )

    def _robot_sysid(self) -> int:
        """This robot's system ID: the vehicle's once heard, else the configured one."""
        return self.vehicle.sysid or self.config.vehicle.system_id or 1

    # -- links ---------------------------------------------------------------------------

    def _health(self) -> int:
        if not self.camera_ok.is_set():
            return MAV_STATE_CRITICAL
        return MAV_STATE_ACTIVE if self.vehicle.poses.latest() is not None else MAV_STATE_STANDBY

    def _on_dialect(self, msg: MavMessage) -> None:
        """From a link thread, which never writes SQLite: acknowledgements go to the
        reporter (the outbox's owner); operator actions, parameter requests and
        commands to processing."""
        if msg.get_type() in PARAM_MESSAGE_TYPES or msg.get_type() == "COMMAND_LONG":
            try:
                self.ground_requests.put_nowait(msg)
            except queue.Full:
                log.warning("ground request queue full; %s dropped", msg.get_type())
            return
        if msg.get_msgId() in (dialect.RESCUE_ACK_ID, dialect.RESCUE_PICTURE_ACK_ID):
            try:
                self.acks.put_nowait(msg)
            except queue.Full:  # the report is resent and acknowledged again
                log.warning("acknowledgement queue full; ack of %d dropped", msg.seq)
            self._wake_reporter.set()
            return
        try:
            self.actions.put_nowait(msg)
        except queue.Full:
            log.warning(
                "operator action queue full; action %d dropped (the HQ resends)", msg.action_seq
            )

    # -- threads -----------------------------------------------------------------------

    def _guard(self, name: str, body: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            try:
                body()
            except Exception as exc:  # a thread's death must stop the service, loudly
                log.exception("%s thread failed", name)
                self.failure = f"{name} thread failed: {exc}"
                self.stop.set()

        return run

    def _apply_settings(self, config: Config) -> None:
        self.video.apply(config)
        self.config = config
        self.pipeline.detector.min_score = config.detector.min_score
        self.policy.update_min_interval_s = config.reporting.update_min_interval_s
        self.announcer.announce_severity = config.reporting.announce_severity

    def _save_settings(self, snapshot: dict[str, Any]) -> None:
        self.store.set("params", snapshot)

    def _reporter_loop(self) -> None:
        period = self.config.reporting.status_period_s
        next_status = 0.0
        next_summary = time.monotonic() + _SUMMARY_PERIOD_S
        was_connected = False
        next_wait_note = time.monotonic() + _FIRST_WAIT_NOTE_S
        while not self.stop.is_set():
            self._apply_acks()
            self.outbox.poll()
            if self.outbox.seconds_until_due() != 0.0:  # reports first, always
                self.picture_sender.poll()
            now = time.monotonic()
            for a in self.announcer.take(now):
                for msg in statustext.statustext_msgs(a.text, a.severity, self.chunk_ids, self._m):
                    self.links.send_plain(msg)
            connected = self.vehicle.connected
            if connected != was_connected:
                self._link_changed(connected)
                was_connected = connected
            if connected:
                next_wait_note = now + _FIRST_WAIT_NOTE_S
            elif now >= next_wait_note:
                next_wait_note = now + _WAIT_NOTE_PERIOD_S
                self._note_waiting(now)
            if now >= next_status:
                next_status = now + period
                self._send_status(now)
                self._check_health(now)
                self.video.heartbeat()  # the camera's own heartbeat: QGC finds it
            if now >= next_summary:
                next_summary = now + _SUMMARY_PERIOD_S
                self._log_summary()
            waits = [
                next_status - now,
                self.outbox.seconds_until_due(),
                self.picture_sender.seconds_until_due(),
                self.announcer.seconds_until_due(now),
            ]
            wait = min(w for w in waits if w is not None)
            self._wake_reporter.wait(max(0.01, wait))
            self._wake_reporter.clear()

    def _note_waiting(self, now: float) -> None:
        """Say what the service waits for, and where, while no autopilot is heard."""
        v = self.config.vehicle
        heard = self.vehicle.state().counters["messages_in"]
        spec = parse_link(v.url)
        where = spec.describe()
        bound = getattr(self.vehicle.link, "local_address", None)
        if spec.kind in ("udpin", "tcpin") and isinstance(bound, tuple) and spec.port == 0:
            where += f" (port {bound[1]} chosen by the system)"
        log.warning(
            "waiting for the autopilot: no HEARTBEAT from a flight controller%s on the "
            "vehicle link %s (%s) for %.0f s%s; pose, geolocation and reports to the HQ "
            "over the vehicle link wait for it",
            f" with system ID {v.system_id}" if v.system_id else "",
            v.url,
            where,
            now - self.started_mono_s,
            f", {heard} other messages heard" if heard else ", nothing heard",
        )

    def _apply_acks(self) -> None:
        while True:
            try:
                ack = self.acks.get_nowait()
            except queue.Empty:
                return
            if ack.get_msgId() == dialect.RESCUE_PICTURE_ACK_ID:
                try:
                    self.picture_sender.on_ack(picture.Ack.from_msg(ack))
                except picture.BadChunk as exc:
                    log.warning("picture acknowledgement refused: %s", exc)
            elif self.outbox.on_ack(ack):
                log.debug("report %d acknowledged", ack.seq)

    def _check_health(self, now: float) -> None:
        """The HQ link (when there is a direct one; heard within hq_timeout_s, judged
        from hq_timeout_s after start) and the state disk."""
        if self.hq is not None and now - self.started_mono_s >= self.config.hq.hq_timeout_s:
            self.announcer.condition(
                "hq", self.hq.heard_within(self.config.hq.hq_timeout_s), time.monotonic()
            )
        try:
            free = shutil.disk_usage(self.config.paths.state_dir).free
        except OSError as exc:
            log.debug("free space of %s: %s", self.config.paths.state_dir, exc)
        else:
            self.announcer.condition("disk", free >= _DISK_FULL_BYTES, time.monotonic())
        self.announcer.settle(now)  # a flapping one settled

    def _link_changed(self, connected: bool) -> None:
        if connected:
            known = self.processing.counts[0]
            self.announcer.announce(f"companion online, {known} victims known", 5)
            self.outbox.resend_all_now()
        else:
            # The autopilot cannot hear this; the HQ link (if any) can.
            self.announcer.announce("companion: vehicle link lost", 3)

    def _log_summary(self) -> None:
        c = self.processing.counters
        counts = Counter(dict(c.rejected))  # one C-level copy: processing adds keys meanwhile
        rejected = ", ".join(f"{k}: {n}" for k, n in counts.most_common(3)) or "none"
        log.info(
            "%d frames (%d without a pose, %d dropped), %d detections, %d observations "
            "(rejected: %s), %d confirmed victims, %d reports unacknowledged, "
            "%d pictures delivered, %d waiting",
            c.frames,
            c.frames_without_pose,
            self.mailbox.dropped,
            c.detections,
            c.observations,
            rejected,
            self.processing.counts[0],
            self.outbox.pending_count,
            self.picture_sender.counters.delivered,
            self.picture_sender.pending,
        )

    def _send_status(self, now: float) -> None:
        m = self._m
        fps, vision_ms = self.stats.summary(now)
        drop_pct = 100.0 * self.mailbox.dropped / max(1, self.mailbox.received)
        flags = 0
        if self.vehicle.connected:
            flags |= m.RESCUE_STATUS_FLAGS_VEHICLE_LINK
        camera_ok = self.camera_ok.is_set()
        if camera_ok:
            flags |= m.RESCUE_STATUS_FLAGS_CAMERA
        if self.hq is not None and self.hq.heard_within(self.config.hq.hq_timeout_s):
            flags |= m.RESCUE_STATUS_FLAGS_HQ_LINK
        if self.vehicle.clock.synced:
            flags |= m.RESCUE_STATUS_FLAGS_CLOCK_SYNCED
        if self.vehicle.origin is not None:
            flags |= m.RESCUE_STATUS_FLAGS_GLOBAL_ORIGIN
        if self.tlog.recording:
            flags |= m.RESCUE_STATUS_FLAGS_RECORDING
        if self.signing is not None:
            flags |= m.RESCUE_STATUS_FLAGS_SIGNING
        confirmed, tentative = self.processing.counts
        pending = self.outbox.pending_count
        self.links.send_dialect(
            m.MAVLink_rescue_status_message(
                int(now - self.started_mono_s),
                fps,
                drop_pct,
                vision_ms,
                flags,
                min(confirmed, 0xFFFF),
                min(tentative, 0xFFFF),
                min(pending, 0xFFFF),
            )
        )
        link = (
            "vehicle up"
            if self.vehicle.connected
            else f"waiting for the autopilot on {self.config.vehicle.url}"
        )
        camera = "ok" if camera_ok else "lost"
        self.notifier.status(
            f"{link}, camera {camera}, {fps:.1f} fps ({drop_pct:.0f}% dropped), "
            f"{confirmed} victims, {pending} unacknowledged"
        )

    # -- lifecycle ---------------------------------------------------------------------

    def run(self, stop_reason: Callable[[], str | None] = lambda: None) -> int:
        """Run until ``stop`` is set, or ``stop_reason`` (polled every
        ``_STOP_POLL_S``) names a reason to stop, such as a signal; 0 after a clean
        stop, 1 after a thread failed."""
        threads = [
            threading.Thread(target=self._guard(n, f), name=n, daemon=True)
            for n, f in (
                ("camera", self.capture.run),
                ("processing", self.processing.run),
                ("reporter", self._reporter_loop),
            )
        ]
        for t in threads:
            t.start()
        if self._state_problem is not None:
            self.announcer.announce("Rescue companion: saved state unusable, started afresh", 3)
        self.video.start()
        self.notifier.ready(
            f"links open: vehicle {self.config.vehicle.url}, camera {self.config.camera.source}"
        )
        log.info(
            "running: vehicle %s, camera %s", self.config.vehicle.url, self.config.camera.source
        )
        while not self.stop.wait(_STOP_POLL_S):
            if (reason := stop_reason()) is not None:
                log.info("%s: stopping", reason)
                self.stop.set()
            elif not self.vehicle.alive:  # it catches its own errors; this is a last resort
                self.failure = "vehicle link thread ended"
                self.stop.set()
        self.notifier.stopping()
        log.info("stopping")
        for t in threads:
            t.join(timeout=2.0)
        self.close()
        if self.failure:
            log.error("%s", self.failure)
            return 1
        return 0

    def close(self) -> None:
        """Save, then close everything; safe twice."""
        try:
            self._apply_acks()  # heard before the stop: do not resend them after a restart
            # The reports a full disk kept in memory go into this last commit with the
            # policy that counts them as reported, else a restart would never send them.
            self.ledger.commit([])
        except Exception:
            log.exception("saving the victim registry at shutdown failed")
        if unsaved := self.ledger.unsaved_victims:
            log.error(
                "stopping with the disk still full: %d victims' reports (IDs %s) are not "
                "saved and will not be sent",
                len(unsaved),
                unsaved,
            )
        self.capture.camera.close()
        self.video.close()
        self.links.close()
        self.tlog.close()
        self.store.close()
