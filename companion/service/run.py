"""``rescue-companion run``: the service on the Pi.

``Service`` builds the parts, runs their threads and stops them. Threads
(docs/ARCHITECTURE.md):
- vehicle link (mavlink_io.VehicleLink): telemetry in, our HEARTBEAT out;
- HQ link (optional, mavlink_io.HqLink): acknowledgements and operator actions;
- camera (companion/service/capture.py): frames into a one-slot mailbox (a newer frame
  replaces an unprocessed one; the drop is counted);
- thermal camera (companion/service/capture.py, only with a ``[thermal]`` section): the
  same, into the mailbox's thermal slot;
- processing (companion/service/processing.py): operator actions and ground requests
  (companion/service/ground.py), the pipeline, persistence (companion/storage/ledger.py), systemd
  watchdog;
- reporter (companion/service/reporter.py): outbox sends and resends, then evidence
  pictures at a bounded rate, announcements (rate-limited), health conditions (HQ
  link, disk) and RESCUE_STATUS (companion/service/status.py).

The processing thread commits a frame's consequences (tracker, what was reported,
the new reports and their outbox entries) in one SQLite transaction; the outbox
schedules the reports only after that commit, so the reporter never sends what is
not on disk, and after a crash nothing unacknowledged is lost. Acknowledgements
arrive on the link threads, which never write SQLite: they are queued to the
reporter, the one owner of the outbox. The queues the link threads fill exist
before the links open, since a link's reader thread starts with it.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from companion.calibration import camera_model
from companion.config import Config
from companion.looks.run import Looks
from companion.pipeline import Pipeline, ThermalEye
from companion.reporting import coverage_sender as coverage_transport
from companion.reporting import pictures
from companion.reporting.announcements import Announcer
from companion.reporting.policy import ReportPolicy
from companion.service.capture import Capture, FrameMailbox, recording_dir
from companion.service.ground import Ground
from companion.service.links import Links
from companion.service.livevideo import LiveVideo
from companion.service.params import Settings
from companion.service.processing import FaultInjection, FrameStats, Processing
from companion.service.reporter import Reporter
from companion.service.sdnotify import Notifier
from companion.service.status import Status
from companion.sources.base import Frame
from companion.sources.colour_open import open_camera
from companion.sources.folder import write_frame
from companion.sources.thermal import ThermalFrame
from companion.sources.thermal_folder import write_thermal_frame
from companion.sources.thermal_open import open_thermal
from companion.storage.ledger import Ledger
from companion.storage.recovery import load_state
from companion.vision.backends import make_detector
from companion.vision.thermal import ThermalDetector
from mavlink_io import coverage as mavcoverage
from mavlink_io import dialect
from mavlink_io.codec import MavMessage
from mavlink_io.params import PARAM_MESSAGE_TYPES, ParamServer
from mavlink_io.reliable import Outbox
from mavlink_io.signing import Signing, load_signing
from mavlink_io.tlog import TlogWriter

log = logging.getLogger(__name__)

MAV_STATE_STANDBY = 3
MAV_STATE_ACTIVE = 4
MAV_STATE_CRITICAL = 5
_STOP_POLL_S = 0.1  # how often the main thread looks for a stop signal


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
        m = dialect.load()
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
        # Parameters set from the ground override the config file's values (companion/service/params.py).
        self.settings = Settings(
            config, self.store.get("params"), self._apply_settings, self._save_settings
        )
        config = self.config = self.settings.config
        self.policy.update_min_interval_s = config.reporting.update_min_interval_s
        self.param_server = ParamServer(self.settings, config.vehicle.component_id, m)
        self.camera_model = camera_model(config.camera)
        thermal = None
        if config.thermal is not None:
            thermal = ThermalEye(
                camera_model(config.thermal), ThermalDetector(config.thermal.detector)
            )
        else:
            log.info("no [thermal] section: running with the colour camera only")
        self.pipeline = Pipeline(
            config,
            self.camera_model,
            make_detector(config.detector),
            self.tracker,
            self.policy,
            thermal,
        )
        self.tlog = TlogWriter(config.paths.tlogs, int(config.paths.tlog_max_mb * 1e6))
        mailbox = FrameMailbox()
        # What the link threads hand over (_on_dialect): acknowledgements to the
        # reporter, operator actions and ground requests to processing.
        self.acks: queue.Queue[MavMessage] = queue.Queue(maxsize=1024)
        self.actions: queue.Queue[MavMessage] = queue.Queue(maxsize=256)
        self.ground_requests: queue.Queue[MavMessage] = queue.Queue(maxsize=64)
        self.wake_reporter = threading.Event()
        self.camera_ok = threading.Event()  # set by the camera thread while frames come
        self.announcer = Announcer(
            enabled=config.reporting.statustext,
            announce_severity=config.reporting.announce_severity,
            robot_sysid=self._robot_sysid,
            wake=self.wake_reporter,
        )
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
        self.capture: Capture[Frame] = Capture(
            camera=open_camera(config.camera),
            put=mailbox.put,
            record=write_frame,
            frames_dir=recording_dir(config, "frames"),
            camera_ok=self.camera_ok,
            announcer=self.announcer,
            stop=self.stop,
        )
        # Set by the thermal camera's thread while its frames come (never without one).
        self.thermal_ok = threading.Event()
        self.thermal_capture: Capture[ThermalFrame] | None = None
        if config.thermal is not None:
            self.thermal_capture = Capture(
                camera=open_thermal(config.thermal),
                put=mailbox.put_thermal,
                record=write_thermal_frame,
                frames_dir=recording_dir(config, "thermal"),
                camera_ok=self.thermal_ok,
                announcer=self.announcer,
                stop=self.stop,
                condition="thermal camera",
            )
        self.video = LiveVideo(config, self.camera_model, self.vehicle, self.signing, m)
        chooser, picture_sender = pictures.resume(
            config.pictures,
            self.store,
            lambda chunk: self.links.send_dialect(chunk.to_msg(m)),
            signed=self.signing is not None,
        )
        self.ledger = Ledger(
            store=self.store,
            tracker=self.tracker,
            policy=self.policy,
            outbox=self.outbox,
            chooser=chooser,
            picture_sender=picture_sender,
            announcer=self.announcer,
            vehicle=self.vehicle,
            robot_sysid=self._robot_sysid,
            report_seq=state.report_seq,
            floor_down_m=config.geolocation.floor_down_m,
            wake_reporter=self.wake_reporter,
            m=m,
        )
        coverage_sender = coverage_transport.resume(
            self.ledger.coverage,
            config.coverage,
            self.store,
            lambda seq, piece: self.links.send_dialect(mavcoverage.piece_msg(m, seq, piece)),
            signed=self.signing is not None,
        )
        # Closer looks: short GUIDED detours (docs/LOOKS.md); ticked by processing.
        self.looks = Looks(config.looks, self.vehicle, self.announcer, self._looks_taken_over)
        ground = Ground(
            looks=self.looks,
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
            m=m,
        )
        self.processing = Processing(
            looks=self.looks,
            config=config,
            pipeline=self.pipeline,
            mailbox=mailbox,
            stats=FrameStats(),
            vehicle=self.vehicle,
            ground=ground,
            ledger=self.ledger,
            chooser=chooser,
            video=self.video,
            notifier=notifier,
            faults=faults,
            started_mono_s=self.started_mono_s,
            stop=self.stop,
        )
        status = Status(
            looks=self.looks,
            config=config,
            vehicle=self.vehicle,
            hq=self.hq,
            tlog=self.tlog,
            signed=self.signing is not None,
            camera_ok=self.camera_ok,
            processing=self.processing,
            outbox=self.outbox,
            picture_sender=picture_sender,
            announcer=self.announcer,
            links=self.links,
            notifier=notifier,
            started_mono_s=self.started_mono_s,
            m=m,
        )
        self.reporter = Reporter(
            acks=self.acks,
            outbox=self.outbox,
            picture_sender=picture_sender,
            coverage_sender=coverage_sender,
            announcer=self.announcer,
            status=status,
            video=self.video,
            vehicle=self.vehicle,
            links=self.links,
            status_period_s=config.reporting.status_period_s,
            stop=self.stop,
            wake=self.wake_reporter,
            m=m,
        )

    def _robot_sysid(self) -> int:
        """This robot's system ID: the vehicle's once heard, else the configured one."""
        return self.vehicle.sysid or self.config.vehicle.system_id or 1

    def _apply_settings(self, config: Config) -> None:
        """A setting changed from the ground (processing thread): applied at once."""
        self.video.apply(config)
        self.config = config
        self.pipeline.detector.min_score = config.detector.min_score
        self.policy.update_min_interval_s = config.reporting.update_min_interval_s
        self.announcer.announce_severity = config.reporting.announce_severity
        self.looks.set_enabled(config.looks.enabled)

    def _looks_taken_over(self) -> None:
        """The operator took over during a look (processing thread): RC_LOOK_ON goes to
        0, saved, so no look starts again until the operator sets it to 1."""
        if self.settings.get("RC_LOOK_ON"):
            self.settings.set("RC_LOOK_ON", 0.0)

    def _save_settings(self, snapshot: dict[str, Any]) -> None:
        self.store.set("params", snapshot)

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
            self.wake_reporter.set()
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

    # -- lifecycle ---------------------------------------------------------------------

    def run(self, stop_reason: Callable[[], str | None] = lambda: None) -> int:
        """Run until ``stop`` is set, or ``stop_reason`` (polled every
        ``_STOP_POLL_S``) names a reason to stop, such as a signal; 0 after a clean
        stop, 1 after a thread failed."""
        bodies = [("camera", self.capture.run)]
        if self.thermal_capture is not None:
            bodies.append(("thermal camera", self.thermal_capture.run))
        bodies += [("processing", self.processing.run), ("reporter", self.reporter.run)]
        threads = [
            threading.Thread(target=self._guard(n, f), name=n, daemon=True) for n, f in bodies
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
            "running: vehicle %s, camera %s, thermal camera %s",
            self.config.vehicle.url,
            self.config.camera.source,
            "none" if self.config.thermal is None else self.config.thermal.source,
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
            self.reporter.apply_acks()  # heard before the stop: not resent after a restart
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
        if self.thermal_capture is not None:
            self.thermal_capture.camera.close()
        self.video.close()
        self.links.close()
        self.tlog.close()
        self.store.close()
