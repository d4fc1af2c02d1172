"""A live simulated mission on loopback: the rover's two MAVLink links and its camera.

    with LiveSim(preset("mixed")) as sim:
        sim.vehicle_url   # "udpout:127.0.0.1:P"  -> [vehicle] url of the companion
        sim.ground_url    # "udpout:127.0.0.1:Q"  -> rescue-hq --listen (the rover's GCS port)
        sim.camera_source # "sim:127.0.0.1:C"     -> [camera] source of the companion

Like ArduPilot SITL with two serial ports mapped to UDP: the companion talks to one,
the ground station to the other, and the rover routes between them the messages it
can check (not our dialect IDs: those travel inside TUNNEL). Both peers connect as
UDP clients, so the rover answers whoever spoke first on each port. Real time only:
camera frames carry wall-clock capture times that must match the poses.
"""

from __future__ import annotations

import dataclasses

from companion.calibration import camera_model
from companion.config import CameraConfig
from scenarios.camserver import CameraServer
from scenarios.render import Renderer
from scenarios.rover import SimRover
from scenarios.world import PointNE, World


def _patrol(world: World, lead_m: float = 2.5, passes: int = 40) -> World:
    """The world with the rover patrolling back and forth across its first victim,
    starting ``lead_m`` short of it: the victim is ahead of the camera on every pass
    (so tests see a victim within seconds and keep seeing it)."""
    if not world.victims:
        return world
    v = world.victims[0]
    near = (max(0.3, v.north_m - lead_m), v.east_m)
    far = (min(world.size_m[0] - 0.3, v.north_m + lead_m), v.east_m)
    route = tuple(far if i % 2 == 0 else near for i in range(passes))
    return dataclasses.replace(world, start_ne_m=near, start_heading_rad=0.0, route_ne_m=route)


class LiveSim:
    """A SimRover with a companion port, a ground port and a camera server."""

    def __init__(
        self,
        world: World,
        *,
        camera: CameraConfig | None = None,
        fps: float = 10.0,
        speed_m_s: float = 0.4,
        patrol_first_victim: bool = False,
        seed: int | None = None,
        route: tuple[PointNE, ...] | None = None,
    ) -> None:
        """``route``: driven exactly as given (not around obstacles); None: the
        world's route as ``scenarios.motion.route_of`` plans it."""
        self.world = _patrol(world) if patrol_first_victim else world
        self.rover = SimRover(
            self.world,
            ["udpin:127.0.0.1:0", "udpin:127.0.0.1:0"],
            route=route,
            speed_m_s=speed_m_s,
            seed=seed,
        )
        try:
            model = camera_model(camera or CameraConfig())
            self.camera = CameraServer(Renderer(self.world, model), self.rover.camera_pose, fps=fps)
        except Exception:
            self.rover.close()
            raise

    def start(self) -> LiveSim:
        self.rover.start()
        self.camera.start()
        return self

    @property
    def vehicle_url(self) -> str:
        return f"udpout:127.0.0.1:{self.rover.local_address(0)[1]}"

    @property
    def ground_url(self) -> str:
        return f"udpout:127.0.0.1:{self.rover.local_address(1)[1]}"

    @property
    def camera_source(self) -> str:
        return f"sim:127.0.0.1:{self.camera.address[1]}"

    def close(self) -> None:
        self.camera.close()
        self.rover.close()

    def __enter__(self) -> LiveSim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
