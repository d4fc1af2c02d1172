"""One frame through the pipeline: pose at capture time, vision, geolocation, tracking.

The same ``Pipeline`` runs live (``rescue-companion run``) and offline
(``rescue-companion replay``): it owns the detector, the tracker and the reporting
policy, and never touches a link or a file. The caller supplies the frame, the pose
history, and what to do with the decisions.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import Counter
from dataclasses import dataclass, field

from companion.config import Config
from companion.reporting import Decision, ReportPolicy
from companion.sources import Frame
from companion.vision import Detector, FrameGeometry, assess
from fusion.camera import CameraModel
from fusion.errors import GeolocationRejected, PoseUnavailable
from fusion.geolocate import geolocate, in_view
from fusion.pose import PoseHistory
from fusion.registry import TrackEvent
from fusion.tracker import VictimTracker
from fusion.types import Detection, Observation, PoseSample

PARTS = {"hand", "face"}  # cues of a lone exposed part (people backend)

log = logging.getLogger(__name__)


@dataclass
class FrameOutcome:
    """What one frame produced (for status, tests and replay)."""

    t_unix_s: float
    pose: PoseSample | None
    detections: list[Detection] = field(default_factory=list)
    observations: list[Observation] = field(default_factory=list)
    # Each detection that became an observation, with it (for evidence pictures).
    located: list[tuple[Detection, Observation]] = field(default_factory=list)
    events: list[TrackEvent] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)
    skipped: str = ""  # why the frame was not used, if it was not
    vision_ms: float = 0.0


@dataclass
class PipelineCounters:
    frames: int = 0
    frames_without_pose: int = 0
    detections: int = 0
    observations: int = 0
    rejected: Counter[str] = field(default_factory=Counter)


class Pipeline:
    """Frames in, tracker events and report decisions out. Owned by one thread."""

    def __init__(
        self,
        config: Config,
        camera: CameraModel,
        detector: Detector,
        tracker: VictimTracker,
        policy: ReportPolicy,
    ) -> None:
        self.config = config
        self.camera = camera
        self.detector = detector
        self.tracker = tracker
        self.policy = policy
        self.counters = PipelineCounters()
        self._geo = config.geolocation
        # Where a tentative track not detected loses support (see TrackerParams).
        self._miss_geo = dataclasses.replace(
            self._geo,
            max_range_m=min(self._geo.max_range_m, config.tracker.miss_max_range_m),
        )

    def process(self, frame: Frame, poses: PoseHistory) -> FrameOutcome:
        """Run one frame; its pose comes from ``poses`` at the frame's capture time."""
        self.counters.frames += 1
        try:
            pose = poses.pose_at(frame.t_mono_s, self._geo.max_pose_extrapolation_s)
        except PoseUnavailable as exc:
            self.counters.frames_without_pose += 1
            return FrameOutcome(frame.t_unix_s, None, skipped=f"no pose: {exc.reason}")
        start = time.perf_counter()
        geometry = FrameGeometry.from_pose(
            self.camera, pose, self._geo, self.config.detector.body_silhouette_fill
        )
        detections = self.detector.detect(frame.image, geometry, frame.t_mono_s)
        located = [
            (d, o) for d in detections if (o := self._observe(d, pose, geometry, frame)) is not None
        ]
        observations = [o for _, o in located]
        vision_ms = (time.perf_counter() - start) * 1000.0
        events = self.tracker.update(
            observations,
            frame.t_unix_s,
            lambda n, e: in_view(self.camera, pose, n, e, self._miss_geo),
        )
        decisions = self.policy.decide(events, self.tracker.victims(), frame.t_unix_s)
        self.counters.detections += len(detections)
        self.counters.observations += len(observations)
        return FrameOutcome(
            frame.t_unix_s,
            pose,
            detections,
            observations,
            located,
            events,
            decisions,
            "",
            vision_ms,
        )

    def _observe(
        self, det: Detection, pose: PoseSample, geometry: FrameGeometry, frame: Frame
    ) -> Observation | None:
        assessment = assess(det, geometry)
        if assessment is None:
            self.counters.rejected["off the usable floor"] += 1
            return None
        x, _y, w, _h = det.bbox_xywh_px
        cut = "person" in det.cues and (x <= 1 or x + w >= frame.image.shape[1] - 1)
        try:
            fix = geolocate(self.camera, pose, det.u_px, det.v_px, self._geo, cut)
        except GeolocationRejected as exc:
            self.counters.rejected[exc.reason.split(":")[0]] += 1
            return None
        return Observation(
            t_unix_s=frame.t_unix_s,
            north_m=fix.north_m,
            east_m=fix.east_m,
            cov_ne_m2=fix.cov_ne_m2,
            visibility_pct=assessment.visibility_pct,
            quality=det.score,
            range_m=fix.range_m,
            part_only=bool(PARTS & set(det.cues)) and "person" not in det.cues,
        )
