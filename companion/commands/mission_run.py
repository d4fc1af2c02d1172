"""One mission through the live pipeline, offline: the autopilot's messages and the
cameras' frames in, in time order; victims, reports and where the cameras looked out.

``MissionRun`` is what the service's processing thread does to a frame (the same
``Pipeline``, tracker, reporting policy and coverage), without links, threads or a
wall clock: ``rescue-companion replay`` drives it from a tlog and frame folders
(replay.py), and the simulator's closed loop (scenarios/inloop.py) from its own
autopilot and renderers while the closer looks drive the rover.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from companion.calibration import camera_model
from companion.config import Config
from companion.coverage import CoverageMapper
from companion.pipeline import FrameOutcome, Pipeline, ThermalEye
from companion.reporting.policy import ReportPolicy
from companion.sources.base import CameraError, Frame
from companion.sources.thermal import ThermalFrame
from companion.vision.backends import make_detector
from companion.vision.thermal import ThermalDetector
from fusion.coverage import CoverageGrid
from fusion.pose import PoseHistory
from fusion.registry import Victim
from fusion.tracker import VictimTracker
from fusion.types import GlobalOrigin, TrackState, VictimReport
from mavlink_io.codec import MavMessage
from mavlink_io.telemetry import TelemetryDecoder, is_autopilot_heartbeat

log = logging.getLogger(__name__)

LOOKAHEAD_S = 0.25  # telemetry read past a frame before it is processed


@dataclass(frozen=True)
class ReplayReport:
    """One report the live service would have sent: at the frame's capture time, the
    victim as reported, the report's flags and the victim it was merged into."""

    t_unix_s: float
    report: VictimReport
    flags: int
    merged_into: int | None


@dataclass
class ReplayResult:
    victims: list[Victim]
    merged: list[Victim]
    origin: GlobalOrigin | None
    robot_sysid: int
    frames: int = 0
    frames_skipped: int = 0  # unreadable or truncated image files
    frames_without_pose: int = 0
    thermal_frames: int = 0
    thermal_frames_skipped: int = 0  # unreadable files, and frames that were no evidence
    poses: int = 0
    reboots: int = 0
    first_reported_unix_s: dict[int, float] = field(default_factory=dict)
    route_ne_m: list[tuple[float, float]] = field(default_factory=list)
    floor_down_m: float = 0.0
    reports: list[ReplayReport] = field(default_factory=list)  # in the order decided
    coverage: CoverageGrid = field(default_factory=CoverageGrid)  # where it has looked


class TelemetryFeed:
    """The autopilot's messages, decoded into a pose history as the vehicle link does
    (the message's time plays the part of its arrival time)."""

    def __init__(self, poses: PoseHistory, mono_minus_unix_s: float) -> None:
        self._offset_s = mono_minus_unix_s  # message wall time -> the frames' t_mono_s
        self.poses = poses
        self.decoder = TelemetryDecoder()
        self.sysid = 0
        self.count = 0
        self.reboots = 0
        self.route: list[tuple[float, float]] = []
        self.last_down_m = 0.0

    def handle(self, t_unix_s: float, msg: MavMessage) -> None:
        if is_autopilot_heartbeat(msg, self.sysid):
            if self.sysid == 0:
                self.sysid = msg.get_srcSystem()
                log.info("vehicle system ID %d", self.sysid)
            return
        if self.sysid == 0 or (msg.get_srcSystem(), msg.get_srcComponent()) != (self.sysid, 1):
            return
        update = self.decoder.handle(msg, t_unix_s + self._offset_s)
        if update.rebooted:
            self.reboots += 1
            log.warning("the autopilot rebooted at %.3f; pose history cleared", t_unix_s)
            self.poses.clear()
        if update.pose is not None:
            self.poses.add(update.pose)
            self.count += 1
            self.last_down_m = update.pose.down_m
            if not self.route or _far(self.route[-1], (update.pose.north_m, update.pose.east_m)):
                self.route.append((update.pose.north_m, update.pose.east_m))


def _far(a: tuple[float, float], b: tuple[float, float], step_m: float = 0.05) -> bool:
    return abs(a[0] - b[0]) + abs(a[1] - b[1]) > step_m


class MissionRun:
    """See the module docstring. ``mono_minus_unix_s``: the frames' monotonic clock
    minus the messages' Unix time; ``thermal``: the config's thermal camera is used
    (its ``[thermal]`` section must be there)."""

    def __init__(self, config: Config, mono_minus_unix_s: float, thermal: bool) -> None:
        self.config = config
        self.poses = PoseHistory(config.vehicle.pose_history_s)
        self.telemetry = TelemetryFeed(self.poses, mono_minus_unix_s)
        self.tracker = VictimTracker(config.tracker)
        eye = None
        if thermal:
            if config.thermal is None:
                raise CameraError(
                    "thermal frames, but the config has no [thermal] section: the thermal "
                    "camera's size, field of view and mount are unknown"
                )
            eye = ThermalEye(camera_model(config.thermal), ThermalDetector(config.thermal.detector))
        self.pipeline = Pipeline(
            config,
            camera_model(config.camera),
            make_detector(config.detector),
            self.tracker,
            ReportPolicy(
                config.reporting.move_threshold_sigma,
                config.reporting.move_min_m,
                config.reporting.update_min_interval_s,
            ),
            eye,
        )
        self.coverage = CoverageMapper(
            CoverageGrid(), config.geolocation, self.pipeline.camera, eye.camera if eye else None
        )
        self.first_reported: dict[int, float] = {}
        self.reports: list[ReplayReport] = []

    def message(self, t_unix_s: float, msg: MavMessage) -> None:
        self.telemetry.handle(t_unix_s, msg)

    def colour(self, frame: Frame) -> FrameOutcome:
        outcome = self.pipeline.process(frame, self.poses)
        self.coverage.add(outcome.pose, outcome.sensor, frame.image)
        self._decided(outcome)
        return outcome

    def thermal(self, frame: ThermalFrame) -> FrameOutcome:
        outcome = self.pipeline.process_thermal(frame, self.poses)
        self.coverage.add(outcome.pose, outcome.sensor)
        self._decided(outcome)
        return outcome

    def _decided(self, outcome: FrameOutcome) -> None:
        t = self.telemetry
        floor_down_m = t.last_down_m + self.config.geolocation.floor_down_m
        for decision in outcome.decisions:
            v = decision.victim
            self.first_reported.setdefault(v.victim_id, outcome.t_unix_s)
            report = v.to_report(t.sysid, floor_down_m, t.decoder.origins.origin)
            self.reports.append(
                ReplayReport(outcome.t_unix_s, report, decision.flags, v.merged_into)
            )

    def result(self, frames_skipped: int = 0, thermal_frames_skipped: int = 0) -> ReplayResult:
        everything = self.tracker.victims()
        t = self.telemetry
        return ReplayResult(
            victims=[v for v in everything if v.state != TrackState.MERGED],
            merged=[v for v in everything if v.state == TrackState.MERGED],
            origin=t.decoder.origins.origin,
            robot_sysid=t.sysid,
            frames=self.pipeline.counters.frames,
            frames_skipped=frames_skipped,
            frames_without_pose=self.pipeline.counters.frames_without_pose,
            thermal_frames=self.pipeline.counters.thermal_frames,
            thermal_frames_skipped=thermal_frames_skipped,
            poses=t.count,
            reboots=t.reboots,
            first_reported_unix_s=self.first_reported,
            route_ne_m=t.route,
            floor_down_m=t.last_down_m + self.config.geolocation.floor_down_m,
            reports=self.reports,
            coverage=self.coverage.grid,
        )
