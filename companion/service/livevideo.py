"""The live video for QGC (companion/reporting/video.py) and the camera component that
advertises it (mavlink_io/camera.py).

The camera is its own component on the vehicle link (QGC looks for cameras at
100-105 only), with its own codec (its own sequence numbers) and its own heartbeat,
which the reporter sends. The processing thread offers it frames, answers the
camera requests the vehicle link delivers for it, and opens a new stream when a
setting (``RC_VID_ON``, ``RC_VID_KBPS``) changes the ``[video]`` section; the
reporter reads ``server`` and may see either the old or the new one.
"""

from __future__ import annotations

import logging
import math
from types import ModuleType

from companion.config import Config
from companion.reporting.video import VideoStreamer
from fusion.camera import CameraModel
from mavlink_io.camera import CameraServer, StreamInfo
from mavlink_io.codec import Codec, MavMessage
from mavlink_io.linkspec import parse_link
from mavlink_io.signing import Signing
from mavlink_io.vehicle import VehicleLink

log = logging.getLogger(__name__)

MAV_STATE_ACTIVE = 4


class LiveVideo:
    def __init__(
        self,
        config: Config,
        camera_model: CameraModel,
        vehicle: VehicleLink,
        signing: Signing | None,
        m: ModuleType,
    ) -> None:
        self._camera_model = camera_model
        self._vehicle = vehicle
        self._m = m
        self._codec = Codec(config.vehicle.system_id or 1, config.video.component_id, signing)
        self._vehicle.other_components = frozenset({config.video.component_id})
        self._config = config
        self.streamer, self.server = self._open(config)

    def _open(self, config: Config) -> tuple[VideoStreamer | None, CameraServer | None]:
        """The live video for QGC and the camera protocol that advertises it, when on
        and a destination is known ([video] host, else the host of [hq] url)."""
        v = config.video
        host = v.host or (parse_link(config.hq.url).host if config.hq.url else "")
        if not v.enabled or not host:
            log.info("no video: %s", "[video] enabled = false" if not v.enabled else "no host")
            return None, None
        k = self._camera_model.intrinsics
        hfov_deg = math.degrees(2.0 * math.atan(0.5 * k.width_px / k.fx_px))
        info = StreamInfo(
            v.port, v.width_px, v.height_px, v.fps, round(v.bitrate_kbps * 1000), hfov_deg
        )
        return VideoStreamer(v, host), CameraServer(v.component_id, info, self._m)

    def start(self) -> None:
        if self.streamer is not None:
            self.streamer.start()

    def apply(self, config: Config) -> None:
        """A changed setting (processing thread): on/off or bit rate, a new stream."""
        if config.video != self._config.video:
            if self.streamer is not None:
                self.streamer.close()
            self.streamer, self.server = self._open(config)
            if self.streamer is not None:
                self.streamer.start()
        self._config = config

    def handle(self, msg: MavMessage) -> None:
        """Answer a camera request (processing thread)."""
        if self.server is not None:
            pose = self._vehicle.poses.latest()
            for reply in self.server.handle(msg, pose.t_boot_s if pose else 0.0) or []:
                self.send(reply)

    def heartbeat(self) -> None:
        """The camera's own heartbeat, while there is a camera: QGC finds it."""
        if self.server is not None:
            m = self._m
            self.send(
                m.MAVLink_heartbeat_message(
                    m.MAV_TYPE_CAMERA, m.MAV_AUTOPILOT_INVALID, 0, 0, MAV_STATE_ACTIVE, 3
                )
            )

    def send(self, msg: MavMessage) -> None:
        """A message from the camera component (the vehicle's system ID, 100)."""
        if self._vehicle.sysid:
            self._codec.src_system = self._vehicle.sysid
        self._vehicle.send_encoded(self._codec.encode(msg))

    def close(self) -> None:
        if self.streamer is not None:
            self.streamer.close()
