"""The companion in the simulator's loop, in simulated time: closer looks that really
move the simulated rover.

``rescue-sim record`` drives its route without anyone in the loop, so a replay of it
shows what the companion makes of the route's views only. ``InLoopCompanion`` sits in
the recording's loop (scenarios/record.py ``InLoop``): it decodes what the simulated
autopilot sends (MAVLink bytes, as a serial port would carry them), runs each frame
through the same pipeline as replay (``companion.commands.mission_run.MissionRun``)
once the telemetry is ``LOOKAHEAD_S`` past it, and steps the closer looks
(``companion.looks.run.Looks``) against it; what the looks send goes back to the
autopilot as bytes, which drives GUIDED targets, mode changes and mission resumes as
ArduPilot Rover does (scenarios/autopilot_drive.py). No threads, no wall clock: the
same world, config and start time give the same mission.

``LookEvent``s say where each look went and what it settled, for the mission map and
the benchmark (bench/looks.py).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.commands.mission_run import LOOKAHEAD_S, MissionRun, ReplayResult
from companion.config import Config
from companion.config_load import load_config
from companion.looks.machine import Phase
from companion.looks.run import Looks
from companion.sources.base import Frame
from companion.sources.thermal import ThermalFrame
from fusion.camera import CameraModel
from fusion.pose import PoseHistory
from mavlink_io.codec import Codec, MavMessage
from scenarios.camera import default_camera, default_thermal_camera
from scenarios.record import write_recording_toml

log = logging.getLogger(__name__)

_TICK_S = 0.2  # the looks are stepped this often (the service: each processing loop)


class _LoopVehicle:
    """The vehicle link of the loop: bytes from the autopilot decoded into the mission
    run's pose history and the listeners; messages to it encoded into ``outbox``."""

    def __init__(self, run: MissionRun, codec: Codec) -> None:
        self.poses: PoseHistory = run.poses
        self.codec = codec
        self._run = run
        self._listeners: list[Callable[[MavMessage, float], None]] = []
        self.outbox: list[bytes] = []

    @property
    def sysid(self) -> int:
        return self._run.telemetry.sysid

    @property
    def connected(self) -> bool:
        return self._run.telemetry.sysid != 0

    def listen(self, callback: Callable[[MavMessage, float], None]) -> None:
        self._listeners.append(callback)

    def send(self, msg: MavMessage) -> bool:
        self.outbox.append(self.codec.encode(msg))
        return True

    def heard(self, t_unix_s: float, packet: bytes) -> None:
        for msg in self.codec.feed(packet):
            self._run.message(t_unix_s, msg)
            for listener in self._listeners:
                listener(msg, t_unix_s)


@dataclass
class LookEvent:
    """One closer look: when and where it left the route, the viewpoint it drove to,
    and what it settled or why it was aborted (the machine's words)."""

    started_unix_s: float
    start_ne_m: tuple[float, float]
    view_ne_m: tuple[float, float]
    candidate_ne_m: tuple[float, float]
    kind: str
    track_id: int
    ended_unix_s: float | None = None
    outcome: str = ""


def recording_config(out_dir: Path, fps: float, camera: CameraModel | None = None) -> Config:
    """The config of the recording about to be made in ``out_dir`` with the simulator's
    cameras (the camera.toml scenarios.record writes there, written now): what the
    companion in its loop runs with."""
    out_dir.mkdir(parents=True, exist_ok=True)
    camera = camera or default_camera()
    return load_config(write_recording_toml(out_dir, camera, fps, default_thermal_camera()))


class InLoopCompanion:
    """See the module docstring. ``looks``: the closer looks are on (the config's
    ``[looks]`` otherwise as given)."""

    def __init__(self, config: Config, *, looks: bool, thermal: bool) -> None:
        config = dataclasses.replace(config, looks=dataclasses.replace(config.looks, enabled=looks))
        self.run = MissionRun(config, 0.0, thermal)  # one clock: the recording's Unix time
        codec = Codec(config.vehicle.system_id or 1, config.vehicle.component_id)
        self.vehicle = _LoopVehicle(self.run, codec)
        self.now_s = 0.0
        self.said: list[tuple[float, str]] = []
        self.looks = Looks(
            config.looks,
            self.vehicle,
            self,
            lambda: None,  # RC_LOOK_ON set to 0: no parameter to keep here
            clock=lambda: self.now_s,
            wall=lambda: self.now_s,
        )
        self.events: list[LookEvent] = []
        self._waiting: list[Frame | ThermalFrame] = []
        self._colour_index = self._thermal_index = 0
        self._next_tick_s = 0.0

    # -- the recording's loop (scenarios.record.InLoop) ------------------------------

    def heard(self, t_unix_s: float, packet: bytes) -> None:
        self.vehicle.heard(t_unix_s, packet)

    def colour(self, t_unix_s: float, image_bgr: np.ndarray) -> None:
        self._waiting.append(Frame(image_bgr, t_unix_s, t_unix_s, self._colour_index))
        self._colour_index += 1

    def thermal(self, t_unix_s: float, temps_c: np.ndarray) -> None:
        self._waiting.append(ThermalFrame(temps_c, t_unix_s, t_unix_s, self._thermal_index))
        self._thermal_index += 1

    def step(self, t_unix_s: float) -> list[bytes]:
        self.now_s = t_unix_s
        ready = [f for f in self._waiting if f.t_unix_s + LOOKAHEAD_S <= t_unix_s]
        if ready:
            self._waiting = [f for f in self._waiting if f.t_unix_s + LOOKAHEAD_S > t_unix_s]
            for frame in sorted(ready, key=lambda f: f.t_unix_s):
                if isinstance(frame, Frame):
                    self.run.colour(frame)
                else:
                    self.run.thermal(frame)
        if t_unix_s >= self._next_tick_s:
            self._next_tick_s = t_unix_s + _TICK_S
            self.looks.tick(lambda: self.run.tracker.victims(include_tentative=True))
            self._note_look(t_unix_s)
        out, self.vehicle.outbox = self.vehicle.outbox, []
        return out

    # -- what it said and did ----------------------------------------------------------

    def announce(self, text: str, severity: int) -> None:
        log.info("in the loop at %.1f: %s", self.now_s, text)
        self.said.append((self.now_s, text))

    def _note_look(self, t_unix_s: float) -> None:
        m = self.looks.machine
        look = m.look
        last = self.events[-1] if self.events else None
        if look is not None and m.phase != Phase.IDLE:
            if (
                last is None
                or last.ended_unix_s is not None
                or last.track_id != (look.candidate.track_id)
            ):
                c = look.candidate
                self.events.append(
                    LookEvent(
                        t_unix_s,
                        look.start,
                        look.view.ne,
                        c.ne,
                        c.kind.value,
                        c.track_id,
                    )
                )
            if look.outcome:
                self.events[-1].outcome = look.outcome
        elif last is not None and last.ended_unix_s is None:
            last.ended_unix_s = t_unix_s
            last.outcome = last.outcome or "ended"

    def result(self) -> ReplayResult:
        return self.run.result()
