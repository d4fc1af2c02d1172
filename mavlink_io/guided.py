"""Taking an ArduPilot Rover off its mission for a moment and giving it back.

The companion's closer looks (companion/looks/machine.py) need four commands and three
things the autopilot reports; the MAVLink side of both is here:

- ``set_mode``: COMMAND_LONG MAV_CMD_DO_SET_MODE (custom mode, answered by
  COMMAND_ACK); Rover's custom modes are ardupilotmega.xml's ROVER_MODE values;
- ``goto``: SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED, position only
  (ArduPilot sends no COMMAND_ACK for it: the rover's motion is the answer);
- ``face``: the same message with the position ignored and the yaw given: Rover
  turns in place to that heading;
- ``set_current``: MAV_CMD_DO_SET_MISSION_CURRENT (COMMAND_ACK), where AUTO resumes;
- ``request_mission_current``: MAV_CMD_REQUEST_MESSAGE for MISSION_CURRENT.

``AutopilotWatch`` keeps what the autopilot (component 1 of the vehicle's system)
reports: HEARTBEAT's custom mode, armed flag, autopilot and vehicle type,
MISSION_CURRENT's item and the COMMAND_ACKs of the commands above, each with its
arrival time on the monotonic clock. The vehicle link's reader thread writes it
(``VehicleLink.listen``); the look controller reads ``snapshot()``. A ``watch``
callback runs on the reader thread at the first heartbeat that shows a mode the
companion did not ask for, so nothing more is sent after that.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from types import ModuleType

from mavlink_io.codec import MavMessage
from mavlink_io.telemetry import AUTOPILOT_COMPONENT

# ardupilotmega.xml ROVER_MODE
ROVER_MANUAL = 0
ROVER_HOLD = 4
ROVER_AUTO = 10
ROVER_RTL = 11
ROVER_SMART_RTL = 12
ROVER_GUIDED = 15
ROVER_MODE_NAMES = {
    0: "MANUAL",
    1: "ACRO",
    3: "STEERING",
    4: "HOLD",
    5: "LOITER",
    6: "FOLLOW",
    7: "SIMPLE",
    8: "DOCK",
    9: "CIRCLE",
    10: "AUTO",
    11: "RTL",
    12: "SMART_RTL",
    15: "GUIDED",
    16: "INITIALISING",
}

MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_SET_MISSION_CURRENT = 224
MAV_CMD_REQUEST_MESSAGE = 512
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_TYPE_GROUND_ROVER = 10
MAV_FRAME_LOCAL_NED = 1
MSG_MISSION_CURRENT = 42
MAV_RESULT_ACCEPTED = 0
# POSITION_TARGET_TYPEMASK: ignore velocity, acceleration, yaw and yaw rate; then
# ignore the position and velocity, acceleration and yaw rate (a heading only).
GOTO_TYPE_MASK = 0b0000_1101_1111_1000
FACE_TYPE_MASK = 0b0000_1001_1111_1111
WATCHED_COMMANDS = frozenset({MAV_CMD_DO_SET_MODE, MAV_CMD_DO_SET_MISSION_CURRENT})


def mode_name(mode: int | None) -> str:
    if mode is None:
        return "unknown"
    return ROVER_MODE_NAMES.get(mode, f"mode {mode}")


def _command(m: ModuleType, sysid: int, command: int, *params: float) -> MavMessage:
    p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
    return m.MAVLink_command_long_message(sysid, AUTOPILOT_COMPONENT, command, 0, *p)


def set_mode(m: ModuleType, sysid: int, mode: int) -> MavMessage:
    return _command(m, sysid, MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode)


def set_current(m: ModuleType, sysid: int, seq: int) -> MavMessage:
    return _command(m, sysid, MAV_CMD_DO_SET_MISSION_CURRENT, float(seq))


def request_mission_current(m: ModuleType, sysid: int) -> MavMessage:
    return _command(m, sysid, MAV_CMD_REQUEST_MESSAGE, float(MSG_MISSION_CURRENT))


def goto(m: ModuleType, sysid: int, north_m: float, east_m: float) -> MavMessage:
    return m.MAVLink_set_position_target_local_ned_message(
        0, sysid, AUTOPILOT_COMPONENT, MAV_FRAME_LOCAL_NED, GOTO_TYPE_MASK,
        north_m, east_m, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    )  # fmt: skip


def face(m: ModuleType, sysid: int, yaw_rad: float) -> MavMessage:
    return m.MAVLink_set_position_target_local_ned_message(
        0, sysid, AUTOPILOT_COMPONENT, MAV_FRAME_LOCAL_NED, FACE_TYPE_MASK,
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw_rad, 0.0,
    )  # fmt: skip


@dataclass(frozen=True)
class AutopilotView:
    """What the autopilot last said; times on the monotonic clock (None: never)."""

    mode: int | None = None
    armed: bool = False
    ardupilot_rover: bool = False
    autopilot: int | None = None  # MAV_AUTOPILOT of its heartbeat
    heartbeat_s: float | None = None
    mission_seq: int | None = None
    mission_s: float | None = None
    acks: dict[int, tuple[int, float]] = field(default_factory=dict)  # command: (result, t)


class AutopilotWatch:
    """See the module docstring."""

    def __init__(self, sysid: Callable[[], int]) -> None:
        self._sysid = sysid
        self._lock = threading.Lock()
        self._view = AutopilotView()
        self._expected: frozenset[int] = frozenset()
        self.on_foreign_mode: Callable[[int], None] = lambda _mode: None

    def expect(self, modes: frozenset[int]) -> None:
        """The modes the companion put (or is putting) the rover in; empty: none, the
        companion is not driving and any mode is the operator's business."""
        with self._lock:
            self._expected = modes

    def snapshot(self) -> AutopilotView:
        with self._lock:
            return self._view

    def on_message(self, msg: MavMessage, now_s: float) -> None:
        """From the vehicle link's reader thread."""
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (self._sysid(), AUTOPILOT_COMPONENT):
            return
        kind = msg.get_type()
        foreign = None
        with self._lock:
            v = self._view
            if kind == "HEARTBEAT":
                self._view = AutopilotView(
                    mode=int(msg.custom_mode),
                    armed=bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
                    ardupilot_rover=msg.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA
                    and msg.type == MAV_TYPE_GROUND_ROVER,
                    autopilot=int(msg.autopilot),
                    heartbeat_s=now_s,
                    mission_seq=v.mission_seq,
                    mission_s=v.mission_s,
                    acks=v.acks,
                )
                if self._expected and int(msg.custom_mode) not in self._expected:
                    foreign = int(msg.custom_mode)
            elif kind == "MISSION_CURRENT":
                self._view = _replace(v, mission_seq=int(msg.seq), mission_s=now_s)
            elif kind == "COMMAND_ACK" and msg.command in WATCHED_COMMANDS:
                acks = {**v.acks, int(msg.command): (int(msg.result), now_s)}
                self._view = _replace(v, acks=acks)
        if foreign is not None:
            self.on_foreign_mode(foreign)


def _replace(v: AutopilotView, **changes: object) -> AutopilotView:
    return dataclasses.replace(v, **changes)  # type: ignore[arg-type]
