"""The simulated rover's route goes around what a rover cannot or must not drive over."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from scenarios.motion import Trajectory, lawnmower, route_of
from scenarios.pathplan import Obstacles, PlanParams, drivable_route
from scenarios.world import Debris, Victim, World, generate_world, preset

GREY = (150, 150, 150)


def _victim(north_m: float, east_m: float, heading_deg: float = 0.0) -> Victim:
    return Victim(
        1,
        north_m,
        east_m,
        math.radians(heading_deg),
        1.75,
        (190, 140, 110),
        (40, 60, 150),
        (50, 50, 60),
    )


def _path_cells(world: World, route: tuple[tuple[float, float], ...], step_m: float = 0.02):
    """Every point of the straight legs from the start through ``route``."""
    points = [world.start_ne_m, *route]
    for a, b in itertools.pairwise(points):
        n = max(2, math.ceil(math.dist(a, b) / step_m))
        for s in np.linspace(0.0, 1.0, n):
            yield (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]))


def _min_clearance_m(world: World, route: tuple[tuple[float, float], ...]) -> float:
    """The least distance from the route to anything the rover must keep off."""
    touching = Obstacles(world, PlanParams(clearance_m=0.0))
    cell = touching.cell_m
    centres = (np.argwhere(touching.blocked) + 0.5) * cell
    best = math.inf
    for p in _path_cells(world, route, 0.05):
        best = min(best, float(np.hypot(*(centres - np.array(p)).T).min()) - cell / 2)
    return best


def test_a_free_floor_keeps_the_lawnmower_as_it_is() -> None:
    world = World()
    assert route_of(world) == lawnmower(world)


def test_a_crate_on_the_lane_is_driven_around_and_the_lane_taken_again() -> None:
    crate = Debris.box("carton", GREY, 5.0, 0.6, 0.8, 0.6, 0.0)
    world = World(debris=(crate,))
    route = route_of(world)
    assert route[-1] == lawnmower(world)[-1]
    assert _min_clearance_m(world, route) >= PlanParams().clearance_m - 0.06
    # Back on the lane (east 0.6) before the lane's end, not cutting across the floor.
    beyond = [p for p in route if 7.0 <= p[0] <= 11.4 and p[1] < 1.5]
    assert beyond and all(abs(p[1] - 0.6) < 0.05 for p in beyond)


def test_a_victim_and_a_flat_pile_on_them_are_not_driven_over() -> None:
    """A tarp is driven over anywhere else; on a person it is a pile."""
    person = _victim(5.0, 2.3)
    tarp_on_person = Debris.box("tarp", GREY, 5.0, 2.3, 1.0, 1.0, 0.0)
    tarp_elsewhere = Debris.box("tarp", GREY, 8.0, 4.0, 1.0, 1.0, 0.0)
    world = World(victims=(person,), debris=(tarp_on_person, tarp_elsewhere))
    grid = Obstacles(world, PlanParams(clearance_m=0.0))
    assert grid.blocked[grid.cell((5.0, 2.3))]
    assert not grid.blocked[grid.cell((8.0, 4.0))]
    route = route_of(world)
    assert _min_clearance_m(world, route) >= PlanParams().clearance_m - 0.06
    lawn = lawnmower(world)  # the plain lanes ran over the person
    assert any(grid.blocked[grid.cell(p)] for p in _path_cells(world, lawn))


def test_a_waypoint_inside_an_obstacle_moves_out_and_a_walled_in_one_is_skipped() -> None:
    racking = Debris.box("racking", GREY, 6.0, 4.0, 1.0, 1.0, 0.0)
    walls = tuple(
        Debris.box("racking", GREY, 2.0 + dn, 6.0 + de, ln, lw, 0.0)
        for dn, de, ln, lw in (
            (0.0, 1.0, 2.2, 0.1),
            (0.0, -1.0, 2.2, 0.1),
            (1.0, 0.0, 0.1, 2.2),
            (-1.0, 0.0, 0.1, 2.2),
        )
    )
    world = World(debris=(racking, *walls))
    route = drivable_route(world, ((6.0, 4.0), (2.0, 6.0), (10.0, 6.0)))
    grid = Obstacles(world)
    assert all(not grid.blocked[grid.cell(p)] for p in route)
    assert math.dist(route[0], (6.0, 4.0)) < 1.0  # the nearest free place to the first
    assert route[-1] == (10.0, 6.0)
    assert all(math.dist(p, (2.0, 6.0)) > 0.5 for p in route)  # inside the walls: skipped


@pytest.mark.parametrize(
    "world",
    [preset("mixed"), generate_world(1), generate_world(2), generate_world(7)],
    ids=["mixed", "seed1", "seed2", "seed7"],
)
def test_the_driven_path_keeps_off_debris_and_bodies(world: World) -> None:
    """The rover's true path (turn-rate limits and all), not only its waypoints."""
    route = route_of(world)
    assert route == route_of(world)  # deterministic
    touching = Obstacles(world, PlanParams(clearance_m=0.1))
    trajectory = Trajectory(world.start_ne_m, world.start_heading_rad, route, seed=world.seed)
    for t in np.arange(0.0, trajectory.duration_s(), 0.1):
        pose = trajectory.pose_at(float(t))
        assert not touching.blocked[touching.cell((pose.north_m, pose.east_m))], (t, pose)
