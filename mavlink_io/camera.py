"""The MAVLink camera protocol on the companion's component: QGC finds the video.

QGC's camera manager listens to components MAV_COMP_ID_CAMERA..CAMERA6 (100-105)
of the vehicle (and the autopilot) only: the companion's camera is such a
component, with its own HEARTBEAT (MAV_TYPE_CAMERA). QGC asks it for
CAMERA_INFORMATION; a camera whose flags say CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
is then asked for VIDEO_STREAM_INFORMATION, and QGC's video widget plays the
stream it describes: here VIDEO_STREAM_TYPE_MPEG_TS (H.264 in MPEG-TS over UDP),
whose ``uri`` is the UDP port QGC listens on.

Answered, when addressed to our component or to all (target_component 0):
- COMMAND_LONG MAV_CMD_REQUEST_MESSAGE with param1 CAMERA_INFORMATION (259),
  VIDEO_STREAM_INFORMATION (269) or VIDEO_STREAM_STATUS (270);
- the older MAV_CMD_REQUEST_CAMERA_INFORMATION (521),
  MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION (2504) and
  MAV_CMD_REQUEST_VIDEO_STREAM_STATUS (2505);
each with COMMAND_ACK (MAV_RESULT_ACCEPTED) and then the message. Any other
command addressed to our component alone gets COMMAND_ACK MAV_RESULT_UNSUPPORTED;
one addressed to all is left to the component it is for.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

from mavlink_io import dialect
from mavlink_io.codec import MavMessage

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_UNSUPPORTED = 3
_REQUEST_MESSAGE = 512
_CAMERA_INFORMATION_ID = 259
_VIDEO_STREAM_INFORMATION_ID = 269
_VIDEO_STREAM_STATUS_ID = 270
_LEGACY = {
    521: _CAMERA_INFORMATION_ID,
    2504: _VIDEO_STREAM_INFORMATION_ID,
    2505: _VIDEO_STREAM_STATUS_ID,
}
_HAS_VIDEO_STREAM = 256  # CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
_MPEG_TS = 3  # VIDEO_STREAM_TYPE_MPEG_TS: H.264 in MPEG-TS over UDP, uri = the port
_RUNNING = 1  # VIDEO_STREAM_STATUS_FLAGS_RUNNING
_H264 = 1  # VIDEO_STREAM_ENCODING_H264


@dataclass(frozen=True)
class StreamInfo:
    port: int
    width_px: int
    height_px: int
    fps: float
    bitrate_bps: int
    hfov_deg: float


def _padded(text: str, size: int) -> list[int]:
    return list(text.encode("ascii")[:size].ljust(size, b"\0"))


class CameraServer:
    """Answers the camera protocol for ``component_id`` with one MPEG-TS stream."""

    def __init__(
        self, component_id: int, stream: StreamInfo, module: ModuleType | None = None
    ) -> None:
        self.component_id = component_id
        self.stream = stream
        self.m = module if module is not None else dialect.load()

    def handle(self, msg: MavMessage, time_boot_s: float) -> list[MavMessage] | None:
        """The replies to a COMMAND_LONG for us (ack first); None if it is not one."""
        if msg.get_type() != "COMMAND_LONG" or msg.target_component not in (0, self.component_id):
            return None
        command = int(msg.command)
        wanted = _LEGACY.get(command)
        if command == _REQUEST_MESSAGE:
            wanted = round(msg.param1)
        reply = self._message(wanted, time_boot_s) if wanted is not None else None
        if reply is None:
            if msg.target_component == 0:
                return []  # for another component
            return [self._ack(msg, command, MAV_RESULT_UNSUPPORTED)]
        return [self._ack(msg, command, MAV_RESULT_ACCEPTED), reply]

    def _ack(self, msg: MavMessage, command: int, result: int) -> MavMessage:
        return self.m.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )

    def _message(self, msg_id: int, time_boot_s: float) -> MavMessage | None:
        s, m = self.stream, self.m
        if msg_id == _CAMERA_INFORMATION_ID:
            return m.MAVLink_camera_information_message(
                round(time_boot_s * 1000) & 0xFFFFFFFF,
                _padded("rescue-companion", 32),
                _padded("victim camera", 32),
                0,
                float("nan"),
                float("nan"),
                float("nan"),
                s.width_px,
                s.height_px,
                0,
                _HAS_VIDEO_STREAM,
                0,
                b"",
            )
        if msg_id == _VIDEO_STREAM_INFORMATION_ID:
            return m.MAVLink_video_stream_information_message(
                1,
                1,
                _MPEG_TS,
                _RUNNING,
                s.fps,
                s.width_px,
                s.height_px,
                s.bitrate_bps,
                0,
                round(s.hfov_deg),
                b"victims",
                str(s.port).encode(),
                _H264,
            )
        if msg_id == _VIDEO_STREAM_STATUS_ID:
            return m.MAVLink_video_stream_status_message(
                1,
                _RUNNING,
                s.fps,
                s.width_px,
                s.height_px,
                s.bitrate_bps,
                0,
                round(s.hfov_deg),
            )
        return None
