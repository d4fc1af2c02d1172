"""Renderer speed: milliseconds per 640x480 frame (scenarios.render)."""

from __future__ import annotations

import statistics
import time

from scenarios.motion import Trajectory
from scenarios.render import Renderer, encode_jpeg
from scenarios.world import preset

FRAMES = 40


def run() -> dict[str, float]:
    world = preset("mixed")
    t0 = time.perf_counter()
    renderer = Renderer(world)
    setup_s = time.perf_counter() - t0
    traj = Trajectory.for_world(world)
    poses = [traj.pose_at(2.0 + 2.0 * k) for k in range(FRAMES)]
    renderer.render(poses[0])  # warm-up
    render_ms, jpeg_ms = [], []
    for pose in poses:
        t = time.perf_counter()
        image = renderer.render(pose).image
        t1 = time.perf_counter()
        encode_jpeg(image, 85)
        render_ms.append((t1 - t) * 1e3)
        jpeg_ms.append((time.perf_counter() - t1) * 1e3)
    return {
        "render_640x480_median_ms": round(statistics.median(render_ms), 2),
        "render_640x480_p90_ms": round(sorted(render_ms)[int(0.9 * FRAMES)], 2),
        "jpeg_q85_median_ms": round(statistics.median(jpeg_ms), 2),
        "world_raster_and_setup_s": round(setup_s, 3),
    }


if __name__ == "__main__":
    print(run())
