"""The companion's configuration: each section a frozen dataclass, its defaults and
its range checks (``__post_init__``); ``Config`` holds them all. The TOML file is
read into them by config_load.py.

``docs/CONFIG.md`` documents every key; ``systemd/config.example.toml`` is a full,
commented example. Both are checked against these classes by the tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from fusion.params import GeolocationParams, TrackerParams
from mavlink_io.linkspec import parse_link
from mavlink_io.picture import MAX_PICTURE_BYTES
from mavlink_io.vehicle import MAX_STREAM_RATE_HZ


@dataclass(frozen=True)
class VehicleConfig:
    """The link to the autopilot."""

    url: str = "udpin:127.0.0.1:14550"  # serial:/dev/ttyAMA0:921600 on the Pi
    system_id: int = 0  # 0: learn it from the autopilot's HEARTBEAT
    component_id: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    heartbeat_timeout_s: float = 3.0  # silence after which the link counts as lost
    attitude_rate_hz: float = 20.0
    local_position_rate_hz: float = 20.0
    global_position_rate_hz: float = 5.0
    reopen_max_backoff_s: float = 1.0  # a vanished serial device is retried at most this far apart
    pose_history_s: float = 30.0  # how much pose history is kept for interpolation

    def __post_init__(self) -> None:
        parse_link(self.url)
        if not 0 <= self.system_id <= 255:
            raise ValueError(f"system_id = {self.system_id}: must be in 0..255 (0 = learn)")
        if not 1 <= self.component_id <= 255:
            raise ValueError(f"component_id = {self.component_id}: must be in 1..255")
        for name in ("heartbeat_timeout_s", "reopen_max_backoff_s", "pose_history_s"):
            _positive(self, name)
        for name in ("attitude_rate_hz", "local_position_rate_hz", "global_position_rate_hz"):
            value = getattr(self, name)
            if not 0 < value <= MAX_STREAM_RATE_HZ:
                raise ValueError(f"{name} = {value!r}: must be in (0, {MAX_STREAM_RATE_HZ:g}] Hz")


@dataclass(frozen=True)
class HqConfig:
    """How the full dialect reports reach rescue-hq."""

    url: str = ""  # direct link, e.g. udpout:10.0.0.2:14600; "" = none
    tunnel: bool = True  # also send them inside TUNNEL over the vehicle link
    resend_initial_s: float = 1.0  # first resend of an unacknowledged report
    resend_max_s: float = 30.0  # the backoff doubles up to this
    hq_timeout_s: float = 10.0  # HQ counts as unheard after this silence

    def __post_init__(self) -> None:
        if self.url:
            parse_link(self.url)
        for name in ("resend_initial_s", "resend_max_s", "hq_timeout_s"):
            _positive(self, name)
        if self.resend_max_s < self.resend_initial_s:
            raise ValueError(f"resend_max_s = {self.resend_max_s}: must be >= resend_initial_s")


@dataclass(frozen=True)
class SigningConfig:
    """MAVLink 2 message signing."""

    enabled: bool = False
    key_file: Path | None = None  # 32-byte key (raw, or 64 hex chars); mode 0600
    link_id: int = 0

    def __post_init__(self) -> None:
        if self.enabled and self.key_file is None:
            raise ValueError("key_file: required when enabled = true")
        if not 0 <= self.link_id <= 255:
            raise ValueError(f"link_id = {self.link_id}: must be in 0..255")


@dataclass(frozen=True)
class MountConfig:
    """The camera's place on the vehicle, in the body frame FRD."""

    x_m: float = 0.15  # forward of the reference point
    y_m: float = 0.0  # right
    z_m: float = -0.20  # down (negative: above)
    roll_deg: float = 0.0
    pitch_deg: float = -12.0  # negative: tilted down
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class CameraConfig:
    """Where frames come from and the camera's geometry."""

    source: str = "sim"  # sim | device:N | /dev/videoN | file:PATH | frames:DIR | picamera2 | gstreamer:PIPELINE | rtsp://...
    width_px: int = 640
    height_px: int = 480
    fps: float = 10.0
    hfov_deg: float = 70.0  # used when neither fx_px nor a calibration file is given
    fx_px: float = 0.0  # 0: from hfov_deg
    fy_px: float = 0.0
    cx_px: float = 0.0  # 0 with fx_px 0: the image centre
    cy_px: float = 0.0
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)  # k1 k2 p1 p2 k3
    calibration_file: Path | None = None  # OpenCV FileStorage YAML/XML or ROS camera_info YAML
    mount: MountConfig = field(default_factory=MountConfig)
    reopen_max_backoff_s: float = 5.0
    # A live camera that sends no frame for this long is closed and reopened (a camera
    # that stays connected but silent is otherwise never noticed); 0: never. Not for
    # file: and frames: recordings.
    stall_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        _check_camera(self)


def _check_camera(cam: CameraConfig | ThermalConfig) -> None:
    """The checks [camera] and [thermal] share: source, size, rate, optics, reopening."""
    if not cam.source.strip():
        raise ValueError("source: must not be empty")
    if cam.width_px <= 0 or cam.height_px <= 0:
        raise ValueError(f"width_px x height_px = {cam.width_px}x{cam.height_px}: must be positive")
    _positive(cam, "fps")
    if not 1.0 <= cam.hfov_deg < 179.0:
        raise ValueError(f"hfov_deg = {cam.hfov_deg}: must be in [1, 179)")
    if (cam.fx_px > 0) != (cam.fy_px > 0) or cam.fx_px < 0 or cam.fy_px < 0:
        raise ValueError("fx_px, fy_px: give both (> 0) or neither (0)")
    if len(cam.distortion) not in (0, 4, 5):
        raise ValueError(
            f"distortion = {list(cam.distortion)}: give 4 or 5 coefficients (k1 k2 p1 p2 [k3])"
        )
    _positive(cam, "reopen_max_backoff_s")
    if not (math.isfinite(cam.stall_timeout_s) and cam.stall_timeout_s >= 0.0):
        raise ValueError(f"stall_timeout_s = {cam.stall_timeout_s}: must be >= 0 (0: never)")


# The BlazePose landmark model the people detector loads (pose_landmark_<name>.tflite).
PoseLandmarks = Literal["full", "lite"]


@dataclass(frozen=True)
class DetectorConfig:
    """Which detector runs, and its settings."""

    backend: Literal["people", "classic", "dnn", "hog"] = "people"
    enhance: bool = True  # dark-scene enhancement before detection
    min_score: float = 0.5
    dnn_model: Path | None = None  # ONNX file, YOLO-style output
    dnn_input_px: int = 640  # square network input
    dnn_person_class_ids: tuple[int, ...] = (0,)
    dnn_nms_iou: float = 0.45
    dnn_output_layout: Literal["auto", "yolov8", "yolov5"] = "auto"  # [1,4+nc,N] | [1,N,5+nc]
    box_fill_ratio: float = 0.5  # dnn/hog: share of a person's box that is body (visible area)
    work_width_px: int = 320  # classic: frames are reduced to this width before detection
    body_silhouette_fill: float = 0.75  # lying adult's silhouette / its length x width rectangle
    model_dir: Path | None = None  # people: folder of the model files (None: the default one)
    # people: the BlazePose landmark model, "full" or "lite" (faster, finds fewer buried
    # people: docs/VISION.md "Which landmark model")
    pose_landmarks: PoseLandmarks = "full"
    # people: CPU threads each model may use. 1 leaves the Pi's other cores to the link,
    # camera and video threads; 2 cut a frame from 49 to 33 ms on two cores here
    # (BENCHMARKS.md real_images), for a Pi that cannot keep its frame rate on one.
    model_threads: int = 1

    def __post_init__(self) -> None:
        if not 1 <= self.model_threads <= 16:
            raise ValueError(f"model_threads = {self.model_threads}: must be 1..16")
        if not 0.0 <= self.min_score <= 1.0:
            raise ValueError(f"min_score = {self.min_score}: must be in [0, 1]")
        if self.backend == "dnn" and self.dnn_model is None:
            raise ValueError("dnn_model: required with backend = 'dnn'")
        if self.dnn_input_px < 32 or self.dnn_input_px % 32:
            raise ValueError(f"dnn_input_px = {self.dnn_input_px}: must be a multiple of 32, >= 32")
        if not 0.0 < self.dnn_nms_iou <= 1.0:
            raise ValueError(f"dnn_nms_iou = {self.dnn_nms_iou}: must be in (0, 1]")
        if not 0.0 < self.box_fill_ratio <= 1.0:
            raise ValueError(f"box_fill_ratio = {self.box_fill_ratio}: must be in (0, 1]")
        if self.work_width_px < 80:
            raise ValueError(f"work_width_px = {self.work_width_px}: must be >= 80")
        if not 0.0 < self.body_silhouette_fill <= 1.0:
            raise ValueError(
                f"body_silhouette_fill = {self.body_silhouette_fill}: must be in (0, 1]"
            )


# ThermalDetectorParams lives with the thermal detector; companion.vision imports
# DetectorConfig from this module, so it can only be imported once that is defined.
from companion.vision.thermal_params import ThermalDetectorParams  # noqa: E402


@dataclass(frozen=True)
class ThermalConfig:
    """The thermal camera (absent section: none, colour camera only)."""

    source: str = "lepton"  # lepton | lepton:/dev/videoN | infiray:/dev/videoN | frames:DIR
    width_px: int = 160  # the temperature picture (InfiRay P2 Pro / TC001: 256 x 192)
    height_px: int = 120
    fps: float = 8.7
    hfov_deg: float = (
        57.0  # FLIR Lepton 3.5; used when neither fx_px nor a calibration file is given
    )
    fx_px: float = 0.0  # 0: from hfov_deg
    fy_px: float = 0.0
    cx_px: float = 0.0  # 0 with fx_px 0: the image centre
    cy_px: float = 0.0
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)  # k1 k2 p1 p2 k3
    calibration_file: Path | None = None  # as camera.calibration_file
    # Of the scene (skin 0.98); the cameras report temperatures as if it were 1.
    emissivity: float = 0.98
    mount: MountConfig = field(default_factory=MountConfig)
    reopen_max_backoff_s: float = 5.0
    stall_timeout_s: float = 5.0  # as camera.stall_timeout_s
    detector: ThermalDetectorParams = field(default_factory=ThermalDetectorParams)

    def __post_init__(self) -> None:
        from companion.sources.base import CameraError
        from companion.sources.thermal import parse_thermal_source

        _check_camera(self)
        try:
            parse_thermal_source(self.source)
        except CameraError as exc:
            raise ValueError(str(exc)) from None
        if not (math.isfinite(self.emissivity) and 0.1 < self.emissivity <= 1.0):
            raise ValueError(f"emissivity = {self.emissivity}: must be in (0.1, 1]")


@dataclass(frozen=True)
class ReportingConfig:
    """What is told to the HQ, and when."""

    statustext: bool = True  # STATUSTEXT that a stock QGC shows and speaks
    status_period_s: float = 1.0  # RESCUE_STATUS and our HEARTBEAT period
    move_threshold_sigma: float = 1.0  # re-report after moving this many sigmas
    move_min_m: float = 0.3  # ... and at least this far
    update_min_interval_s: float = 5.0  # quiet updates of one victim at most this often
    announce_severity: int = 5  # MAV_SEVERITY of a new LIGHT/MEDIUM victim (<= 5: spoken)

    def __post_init__(self) -> None:
        _positive(self, "status_period_s")
        _positive(self, "move_threshold_sigma")
        if not (self.move_min_m >= 0 and self.update_min_interval_s >= 0):
            raise ValueError("move_min_m and update_min_interval_s must be >= 0")
        if not 0 <= self.announce_severity <= 7:
            raise ValueError(
                f"announce_severity = {self.announce_severity}: must be a MAV_SEVERITY 0..7"
            )


@dataclass(frozen=True)
class PathsConfig:
    """Where state and recordings go."""

    state_dir: Path = Path("/var/lib/rescue-companion")  # SQLite registry and outbox
    tlog_dir: Path | None = None  # None: state_dir/tlogs
    tlog_max_mb: float = 64.0  # rotate the tlog at this size
    record_frames: bool = False  # also save camera frames for replay

    def __post_init__(self) -> None:
        _positive(self, "tlog_max_mb")

    @property
    def tlogs(self) -> Path:
        return self.tlog_dir if self.tlog_dir is not None else self.state_dir / "tlogs"


@dataclass(frozen=True)
class VideoConfig:
    """The live camera view with the detections drawn, for QGC's video widget:
    H.264 (libx264) in MPEG-TS over UDP, advertised by the camera protocol."""

    enabled: bool = True
    host: str = ""  # where QGC runs; "" = the host of [hq] url (QGC beside rescue-hq)
    port: int = 5600  # QGC's video port (VIDEO_STREAM_INFORMATION tells QGC)
    component_id: int = 100  # the camera's MAVLink component: QGC looks for cameras at 100-105
    bitrate_kbps: float = 1000.0
    width_px: int = 640
    height_px: int = 480
    fps: float = 10.0

    def __post_init__(self) -> None:
        if not 1 <= self.port <= 65535:
            raise ValueError(f"port = {self.port}: must be 1..65535")
        if not 100 <= self.component_id <= 105:
            raise ValueError(
                f"component_id = {self.component_id}: must be 100..105 "
                "(MAV_COMP_ID_CAMERA..CAMERA6, where QGC looks for cameras)"
            )
        if not 50.0 <= self.bitrate_kbps <= 20000.0:
            raise ValueError(f"bitrate_kbps = {self.bitrate_kbps}: must be 50..20000")
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if not (16 <= value <= 1920 and value % 2 == 0):
                raise ValueError(f"{name} = {value}: must be even, 16..1920")
        if not 0.5 <= self.fps <= 30.0:
            raise ValueError(f"fps = {self.fps}: must be 0.5..30")


@dataclass(frozen=True)
class PicturesConfig:
    """Each confirmed victim's evidence picture for rescue-hq (companion/reporting/pictures.py)."""

    enabled: bool = True
    max_bytes: int = 6000  # the JPEG's size at most (quality, then scale, are lowered)
    width_px: int = 240  # the crop around the victim is scaled to this width
    rate_bytes_s: float = 1000.0  # picture bytes a second at most on the links (after reports)
    min_gain: float = 0.25  # a new picture replaces the kept one when its score is 25 % higher
    min_interval_s: float = 10.0  # and at most this often per victim

    def __post_init__(self) -> None:
        if not 500 <= self.max_bytes <= MAX_PICTURE_BYTES:
            raise ValueError(f"max_bytes = {self.max_bytes}: must be 500..{MAX_PICTURE_BYTES}")
        if not 32 <= self.width_px <= 1280:
            raise ValueError(f"width_px = {self.width_px}: must be 32..1280")
        if not (math.isfinite(self.rate_bytes_s) and 100.0 <= self.rate_bytes_s <= 100_000.0):
            raise ValueError(f"rate_bytes_s = {self.rate_bytes_s}: must be 100..100000")
        if not (math.isfinite(self.min_gain) and 0.0 <= self.min_gain <= 10.0):
            raise ValueError(f"min_gain = {self.min_gain}: must be 0..10")
        if not (math.isfinite(self.min_interval_s) and 0.0 <= self.min_interval_s <= 3600.0):
            raise ValueError(f"min_interval_s = {self.min_interval_s}: must be 0..3600")


@dataclass(frozen=True)
class CoverageConfig:
    """The searched-area map's transport to rescue-hq (companion/reporting/coverage_sender.py)."""

    rate_bytes_s: float = 300.0  # its bytes a second at most on the links (after pictures)
    period_s: float = 10.0  # the changed cells are gathered and sent this often at most

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_bytes_s) and 50.0 <= self.rate_bytes_s <= 100_000.0):
            raise ValueError(f"rate_bytes_s = {self.rate_bytes_s}: must be 50..100000")
        if not (math.isfinite(self.period_s) and 1.0 <= self.period_s <= 3600.0):
            raise ValueError(f"period_s = {self.period_s}: must be 1..3600")


@dataclass(frozen=True)
class LooksConfig:
    """Closer looks: short GUIDED detours to a candidate the companion cannot settle
    (companion/looks/, docs/LOOKS.md). Off unless enabled here or by RC_LOOK_ON."""

    enabled: bool = False
    view_min_m: float = 1.0  # the viewpoint is this far from the candidate at least...
    view_max_m: float = 1.5  # ...and at most
    beside_path_m: float = 0.5  # how far beside the path already driven a viewpoint may be
    clearance_m: float = 0.9  # no viewpoint this close to any victim or candidate
    max_detour_m: float = 8.0  # candidates farther than this from the rover are not visited
    look_s: float = 4.0  # time spent looking at the viewpoint
    look_budget_s: float = 60.0  # one look, from leaving the route to being back in AUTO
    mission_budget_s: float = 300.0  # all looks of this run together
    # A look of the companion's own starts only while the looks so far took at most
    # this share of the time the rover has driven its route (armed, in AUTO).
    route_share_pct: float = 10.0
    stuck_s: float = 8.0  # no 0.2 m of progress towards the viewpoint for this long: stuck
    ack_timeout_s: float = 2.0  # a mode or mission command unanswered this long: aborted
    tentative_min_s: float = 5.0  # a tentative track this old deserves a look
    urgency_margin_pct: float = 4.0  # visibility this close to 10 or 50 %: urgency uncertain

    def __post_init__(self) -> None:
        for name in (
            "view_min_m",
            "view_max_m",
            "beside_path_m",
            "clearance_m",
            "max_detour_m",
            "look_s",
            "look_budget_s",
            "mission_budget_s",
            "route_share_pct",
            "stuck_s",
            "ack_timeout_s",
            "tentative_min_s",
            "urgency_margin_pct",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 < value <= 3600):
                raise ValueError(f"{name} = {value!r}: must be a number in (0, 3600]")
        if not 0.5 <= self.view_min_m <= self.view_max_m <= 5.0:
            raise ValueError(
                f"view_min_m = {self.view_min_m}, view_max_m = {self.view_max_m}: "
                "must satisfy 0.5 <= view_min_m <= view_max_m <= 5"
            )
        if self.clearance_m >= self.view_min_m:
            raise ValueError(
                f"clearance_m = {self.clearance_m}: must be below view_min_m = {self.view_min_m}"
            )
        if self.look_budget_s > self.mission_budget_s:
            raise ValueError(
                f"look_budget_s = {self.look_budget_s}: must not exceed "
                f"mission_budget_s = {self.mission_budget_s}"
            )
        if self.route_share_pct > 100:
            raise ValueError(f"route_share_pct = {self.route_share_pct}: must be <= 100")
        if self.urgency_margin_pct > 20:
            raise ValueError(f"urgency_margin_pct = {self.urgency_margin_pct}: must be <= 20")


@dataclass(frozen=True)
class Config:
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    hq: HqConfig = field(default_factory=HqConfig)
    signing: SigningConfig = field(default_factory=SigningConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    geolocation: GeolocationParams = field(default_factory=GeolocationParams)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    reporting: ReportingConfig = field(default_factory=ReportingConfig)
    paths: PathsConfig = field(default_factory=PathsConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    pictures: PicturesConfig = field(default_factory=PicturesConfig)
    coverage: CoverageConfig = field(default_factory=CoverageConfig)
    looks: LooksConfig = field(default_factory=LooksConfig)
    thermal: ThermalConfig | None = None  # built only when the file has a [thermal] section


def _positive(owner: object, name: str) -> None:
    value = getattr(owner, name)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} = {value!r}: must be a positive number")
