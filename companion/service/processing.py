"""The processing thread: operator actions and ground requests, then the newest frame.

Each iteration answers what the ground asked (companion/service/ground.py), reports the
victims again when the EKF origin becomes known (or changes), then takes the newest
frame from the camera's one-slot mailbox: pipeline (enhance, detect, geolocate,
track, decide reports), the live video's shot, the evidence pictures (a thermal
frame: the thermal camera's view of each warm victim), and a commit
(companion/storage/ledger.py) when there is news or the periodic save is due; then it pings
the systemd watchdog (also when no frame came).

It owns the pipeline (detector, tracker, policy), the picture chooser and the
ledger. What the reporter reads from it goes through ``FrameStats`` (locked) and
``counts`` (one tuple, replaced whole); the reporter never touches the tracker.
"""

from __future__ import annotations

import logging
import statistics
import threading
import time
from collections import deque
from dataclasses import dataclass

from companion.config import Config
from companion.coverage import CoverageMapper
from companion.looks.run import Looks
from companion.pipeline import FrameOutcome, Pipeline, PipelineCounters
from companion.reporting.pictures import Candidate, PictureChooser
from companion.reporting.video import Label, labels_in_view, shot
from companion.service.capture import FrameMailbox
from companion.service.ground import Ground
from companion.service.livevideo import LiveVideo
from companion.service.sdnotify import Notifier, watchdog_period_s
from companion.sources.base import CameraTimeout, Frame
from companion.sources.thermal import ThermalFrame
from companion.storage.ledger import Ledger
from fusion.types import GlobalOrigin, TrackState
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)

_SAVE_PERIOD_S = 5.0  # the tracker is saved at least this often while frames flow
_MAILBOX_WAIT_S = 0.25


@dataclass(frozen=True)
class FaultInjection:
    """Testing aids for the service tests (CLI --debug-* flags); off by default."""

    processing_delay_s: float = 0.0  # extra time per frame: processing falls behind
    stall_after_s: float | None = None  # the processing loop hangs after this long


class FrameStats:
    """Processed-frame times and vision durations: written by processing, read by
    the reporter, so every access holds the lock (iterating a deque that another
    thread appends to raises "deque mutated during iteration")."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._vision_ms: deque[float] = deque(maxlen=50)
        self._processed: deque[float] = deque(maxlen=100)  # monotonic times

    def add(self, t_mono_s: float, vision_ms: float | None) -> None:
        with self._lock:
            self._processed.append(t_mono_s)
            if vision_ms is not None:
                self._vision_ms.append(vision_ms)

    def summary(self, now_mono_s: float, window_s: float = 5.0) -> tuple[float, float]:
        """(frames per second over the last ``window_s``, median vision ms)."""
        with self._lock:
            recent = sum(1 for t in self._processed if now_mono_s - t <= window_s)
            vision_ms = statistics.median(self._vision_ms) if self._vision_ms else 0.0
        return recent / window_s, vision_ms


class Processing:
    def __init__(
        self,
        *,
        config: Config,
        pipeline: Pipeline,
        mailbox: FrameMailbox,
        stats: FrameStats,
        vehicle: VehicleLink,
        ground: Ground,
        ledger: Ledger,
        chooser: PictureChooser,
        video: LiveVideo,
        notifier: Notifier,
        faults: FaultInjection,
        started_mono_s: float,
        stop: threading.Event,
        looks: Looks | None = None,
    ) -> None:
        self._config = config
        self._looks = looks
        self._pipeline = pipeline
        self._tracker = pipeline.tracker
        self._policy = pipeline.policy
        self.mailbox = mailbox
        self.stats = stats
        self._vehicle = vehicle
        self._ground = ground
        self._ledger = ledger
        self._chooser = chooser
        self._video = video
        self._notifier = notifier
        self._faults = faults
        self._started_mono_s = started_mono_s
        self._stop = stop
        self._origin: GlobalOrigin | None = None  # the origin reports were last made with
        self.counts = (0, 0)  # confirmed, tentative (written by processing, read by reporter)
        thermal = pipeline.thermal.camera if pipeline.thermal is not None else None
        # Each frame's footprint goes into the ledger's grid, saved with its commits.
        self.coverage = CoverageMapper(
            ledger.coverage, config.geolocation, pipeline.camera, thermal
        )
        self._count_victims()  # the restored ones, before any thread runs

    @property
    def looks_line(self) -> str:
        """The closer looks made and what they settled ("" before the first)."""
        return self._looks.line if self._looks is not None else ""

    @property
    def counters(self) -> PipelineCounters:
        """The pipeline's counters (processing adds to them; the reporter reads them)."""
        return self._pipeline.counters

    def run(self) -> None:
        watchdog_s = watchdog_period_s()
        next_ping = 0.0
        last_save = time.monotonic()
        while not self._stop.is_set():
            stall = self._faults.stall_after_s
            if stall is not None and time.monotonic() - self._started_mono_s > stall:
                log.warning("fault injection: the processing loop stalls now")
                self._stop.wait()
                return
            self._ground.handle_actions()
            self._ground.handle_requests()
            self._check_origin()
            if self._looks is not None:  # closer looks (companion/looks/run.py)
                self._looks.tick(lambda: self._tracker.victims(include_tentative=True))
            try:
                frame = self.mailbox.get(_MAILBOX_WAIT_S)
            except CameraTimeout:
                frame = None
            if isinstance(frame, ThermalFrame):
                outcome = self._pipeline.process_thermal(frame, self._vehicle.poses)
                self.coverage.add(outcome.pose, outcome.sensor)
                self._count_victims()
                candidates = self._choose_thermal_pictures(frame, outcome)
                if (
                    outcome.decisions
                    or candidates
                    or (outcome.events and time.monotonic() - last_save > 0.5)
                ):
                    self._ledger.commit(outcome.decisions, candidates)
                    last_save = time.monotonic()
            elif frame is not None:
                outcome = self._pipeline.process(frame, self._vehicle.poses)
                self.coverage.add(outcome.pose, outcome.sensor, frame.image)
                self._after_frame(outcome)
                self._offer_video(frame, outcome)
                candidates = self._choose_pictures(frame, outcome)
                if (
                    outcome.decisions
                    or candidates
                    or (outcome.events and time.monotonic() - last_save > 0.5)
                    or (time.monotonic() - last_save > _SAVE_PERIOD_S)
                ):
                    self._ledger.commit(outcome.decisions, candidates)
                    last_save = time.monotonic()
                if self._faults.processing_delay_s:
                    self._stop.wait(self._faults.processing_delay_s)
            now = time.monotonic()
            if watchdog_s is not None and now >= next_ping:
                self._notifier.watchdog()
                next_ping = now + watchdog_s

    def _choose_pictures(self, frame: Frame, outcome: FrameOutcome) -> list[Candidate]:
        if not (self._config.pictures.enabled and outcome.located):
            return []
        return self._chooser.consider(
            frame.image, outcome.located, self._tracker.victims(), frame.t_unix_s
        )

    def _choose_thermal_pictures(
        self, frame: ThermalFrame, outcome: FrameOutcome
    ) -> list[Candidate]:
        """A warm victim's thermal evidence picture, chosen as the colour one is."""
        if not (self._config.pictures.enabled and outcome.located):
            return []
        return self._chooser.consider_thermal(frame, outcome.located, self._tracker.victims())

    def _offer_video(self, frame: Frame, outcome: FrameOutcome) -> None:
        streamer = self._video.streamer
        if streamer is None:
            return
        labels: tuple[Label, ...] = ()
        if outcome.pose is not None:
            labels = labels_in_view(
                self._pipeline.camera,
                outcome.pose,
                self._tracker.victims(),
                self._ledger.floor_down_m,
            )
        streamer.offer(shot(frame.image, outcome.detections, labels))

    def _check_origin(self) -> None:
        """Victims reported before the EKF origin was known (or under another origin)
        are reported again, now with latitude, longitude and a map marker."""
        origin = self._vehicle.origin
        if origin is None or origin == self._origin:
            return
        self._origin = origin
        decisions = self._policy.requested(self._tracker.victims(), time.time(), flags=0)
        if decisions:
            log.info("EKF origin known: reporting %d victims again with lat/lon", len(decisions))
            self._ledger.commit(decisions)

    def _after_frame(self, outcome: FrameOutcome) -> None:
        vision_ms = None
        if outcome.pose is not None:
            self._ledger.floor_down_m = outcome.pose.down_m + self._config.geolocation.floor_down_m
            vision_ms = outcome.vision_ms
        self.stats.add(time.monotonic(), vision_ms)
        self._count_victims()

    def _count_victims(self) -> None:
        """Publish the victim counts for the reporter, which must not touch the tracker
        (it is the processing thread's: iterating it there can see it change)."""
        victims = self._tracker.victims(include_tentative=True)
        confirmed = sum(
            1 for v in victims if v.state in (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
        )
        self.counts = (confirmed, sum(1 for v in victims if v.state == TrackState.TENTATIVE))
