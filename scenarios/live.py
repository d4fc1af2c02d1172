"""A live simulated mission on loopback: the rover's two MAVLink links and its cameras.

    with LiveSim(preset("mixed")) as sim:
        sim.vehicle_url    # "udpout:127.0.0.1:P"  -> [vehicle] url of the companion
        sim.ground_url     # "udpout:127.0.0.1:Q"  -> rescue-hq --listen (the rover's GCS port)
        sim.camera_source  # "sim:127.0.0.1:C"     -> [camera] source of the companion
        sim.thermal_source # "sim:127.0.0.1:T"     -> [thermal] source of the companion
        sim.thermal_toml   # the whole [thermal] section (and [thermal.mount]) for it

Like ArduPilot SITL with two serial ports mapped to UDP: the companion talks to one,
the ground station to the other, and the rover routes between them the messages it
can check (not our dialect IDs: those travel inside TUNNEL). Both peers connect as
UDP clients, so the rover answers whoever spoke first on each port. Real time only:
camera frames carry wall-clock capture times that must match the poses.

The thermal camera (``thermal=True``, the default) is the Lepton beside the colour
camera (scenarios.camera.default_thermal_camera), rendered from the same world and
true pose at 8.7 frames/s on its own port; a companion uses it only when its config
has the ``[thermal]`` section ``thermal_toml`` gives.
"""

from __future__ import annotations

import dataclasses

from companion.calibration import camera_model
from companion.config import CameraConfig
from scenarios.camera import default_thermal_camera, thermal_toml
from scenarios.camserver import CameraServer, ThermalCameraServer
from scenarios.errors import SimError
from scenarios.render import Renderer
from scenarios.rover import SimRover
from scenarios.thermal import ThermalRenderer
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
    """A SimRover with a companion port, a ground port and a camera server (and a
    thermal camera server unless ``thermal`` is False)."""

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
        thermal: bool = True,
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
        self.thermal_camera = default_thermal_camera()
        self.thermal: ThermalCameraServer | None = None
        try:
            model = camera_model(camera or CameraConfig())
            self.camera = CameraServer(Renderer(self.world, model), self.rover.camera_pose, fps=fps)
        except Exception:
            self.rover.close()
            raise
        if thermal:
            try:
                renderer = ThermalRenderer(self.world, self.thermal_camera, seed=seed or 0)
                self.thermal = ThermalCameraServer(renderer, self.rover.camera_pose)
            except Exception:
                self.camera.close()
                self.rover.close()
                raise

    def start(self) -> LiveSim:
        self.rover.start()
        self.camera.start()
        if self.thermal is not None:
            self.thermal.start()
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

    def _thermal_server(self) -> ThermalCameraServer:
        if self.thermal is None:
            raise SimError("this LiveSim has no thermal camera (thermal=False)")
        return self.thermal

    @property
    def thermal_source(self) -> str:
        return f"sim:127.0.0.1:{self._thermal_server().address[1]}"

    @property
    def thermal_toml(self) -> str:
        """The companion's [thermal] section (with [thermal.mount]) for this thermal
        camera: its source, size, frame rate, intrinsics and mount, as a recording's
        camera.toml carries them."""
        server = self._thermal_server()
        return thermal_toml(self.thermal_camera, self.thermal_source, server.fps)

    @property
    def first_in_view_unix_s(self) -> dict[int, float]:
        """When each victim first showed enough of itself to either camera."""
        seen = dict(self.camera.first_in_view_unix_s)
        if self.thermal is not None:
            for vid, t in self.thermal.first_in_view_unix_s.items():
                seen[vid] = min(t, seen.get(vid, t))
        return seen

    def close(self) -> None:
        if self.thermal is not None:
            self.thermal.close()
        self.camera.close()
        self.rover.close()

    def __enter__(self) -> LiveSim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
