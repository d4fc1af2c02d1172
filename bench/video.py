"""Live video encoder: CPU share of libx264 at the default settings (companion.reporting.video).

The Pi 5 has no hardware H.264 encoder, so the stream costs CPU: rendered 640x480
warehouse frames of a rover driving its route, with boxes and labels drawn, scaled
and encoded (ultrafast, zero latency, 1000 kbit/s, a key frame a second) at 10 fps
into MPEG-TS. ``cpu_share_pct`` is process CPU time over stream time, all of
x264's threads included; the goal is a small share of one Pi 5 core (not measured
on a Pi 5 here: there is none). ``bitrate_kbps`` is what left, MPEG-TS included.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from companion.config import VideoConfig
from companion.reporting.video import H264Encoder, Label, Shot, draw
from fusion.types import Urgency
from scenarios.motion import Trajectory
from scenarios.render import Renderer
from scenarios.world import preset

FRAMES = 100


def run() -> dict[str, float]:
    cfg = VideoConfig()
    world = preset("mixed")
    renderer = Renderer(world)
    traj = Trajectory.for_world(world)
    images = [renderer.render(traj.pose_at(0.1 * k)).image for k in range(FRAMES)]
    label = (Label(320.0, 300.0, "7 CRITICAL", Urgency.CRITICAL),)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "v.ts"
        enc = H264Encoder(str(path), cfg)
        cpu0, wall0 = time.process_time(), time.perf_counter()
        for k, image in enumerate(images):
            enc.encode(draw(Shot(image, ((200, 180, 120, 90),), label), 640, 480), k / cfg.fps)
        enc.close()
        cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - wall0
        size = path.stat().st_size
    stream_s = FRAMES / cfg.fps
    return {
        "cpu_per_frame_ms": round(1e3 * cpu_s / FRAMES, 2),
        "cpu_share_pct": round(100.0 * cpu_s / stream_s, 2),
        "wall_per_frame_ms": round(1e3 * wall_s / FRAMES, 2),
        "bitrate_kbps": round(size * 8 / stream_s / 1000, 1),
    }


if __name__ == "__main__":
    print(run())
