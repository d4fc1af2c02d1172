"""``rescue-companion replay``: the live pipeline, offline, on a recorded mission.

Inputs: a tlog of what the autopilot sent (8-byte big-endian Unix microseconds before
each packet), a folder of frames named ``<unix_time_microseconds>.jpg|png`` on
the same clock and, optionally, a folder of thermal frames named
``<unix_time_microseconds>.png`` (16-bit, centi-kelvin) on that clock too, which
needs the config's ``[thermal]`` section for the thermal camera's geometry. Colour
and thermal frames are processed together in capture-time order, as the service's
mailbox hands them over. Poses are decoded exactly as live (the tlog time plays the part of
the arrival time), frames are processed in time order once the telemetry has run
``LOOKAHEAD_S`` past them (so the pose after the frame is known for interpolation),
and the result is deterministic: no wall clock, no threads.

Output: a JSON document (docs/REPLAY.md) and a mission map PNG beside it, both with
where the cameras looked (the coverage grid, companion/coverage.py).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from companion.commands.mission_run import LOOKAHEAD_S, MissionRun, ReplayResult
from companion.commands.missionmap import MapVictim, draw_mission_map
from companion.config import Config
from companion.coverage import coverage_document
from companion.sources.base import CameraError, EndOfStream, Frame
from companion.sources.folder import FramesDirSource
from companion.sources.size import SizedSource
from companion.sources.thermal import ThermalFrame
from companion.sources.thermal_folder import ThermalFramesDir
from mavlink_io.codec import MavMessage
from mavlink_io.errors import TlogError
from mavlink_io.telemetry import is_autopilot_heartbeat
from mavlink_io.tlog import read_tlog

log = logging.getLogger(__name__)

REPLAY_FORMAT = "rescue-companion/replay"
REPLAY_VERSION = 1


class _Tlog:
    """A tlog's messages, handed to the mission run up to a time."""

    def __init__(self, tlog: Path, run: MissionRun) -> None:
        self._messages: Iterator[tuple[float, MavMessage]] = read_tlog(tlog)
        self._pending: tuple[float, MavMessage] | None = None
        self._run = run

    def advance_to(self, t_unix_s: float) -> None:
        """Feed every message stamped up to ``t_unix_s``."""
        while True:
            if self._pending is None:
                self._pending = next(self._messages, None)
                if self._pending is None:
                    return
            t, msg = self._pending
            if t > t_unix_s:
                return
            self._pending = None
            self._run.message(t, msg)


def _progress(done: int, total: int, victims: int) -> None:
    if sys.stderr.isatty():
        width = 30
        filled = width * done // max(total, 1)
        sys.stderr.write(
            f"\r[{'#' * filled}{'.' * (width - filled)}] {done}/{total} frames, {victims} victims"
        )
        if done == total:
            sys.stderr.write("\n")
        sys.stderr.flush()
    elif done == total or done % 200 == 0:
        log.info("replay: %d/%d frames, %d victims", done, total, victims)


def check_tlog(tlog: Path) -> None:
    """TlogError unless the tlog holds a valid record from an autopilot (its
    HEARTBEAT); read only up to that heartbeat, so it is quick on any size."""
    records = 0
    for _t, msg in read_tlog(tlog):
        records += 1
        if is_autopilot_heartbeat(msg):
            return
    if records == 0:
        raise TlogError(f"{tlog}: no MAVLink record in it (empty, or not a tlog)")
    raise TlogError(f"{tlog}: {records} MAVLink records but no autopilot HEARTBEAT")


def prepare_output(out: Path) -> Path:
    """The JSON path to write (``out``, or ``out/victims.json`` for a folder), its
    folder created and proven writable now, before any processing; OSError if not."""
    path = out / "victims.json" if out.is_dir() else out
    path.parent.mkdir(parents=True, exist_ok=True)
    probe = path.with_name(f".{path.name}.probe")
    probe.write_bytes(b"")
    probe.unlink()
    return path


class _ThermalFolder:
    """The thermal frames of a replay, on the colour frames' monotonic clock."""

    def __init__(self, config: Config, folder: Path, mono_minus_unix_s: float) -> None:
        if config.thermal is None:
            raise CameraError(
                f"--thermal-frames {folder}: the config has no [thermal] section, so the "
                "thermal camera's size, field of view and mount are unknown"
            )
        self.source = ThermalFramesDir(folder, config.thermal.width_px, config.thermal.height_px)
        self._offset_s = mono_minus_unix_s
        self.next: ThermalFrame | None = None
        self.advance()

    def advance(self) -> None:
        """Read the next frame into ``next`` (None at the end)."""
        try:
            frame = self.source.read(timeout_s=0.0)
        except EndOfStream:
            self.next = None
            return
        # One clock for both cameras: the folder sampled its own offset when opened.
        self.next = dataclasses.replace(frame, t_mono_s=frame.t_unix_s + self._offset_s)


def replay(
    config: Config, tlog: Path, frames_dir: Path, thermal_dir: Path | None = None
) -> ReplayResult:
    """Run the pipeline over a recorded mission. Raises CameraError/TlogError on
    unusable inputs (the CLI reports them): a frames folder without frames, a tlog
    without an autopilot, thermal frames without a ``[thermal]`` section."""
    check_tlog(tlog)
    source = FramesDirSource(frames_dir)
    sized = SizedSource(source, config.camera.width_px, config.camera.height_px)
    thermal = (
        _ThermalFolder(config, thermal_dir, source.mono_minus_unix_s)
        if thermal_dir is not None
        else None
    )
    run = MissionRun(config, source.mono_minus_unix_s, thermal is not None)
    telemetry = _Tlog(tlog, run)
    total = len(source)
    while True:
        try:
            frame: Frame | None = sized.read(timeout_s=0.0)
        except EndOfStream:
            frame = None
        # The thermal frames captured before this colour frame go first.
        while (
            thermal is not None
            and thermal.next is not None
            and (frame is None or thermal.next.t_unix_s < frame.t_unix_s)
        ):
            telemetry.advance_to(thermal.next.t_unix_s + LOOKAHEAD_S)
            run.thermal(thermal.next)
            thermal.advance()
        if frame is None:
            break
        telemetry.advance_to(frame.t_unix_s + LOOKAHEAD_S)
        run.colour(frame)
        _progress(frame.index + 1, total, len(run.tracker.victims()))
    telemetry.advance_to(float("inf"))
    source.close()
    if thermal is not None:
        thermal.source.close()
    if run.telemetry.count == 0:  # a real log can lack LOCAL_POSITION_NED: say it, do not fail
        log.warning("replay: no pose decoded from %s (no ATTITUDE with LOCAL_POSITION_NED)", tlog)
    return run.result(
        source.frames_skipped, thermal.source.frames_skipped if thermal is not None else 0
    )


def result_document(result: ReplayResult) -> dict[str, Any]:
    """The JSON document of a replay (schema in docs/REPLAY.md)."""
    sysid = result.robot_sysid or 1
    victims = []
    for v in result.victims:
        report = v.to_report(sysid, result.floor_down_m, result.origin)
        victims.append(
            {
                "victim_id": v.victim_id,
                "state": v.state.name,
                "urgency": v.urgency.name,
                "cues": v.cues.names(),
                "visibility_pct": round(v.visibility_pct, 2),
                "north_m": v.north_m,
                "east_m": v.east_m,
                "down_m": report.down_m,
                "lat_deg": report.lat_deg,
                "lon_deg": report.lon_deg,
                "alt_m": report.alt_m,
                "sigma_m": v.sigma_m,
                "cov_ne_m2": [list(row) for row in v.cov_ne_m2],
                "observations": v.observations,
                "first_seen_unix_s": v.first_seen_unix_s,
                "last_seen_unix_s": v.last_seen_unix_s,
                "first_reported_unix_s": result.first_reported_unix_s.get(v.victim_id),
            }
        )
    origin = result.origin
    return {
        "format": REPLAY_FORMAT,
        "version": REPLAY_VERSION,
        "robot_sysid": result.robot_sysid,
        "origin": None
        if origin is None
        else {"lat_deg": origin.lat_deg, "lon_deg": origin.lon_deg, "alt_m": origin.alt_m},
        "frames": result.frames,
        "frames_skipped": result.frames_skipped,
        "frames_without_pose": result.frames_without_pose,
        "thermal_frames": result.thermal_frames,
        "thermal_frames_skipped": result.thermal_frames_skipped,
        "poses": result.poses,
        "autopilot_reboots": result.reboots,
        "victims": victims,
        "merged": [{"victim_id": v.victim_id, "merged_into": v.merged_into} for v in result.merged],
        "coverage": coverage_document(result.coverage),
    }


def write_outputs(result: ReplayResult, out_json: Path) -> Path:
    """Write the JSON document and the map PNG beside it, each whole or not at all
    (no temporary file is left behind); the PNG's path. OSError if they cannot be."""
    out_json.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_json.with_name(out_json.name + ".tmp")
    try:
        tmp.write_text(json.dumps(result_document(result), indent=2) + "\n")
        tmp.replace(out_json)
    finally:
        tmp.unlink(missing_ok=True)
    png = out_json.with_suffix(".png")
    draw_mission_map(
        png, result.route_ne_m, [MapVictim.of(v) for v in result.victims], coverage=result.coverage
    )
    return png
