"""Record a simulated mission to disk, faster than real time, without sockets.

    DIR/mission.tlog        what the rover sent: 8-byte big-endian Unix µs + packet
    DIR/frames/<µs>.jpg     camera frames named by capture time on the same clock
    DIR/thermal/<µs>.png    thermal frames (16-bit centi-kelvin, 8.7 frames/s, the
                            Lepton beside the colour camera) on the same clock,
                            unless ``thermal`` is off
    DIR/camera.toml         the [camera] (and [thermal]) config the frames were rendered with
    DIR/world.toml          the world
    DIR/ground_truth.json   victims (position, urgency, visibility, first sight), route;
                            with the thermal camera also each victim's
                            warm_visibility_pct (skin and clothing under no opaque
                            debris) and first_warm_in_view_unix_s (its warmth on at
                            least MIN_WARM_VIEW_PX thermal pixels; the scorer takes
                            the earlier of the two cameras), and a "thermal" section
                            (frames, flat-field frames, warm objects)

The rover's streams are those a companion asks for (its VehicleConfig rates:
ATTITUDE and LOCAL_POSITION_NED at 20 Hz, GLOBAL_POSITION_INT at 5 Hz) plus
HEARTBEAT, SYSTEM_TIME, SYS_STATUS and SIM_STATE; GPS_GLOBAL_ORIGIN and
HOME_POSITION come once at the start. Simulation time 0 is ``start_unix_s``.
"""

from __future__ import annotations

import json
import logging
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from fusion.camera import CameraModel
from mavlink_io.convert import usec_from_unix_s
from scenarios import autopilot as ap
from scenarios.camera import (
    THERMAL_FPS,
    default_camera,
    default_thermal_camera,
    write_camera_toml,
)
from scenarios.motion import Trajectory, TruePose, route_of
from scenarios.render import MIN_VIEW_PX, Renderer, RenderOptions, encode_jpeg
from scenarios.thermal import (
    MIN_WARM_VIEW_PX,
    ThermalOptions,
    ThermalRenderer,
    decode_centikelvin_png,
    encode_centikelvin_png,
)
from scenarios.world import World, save_world

log = logging.getLogger(__name__)

TRUTH_FORMAT = "rescue-sim-truth/1"
COMPANION_RATES_HZ: dict[int, float] = {
    ap.ATTITUDE: 20.0,
    ap.LOCAL_POSITION_NED: 20.0,
    ap.GLOBAL_POSITION_INT: 5.0,
    ap.SIM_STATE: 10.0,
}
_PATH_STEP_S = 0.5


class InLoop(Protocol):
    """A companion in the recording's loop (scenarios/inloop.py), on the recording's
    Unix clock: it hears what the autopilot sends, sees each frame as the companion
    would read it back from disk, and what ``step`` returns is sent to the autopilot."""

    def heard(self, t_unix_s: float, packet: bytes) -> None: ...

    def colour(self, t_unix_s: float, image_bgr: np.ndarray) -> None: ...

    def thermal(self, t_unix_s: float, temps_c: np.ndarray) -> None: ...

    def step(self, t_unix_s: float) -> list[bytes]: ...


_STEP_S = 0.05  # how often the companion in the loop is stepped
MISSION_END_S = 2.0  # recorded past the end of the mission


@dataclass(frozen=True)
class RecordResult:
    out_dir: Path
    frames: int
    packets: int
    thermal_frames: int
    duration_s: float
    start_unix_s: float


def _tlog_entry(t_unix_s: float, packet: bytes) -> bytes:
    return struct.pack(">Q", usec_from_unix_s(t_unix_s)) + packet


def record(
    world: World,
    out_dir: Path,
    *,
    duration_s: float | None = None,
    fps: float = 10.0,
    camera: CameraModel | None = None,
    start_unix_s: float | None = None,
    speed_m_s: float = 0.4,
    jpeg_quality: int = 85,
    render_options: RenderOptions | None = None,
    min_view_px: int = MIN_VIEW_PX,
    thermal: bool = True,
    thermal_camera: CameraModel | None = None,
    thermal_fps: float = THERMAL_FPS,
    thermal_options: ThermalOptions | None = None,
    companion: InLoop | None = None,
) -> RecordResult:
    """Simulate and write a mission (see the module docstring). Deterministic for the
    world's seed and start_unix_s. ``thermal``: also the thermal camera's frames.

    With ``companion`` in the loop the rover drives as the autopilot is told (its
    closer looks), so the mission is recorded until the autopilot has driven its whole
    route (and ``MISSION_END_S`` more), at most ``duration_s``; the frames and the
    truth follow the rover where it really went."""
    camera = camera or default_camera()
    thermal_camera = thermal_camera or default_thermal_camera()
    start = time.time() if start_unix_s is None else start_unix_s
    out_dir = Path(out_dir)
    frames_dir = out_dir / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    trajectory = Trajectory(
        world.start_ne_m,
        world.start_heading_rad,
        route_of(world),
        speed_m_s=speed_m_s,
        seed=world.seed,
    )
    pilot = ap.Autopilot(
        trajectory,
        world.origin,
        seed=world.seed,
        unix_of=lambda t: start + t,
        rates_hz=COMPANION_RATES_HZ,
    )
    if duration_s is None:
        duration_s = trajectory.duration_s() + MISSION_END_S
        if companion is not None:  # the looks' detours take longer; at most this
            duration_s = 3.0 * duration_s + 120.0
    # The autopilot's motion is the trajectory's own until the first mode change.
    pose_at: Callable[[float], TruePose] = pilot.drive.pose_at if companion else trajectory.pose_at
    next_step = 0.0 if companion is not None else math.inf
    ended_s: float | None = None
    renderer = Renderer(world, camera, options=render_options)
    first_seen: dict[int, float] = {}
    frames_in_view: dict[int, int] = {}
    max_px: dict[int, int] = {}
    n_frames = n_packets = 0
    frame_period = 1.0 / fps
    next_frame = 0.5 * frame_period  # frames fall between telemetry instants
    warm = _WarmView()
    thermal_dir = out_dir / "thermal"
    thermal_renderer = None
    next_thermal = math.inf
    if thermal:
        thermal_dir.mkdir(parents=True, exist_ok=True)
        thermal_renderer = ThermalRenderer(world, thermal_camera, options=thermal_options)
        next_thermal = 0.25 / thermal_fps  # off the colour frames' and telemetry instants
    t = 0.0
    with (out_dir / "mission.tlog").open("wb") as tlog:
        while True:
            t = min(pilot.next_due_s(), next_frame, next_thermal, next_step)
            if t > duration_s or (ended_s is not None and t > ended_s + MISSION_END_S):
                break
            t = max(t, 0.0)
            for _link, packet in pilot.poll(t):
                tlog.write(_tlog_entry(start + t, packet))
                n_packets += 1
                if companion is not None:
                    companion.heard(start + t, packet)
            if next_frame <= t:
                usec = usec_from_unix_s(start + next_frame)
                result = renderer.render(pose_at(next_frame), frame_key=n_frames)
                jpeg = encode_jpeg(result.image, jpeg_quality)
                (frames_dir / f"{usec}.jpg").write_bytes(jpeg)
                if companion is not None:  # as the companion reads it back
                    decoded = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
                    assert decoded is not None  # our own JPEG
                    companion.colour(usec / 1e6, decoded)
                for vid, px in result.visible_px.items():
                    max_px[vid] = max(max_px.get(vid, 0), px)
                    if px >= min_view_px:
                        frames_in_view[vid] = frames_in_view.get(vid, 0) + 1
                        first_seen.setdefault(vid, usec / 1e6)
                n_frames += 1
                next_frame = (n_frames + 0.5) * frame_period
            if thermal_renderer is not None and next_thermal <= t:
                usec = usec_from_unix_s(start + next_thermal)
                shot = thermal_renderer.render(
                    pose_at(next_thermal), next_thermal, frame_key=warm.frames
                )
                png = encode_centikelvin_png(shot.temps_c)
                (thermal_dir / f"{usec}.png").write_bytes(png)
                if companion is not None and not shot.frozen:  # a frozen frame is skipped
                    companion.thermal(usec / 1e6, decode_centikelvin_png(png))
                warm.add(shot.warm_px, usec / 1e6, shot.frozen)
                next_thermal = (warm.frames + 0.25) / thermal_fps
            if companion is not None and next_step <= t:
                for data in companion.step(start + t):
                    for _link, packet in pilot.handle(0, data, t):
                        tlog.write(_tlog_entry(start + t, packet))
                        n_packets += 1
                        companion.heard(start + t, packet)
                next_step = t + _STEP_S
                if ended_s is None and pilot.drive.mission_done(t):
                    ended_s = t
        duration_s = min(duration_s, t)
    write_recording_toml(out_dir, camera, fps, thermal_camera if thermal else None, thermal_fps)
    save_world(world, out_dir / "world.toml")
    truth = _truth(
        world,
        pose_at,
        trajectory.route,
        start,
        duration_s,
        fps,
        min_view_px,
        first_seen,
        frames_in_view,
        max_px,
    )
    truth["thermal"] = warm.truth(world, thermal_fps) if thermal else None
    if thermal:  # in view of either camera: the scorer takes the earlier
        for entry in truth["victims"]:
            entry["warm_visibility_pct"] = round(
                world.victim(entry["victim_id"]).warm_visibility_pct, 3
            )
            entry["first_warm_in_view_unix_s"] = warm.first_seen.get(entry["victim_id"])
    (out_dir / "ground_truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    log.info(
        "recorded %d frames, %d thermal frames and %d packets (%.1f s) in %s",
        n_frames,
        warm.frames,
        n_packets,
        duration_s,
        out_dir,
    )
    return RecordResult(out_dir, n_frames, n_packets, warm.frames, duration_s, start)


def write_recording_toml(
    out_dir: Path,
    camera: CameraModel,
    fps: float,
    thermal_camera: CameraModel | None,
    thermal_fps: float = THERMAL_FPS,
) -> Path:
    """DIR/camera.toml: the [camera] section of the recording's frames folder and, with
    a thermal camera, the [thermal] one of its thermal folder; the file's path."""
    path = out_dir / "camera.toml"
    thermal = None
    if thermal_camera is not None:
        thermal = (thermal_camera, f"frames:{(out_dir / 'thermal').resolve()}", thermal_fps)
    write_camera_toml(camera, path, f"frames:{(out_dir / 'frames').resolve()}", fps, thermal)
    return path


class _WarmView:
    """What the thermal camera saw of each victim, for the ground truth."""

    def __init__(self) -> None:
        self.frames = 0
        self.frozen = 0
        self.first_seen: dict[int, float] = {}
        self.in_view: dict[int, int] = {}
        self.max_px: dict[int, int] = {}

    def add(self, warm_px: dict[int, int], t_unix_s: float, frozen: bool) -> None:
        self.frames += 1
        if frozen:  # a flat-field frame shows nothing new
            self.frozen += 1
            return
        for vid, px in warm_px.items():
            self.max_px[vid] = max(self.max_px.get(vid, 0), px)
            if px >= MIN_WARM_VIEW_PX:
                self.in_view[vid] = self.in_view.get(vid, 0) + 1
                self.first_seen.setdefault(vid, t_unix_s)

    def truth(self, world: World, fps: float) -> dict[str, Any]:
        return {
            "fps": fps,
            "frames": self.frames,
            "flat_field_frames": self.frozen,
            "min_warm_view_px": MIN_WARM_VIEW_PX,
            "ambient_c": world.floor.temperature_c,
            "victims": [
                {
                    "victim_id": v.victim_id,
                    "warm_visibility_pct": round(v.warm_visibility_pct, 3),
                    "skin_c": v.skin_c,
                    "first_warm_in_view_unix_s": self.first_seen.get(v.victim_id),
                    "frames_warm_in_view": self.in_view.get(v.victim_id, 0),
                    "max_warm_px": self.max_px.get(v.victim_id, 0),
                }
                for v in world.victims
            ],
            "warm_objects": [
                {
                    "kind": w.kind,
                    "north_m": w.north_m,
                    "east_m": w.east_m,
                    "temperature_c": w.temperature_c,
                }
                for w in world.warm_objects
            ],
        }


def _truth(
    world: World,
    pose_at: Callable[[float], TruePose],
    route: tuple[tuple[float, float], ...],
    start: float,
    duration_s: float,
    fps: float,
    min_view_px: int,
    first_seen: dict[int, float],
    frames_in_view: dict[int, int],
    max_px: dict[int, int],
) -> dict[str, Any]:
    path = []
    for k in range(int(duration_s / _PATH_STEP_S) + 1):
        p = pose_at(k * _PATH_STEP_S)
        path.append(
            [
                round(start + p.t_s, 3),
                round(p.north_m, 4),
                round(p.east_m, 4),
                round(math.degrees(p.yaw_rad), 2),
            ]
        )
    return {
        "format": TRUTH_FORMAT,
        "world_name": world.name,
        "seed": world.seed,
        "size_m": list(world.size_m),
        "origin": {
            "lat_deg": world.origin.lat_deg,
            "lon_deg": world.origin.lon_deg,
            "alt_m": world.origin.alt_m,
        },
        "start_unix_s": start,
        "duration_s": duration_s,
        "fps": fps,
        "min_view_px": min_view_px,
        "victims": [
            {
                "victim_id": v.victim_id,
                "north_m": v.north_m,
                "east_m": v.east_m,
                "visible_north_m": round(v.visible_north_m, 4),
                "visible_east_m": round(v.visible_east_m, 4),
                "heading_deg": round(math.degrees(v.heading_rad), 3),
                "height_m": v.height_m,
                "visibility_pct": round(v.visibility_pct, 3),
                "urgency": v.urgency.name,
                "first_in_view_unix_s": first_seen.get(v.victim_id),
                "frames_in_view": frames_in_view.get(v.victim_id, 0),
                "max_visible_px": max_px.get(v.victim_id, 0),
            }
            for v in world.victims
        ],
        "lookalike_debris": sum(1 for d in world.debris if d.kind.startswith("lookalike")),
        "route_ne_m": [list(p) for p in route],
        "true_path_unix_n_e_yaw": path,
    }
