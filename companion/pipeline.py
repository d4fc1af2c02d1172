"""One frame through the pipeline: pose at capture time, vision, geolocation, tracking.

The same ``Pipeline`` runs live (``rescue-companion run``) and offline
(``rescue-companion replay``): it owns the detector, the tracker and the reporting
policy, and never touches a link or a file. The caller supplies the frame, the pose
history, and what to do with the decisions.

With a thermal camera (``ThermalEye``) its frames go through ``process_thermal``: the
thermal detector, the same geolocation with the thermal camera's model and its own
pixel noise, and the same tracker, so a person seen by both cameras is one victim.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from companion.config import Config
from companion.coverage import LIT_LUMA
from companion.reporting.policy import Decision, ReportPolicy
from companion.sources.base import Frame
from companion.sources.thermal import ThermalFrame
from companion.vision.base import Detector, FrameGeometry
from companion.vision.thermal import UNSETTLED
from companion.vision.visibility import assess
from fusion.camera import CameraModel, rotation_zyx
from fusion.errors import GeolocationRejected, PoseUnavailable
from fusion.geolocate import geolocate, in_view
from fusion.params import GeolocationParams
from fusion.pose import PoseHistory
from fusion.registry import TrackEvent
from fusion.tracker import VictimTracker
from fusion.types import Detection, Observation, PoseSample, Sensor

# Cues of a lone exposed part: a hand or a face (people backend), a small warm area
# (thermal detector).
PARTS = {"hand", "face", "warm_part"}

log = logging.getLogger(__name__)


class ThermalDetecting(Protocol):
    """What the pipeline needs of a thermal detector (companion.vision.thermal)."""

    def detect(
        self, temps_c: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]: ...


@dataclass(frozen=True)
class ThermalEye:
    """The thermal camera as the pipeline sees it: its model, its detector, and the
    1-sigma of a warm blob's centre in its pixels (a Lepton pixel is about 2 cm at 3 m,
    where a colour pixel is 0.6 cm, so the same pixel noise is a coarser fix)."""

    camera: CameraModel
    detector: ThermalDetecting
    pixel_sigma_px: float = 1.5


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
    sensor: Sensor = Sensor.COLOUR


@dataclass
class PipelineCounters:
    frames: int = 0
    thermal_frames: int = 0
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
        thermal: ThermalEye | None = None,
    ) -> None:
        self.config = config
        self.thermal = thermal
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
        self._thermal_geo = (
            dataclasses.replace(self._geo, pixel_sigma_px=thermal.pixel_sigma_px)
            if thermal is not None
            else self._geo
        )
        self._thermal_miss_geo = dataclasses.replace(
            self._thermal_geo, max_range_m=self._miss_geo.max_range_m
        )

    def process(self, frame: Frame, poses: PoseHistory) -> FrameOutcome:
        """Run one colour frame; its pose comes from ``poses`` at its capture time."""
        self.counters.frames += 1
        width_px = frame.image.shape[1]
        return self._run(
            frame.t_mono_s,
            frame.t_unix_s,
            poses,
            self.camera,
            self._geo,
            self._miss_geo,
            lambda geometry: self.detector.detect(frame.image, geometry, frame.t_mono_s),
            lambda pose: _clear_look(frame.image, self.camera, pose, self._miss_geo),
            lambda det: (
                "person" in det.cues
                and (det.bbox_xywh_px[0] <= 1 or sum(det.bbox_xywh_px[::2]) >= width_px - 1)
            ),
            Sensor.COLOUR,
        )

    def process_thermal(self, frame: ThermalFrame, poses: PoseHistory) -> FrameOutcome:
        """Run one thermal frame (``thermal`` must be set) through the same tracker. A
        warm region cut by the frame's side is a body that may go on beyond it: its
        floor point gets the same doubt across the ray as a colour one's."""
        if self.thermal is None:
            raise RuntimeError("process_thermal without a thermal camera")
        self.counters.thermal_frames += 1
        detector = self.thermal.detector
        width_px = frame.temps_c.shape[1]
        return self._run(
            frame.t_mono_s,
            frame.t_unix_s,
            poses,
            self.thermal.camera,
            self._thermal_geo,
            self._thermal_miss_geo,
            lambda geometry: detector.detect(frame.temps_c, geometry, frame.t_mono_s),
            None,
            lambda det: det.bbox_xywh_px[0] <= 1 or sum(det.bbox_xywh_px[::2]) >= width_px - 1,
            Sensor.THERMAL,
        )

    def _run(
        self,
        t_mono_s: float,
        t_unix_s: float,
        poses: PoseHistory,
        camera: CameraModel,
        geo: GeolocationParams,
        miss_geo: GeolocationParams,
        detect: Callable[[FrameGeometry], list[Detection]],
        clear_look: Callable[[PoseSample], Callable[[float, float], bool]] | None,
        cut_by_frame: Callable[[Detection], bool],
        sensor: Sensor,
    ) -> FrameOutcome:
        try:
            pose = poses.pose_at(t_mono_s, geo.max_pose_extrapolation_s)
        except PoseUnavailable as exc:
            self.counters.frames_without_pose += 1
            return FrameOutcome(t_unix_s, None, skipped=f"no pose: {exc.reason}", sensor=sensor)
        start = time.perf_counter()
        geometry = FrameGeometry.from_pose(
            camera, pose, geo, self.config.detector.body_silhouette_fill
        )
        detections = detect(geometry)
        located = []
        for det in detections:
            obs = self._observe(det, pose, geometry, t_unix_s, camera, geo, cut_by_frame(det))
            if obs is not None:
                located.append((det, dataclasses.replace(obs, sensor=sensor)))
        observations = [o for _, o in located]
        vision_ms = (time.perf_counter() - start) * 1000.0
        events = self.tracker.update(
            observations,
            t_unix_s,
            lambda n, e: in_view(camera, pose, n, e, miss_geo),
            sensor,
            clear_look(pose) if clear_look is not None else None,
        )
        decisions = self.policy.decide(events, self.tracker.victims(), t_unix_s)
        self.counters.detections += len(detections)
        self.counters.observations += len(observations)
        return FrameOutcome(
            t_unix_s,
            pose,
            detections,
            observations,
            located,
            events,
            decisions,
            "",
            vision_ms,
            sensor,
        )

    def _observe(
        self,
        det: Detection,
        pose: PoseSample,
        geometry: FrameGeometry,
        t_unix_s: float,
        camera: CameraModel,
        geo: GeolocationParams,
        cut: bool,
    ) -> Observation | None:
        assessment = assess(det, geometry)
        if assessment is None:
            self.counters.rejected["off the usable floor"] += 1
            return None
        try:
            fix = geolocate(camera, pose, det.u_px, det.v_px, geo, cut)
        except GeolocationRejected as exc:
            self.counters.rejected[exc.reason.split(":")[0]] += 1
            return None
        return Observation(
            t_unix_s=t_unix_s,
            north_m=fix.north_m,
            east_m=fix.east_m,
            cov_ne_m2=fix.cov_ne_m2,
            visibility_pct=assessment.visibility_pct,
            quality=det.score,
            range_m=fix.range_m,
            part_only=bool(PARTS & set(det.cues)) and "person" not in det.cues,
            supports=UNSETTLED not in det.cues,
        )


def _clear_look(
    image: np.ndarray, camera: CameraModel, pose: PoseSample, geo: GeolocationParams
) -> Callable[[float, float], bool]:
    """Where the colour frame (BGR) had a clear look at the floor: in view within
    ``geo``'s range and lit there (the mean luma of the 16x16 pixels around the point
    at least LIT_LUMA, the level the person models work at; docs/VISION.md)."""
    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    floor_down_m = pose.down_m + geo.floor_down_m

    def clear(north_m: float, east_m: float) -> bool:
        # in_view keeps the point 10 px inside the image: its patch is never empty
        if not in_view(camera, pose, north_m, east_m, geo):
            return False
        px, _ = camera.project_ned(np.array([[north_m, east_m, floor_down_m]]), vehicle, r_ned_body)
        u, v = int(px[0, 0]), int(px[0, 1])
        b, g, r = image[max(0, v - 8) : v + 8, max(0, u - 8) : u + 8].reshape(-1, 3).mean(axis=0)
        return float(0.114 * b + 0.587 * g + 0.299 * r) / 255.0 >= LIT_LUMA

    return clear
