"""The robot's eye in QGC: the H.264 stream decodes in a real client (PyAV's FFmpeg,
the decoder QGC's GStreamer pipeline also wraps), and the camera protocol answers
QGC's discovery requests through the simulated rover's routing."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import av
import numpy as np
import pytest
from pymavlink import mavutil

from companion.config import VideoConfig
from companion.reporting.video import H264Encoder, Label, Shot, draw
from fusion.types import Urgency
from scenarios.live import LiveSim
from scenarios.world import preset

COMPANION = 191
CAMERA = 100  # MAV_COMP_ID_CAMERA: QGC looks for cameras at components 100-105 only


def test_overlay_draws_boxes_and_labels_in_the_urgency_colour() -> None:
    image = np.zeros((240, 320, 3), np.uint8)
    s = Shot(image, ((10, 10, 50, 40),), (Label(200.0, 150.0, "7 CRITICAL", Urgency.CRITICAL),))
    out = draw(s, 640, 480)
    assert out.shape == (480, 640, 3)
    assert (out[20:100, 18:22] == (255, 255, 0)).all(axis=-1).any()  # the box, scaled x2
    red = (out[:, :, 2] > 200) & (out[:, :, 1] < 80) & (out[:, :, 0] < 80)
    assert red[280:310, 380:420].any()  # the victim's dot and label near (400, 300)


def test_h264_stream_decodes_at_its_size_and_bit_rate(tmp_path: Path) -> None:
    cfg = VideoConfig(bitrate_kbps=1000.0, fps=10.0)
    path = tmp_path / "v.ts"
    enc = H264Encoder(str(path), cfg)
    rng = np.random.default_rng(1)
    base = (rng.random((480, 640, 3)) * 255).astype(np.uint8)  # hard to compress: the worst case
    for i in range(50):
        enc.encode(np.roll(base, 4 * i, axis=1), i / cfg.fps)
    enc.close()
    with av.open(str(path)) as container:
        frames = [f for f in container.decode(video=0)]
    assert len(frames) == 50 and (frames[0].width, frames[0].height) == (640, 480)
    kbps = path.stat().st_size * 8 / (50 / cfg.fps) / 1000
    # noise at a 1 s VBV cap: within the cap plus MPEG-TS overhead (about 5 %)
    assert kbps < 1.15 * cfg.bitrate_kbps, kbps


class Receiver:
    """A UDP MPEG-TS client like QGC's (listens on the advertised port), decoding."""

    def __init__(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.frames: list[tuple[int, int]] = []
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        url = f"udp://127.0.0.1:{self.port}?timeout=20000000&overrun_nonfatal=1"
        try:
            with av.open(url, format="mpegts", timeout=20.0) as container:
                for frame in container.decode(video=0):
                    self.frames.append((frame.width, frame.height))
                    if len(self.frames) >= 20:
                        return
        except av.error.FFmpegError as exc:
            self.error = str(exc)

    def wait(self, timeout_s: float) -> None:
        self._thread.join(timeout_s)


class Gcs:
    def __init__(self, url: str) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)
        self._next_heartbeat = 0.0

    def recv(self, want: str, timeout_s: float, component: int = CAMERA) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if time.monotonic() >= self._next_heartbeat:
                self.conn.mav.heartbeat_send(6, 8, 0, 0, 4)
                self._next_heartbeat = time.monotonic() + 0.5
            msg = self.conn.recv_match(type=want, blocking=True, timeout=0.2)
            if msg is not None and msg.get_srcComponent() == component:
                return msg
        raise TimeoutError(f"no {want} from component {component}")

    def request(self, msg_id: int) -> tuple[Any, Any]:
        """MAV_CMD_REQUEST_MESSAGE, as QGC's camera manager sends it; resent until
        answered (the companion may not know its system ID yet)."""
        for _ in range(10):
            self.conn.mav.command_long_send(1, CAMERA, 512, 0, msg_id, 0, 0, 0, 0, 0, 0)
            try:
                ack = self.recv("COMMAND_ACK", 2.0)
            except TimeoutError:
                continue
            want = {259: "CAMERA_INFORMATION", 269: "VIDEO_STREAM_INFORMATION"}[msg_id]
            return ack, self.recv(want, 5.0)
        raise TimeoutError(f"no answer to MAV_CMD_REQUEST_MESSAGE({msg_id})")


@pytest.fixture
def sim() -> Iterator[LiveSim]:
    with LiveSim(preset("light")) as live:
        yield live


@pytest.mark.slow
def test_qgc_discovers_the_camera_and_a_client_decodes_the_stream(
    tmp_path: Path, sim: LiveSim
) -> None:
    receiver = Receiver()
    cfg = tmp_path / "companion.toml"
    cfg.write_text(
        f'[vehicle]\nurl = "{sim.vehicle_url}"\n[hq]\nurl = ""\n'
        f'[camera]\nsource = "{sim.camera_source}"\n[paths]\nstate_dir = "{tmp_path / "s"}"\n'
        f'[video]\nhost = "127.0.0.1"\nport = {receiver.port}\n'
    )
    log_path = tmp_path / "companion.log"
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC")}
    gcs = Gcs(sim.ground_url)
    with log_path.open("ab") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "companion.commands.cli", "run", "--config", str(cfg)],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
        )
    try:
        # What QGC's camera manager waits for: a HEARTBEAT from a camera component.
        heartbeat = gcs.recv("HEARTBEAT", 30.0)
        assert heartbeat.type == 30  # MAV_TYPE_CAMERA
        ack, info = gcs.request(259)
        assert (ack.command, ack.result) == (512, 0)
        assert info.flags & 256  # CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        assert (info.resolution_h, info.resolution_v) == (640, 480)
        ack, stream = gcs.request(269)
        assert ack.result == 0
        assert stream.type == 3 and stream.uri == str(receiver.port)  # MPEG-TS on that port
        assert stream.encoding == 1 and stream.bitrate == 1_000_000
        receiver.wait(40.0)
        assert receiver.error is None, receiver.error
        assert len(receiver.frames) >= 20 and set(receiver.frames) == {(640, 480)}
        # The bit rate from QGC's parameter editor: a new stream, advertised as such.
        gcs.conn.mav.param_set_send(1, COMPANION, b"RC_VID_KBPS", 500.0, 9)
        assert gcs.recv("PARAM_VALUE", 10.0, component=COMPANION).param_value == 500.0
        _, stream = gcs.request(269)
        assert stream.bitrate == 500_000
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=15) == 0, log_path.read_text()[-3000:]
        gcs.conn.close()
    assert "Traceback" not in log_path.read_text()


def test_camera_protocol_answers_legacy_requests_and_refuses_the_rest() -> None:
    from mavlink_io import dialect
    from mavlink_io.camera import CameraServer, StreamInfo

    m = dialect.load()
    server = CameraServer(100, StreamInfo(5602, 640, 480, 10.0, 1_000_000, 62.0), m)

    def command(command: int, target_component: int = 100, param1: float = 0.0) -> list[Any]:
        msg = m.MAVLink_command_long_message(
            1, target_component, command, 0, param1, 0, 0, 0, 0, 0, 0
        )
        msg._header.srcSystem, msg._header.srcComponent = 255, 190
        return server.handle(msg, 12.5) or []

    ack, info = command(521)  # MAV_CMD_REQUEST_CAMERA_INFORMATION, as older QGC sends it
    assert (ack.command, ack.result, ack.target_system) == (521, 0, 255)
    assert info.get_type() == "CAMERA_INFORMATION" and info.time_boot_ms == 12500
    ack, stream = command(2504)  # MAV_CMD_REQUEST_VIDEO_STREAM_INFORMATION
    assert stream.uri == "5602" and stream.hfov == 62
    (ack,) = command(2000)  # MAV_CMD_IMAGE_START_CAPTURE: not this camera's
    assert ack.result == 3  # MAV_RESULT_UNSUPPORTED
    assert command(2000, target_component=0) == []  # for everyone: someone else answers
    assert command(512, target_component=0, param1=148) == []  # AUTOPILOT_VERSION
    assert command(512, target_component=101, param1=259) == []  # another camera's
