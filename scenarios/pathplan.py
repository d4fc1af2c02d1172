"""Routes a rover can drive: around what it cannot climb and what it must not drive on.

A rescue rover (or its operator) keeps off:

- debris taller than ``climb_m`` (cartons, racking, slabs, beams, pallets);
- every piece of debris that lies on a victim, however flat: a pile over a person;
- every victim's body;
- the solid warm objects (a radiator, a pipe, machinery, a dog);
- the walls at the floor's edge;

each grown by ``clearance_m`` (half the rover's width and a margin). Without this the
simulated rover drove straight through crates and along bodies on its lawnmower
lanes, and the camera saw the inside of a carton or a torso from above, views no
real rover gives (on 2026-11-27 up to 9.7 m of the 60.8 m suite route ran through
tall debris and 2.4 m over bodies).

``drivable_route`` plans each leg between two waypoints on a grid of ``cell_m`` by
A* (8-connected, octile distance, and a cost for leaving the leg's straight line so
that a detour comes back to the lane), then keeps only the points line of sight
needs. A waypoint inside an obstacle moves to the nearest free cell; a waypoint that
cannot be reached from the last one is skipped. Pure and deterministic: the same
world and route give the same path.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import cv2
import numpy as np

from scenarios.world import PointNE, World


@dataclass(frozen=True)
class PlanParams:
    cell_m: float = 0.05
    clearance_m: float = 0.3  # the rover's half width (0.2 m) and 0.1 m to spare
    climb_m: float = 0.05  # debris up to this height is driven over (sheets, tarps, cables)
    # Cost per metre driven of each metre off the leg's straight line: a detour leaves
    # the lane only where an obstacle makes it, and comes back (a lane is the camera's
    # sweep of the floor; A* alone has many equally short paths, some off the lane).
    off_lane_cost: float = 0.5
    simplify_m: float = 0.2  # the kept points stay this close to the planned path


class Obstacles:
    """The floor as a grid: True where the rover's centre must not be."""

    def __init__(self, world: World, params: PlanParams | None = None) -> None:
        p = params or PlanParams()
        self.params = p
        self.cell_m = p.cell_m
        rows = max(1, math.ceil(world.size_m[0] / p.cell_m))
        cols = max(1, math.ceil(world.size_m[1] / p.cell_m))
        bodies = np.zeros((rows, cols), np.uint8)
        for victim in world.victims:
            for part in victim.parts():
                self._fill(bodies, part.polygon_ne_m)
        solid = bodies.copy()
        for piece in world.debris:
            footprint = np.zeros_like(bodies)
            self._fill(footprint, piece.polygon)
            if piece.height_m > p.climb_m or (footprint & bodies).any():
                solid |= footprint
        for thing in world.warm_objects:  # a radiator, pipe, machine or dog is in the way
            if thing.solid:
                self._fill(solid, thing.polygon)
        free = np.pad(1 - solid, 1, constant_values=0)  # beyond the floor: walls
        # Distance (m) from each cell to the nearest blocked one.
        dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
        self.blocked: np.ndarray = dist * p.cell_m <= p.clearance_m

    def _fill(self, grid: np.ndarray, polygon_ne_m: np.ndarray) -> None:
        pts = np.asarray(polygon_ne_m, dtype=np.float64)[:, ::-1] / self.cell_m - 0.5
        hull = cv2.convexHull(np.round(pts).astype(np.int32))
        cv2.fillConvexPoly(grid, hull, 1)

    def cell(self, point: PointNE) -> tuple[int, int]:
        rows, cols = self.blocked.shape
        r = min(rows - 1, max(0, int(point[0] / self.cell_m)))
        c = min(cols - 1, max(0, int(point[1] / self.cell_m)))
        return r, c

    def point(self, cell: tuple[int, int]) -> PointNE:
        return (
            round((cell[0] + 0.5) * self.cell_m, 4),
            round((cell[1] + 0.5) * self.cell_m, 4),
        )

    def nearest_free(self, cell: tuple[int, int]) -> tuple[int, int] | None:
        if not self.blocked[cell]:
            return cell
        free = np.argwhere(~self.blocked)
        if len(free) == 0:
            return None
        d2 = ((free - np.array(cell)) ** 2).sum(axis=1)
        r, c = free[int(np.argmin(d2))]
        return int(r), int(c)

    def line_free(self, a: tuple[int, int], b: tuple[int, int]) -> bool:
        n = max(abs(b[0] - a[0]), abs(b[1] - a[1])) * 2 + 1
        rs = np.round(np.linspace(a[0], b[0], n)).astype(int)
        cs = np.round(np.linspace(a[1], b[1], n)).astype(int)
        return not bool(self.blocked[rs, cs].any())

    def path(self, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]] | None:
        """A* over free cells, 8-connected, each step also paying for its distance
        from the straight line start-goal; None when the goal cannot be reached."""
        if start == goal:
            return [start]
        rows, cols = self.blocked.shape
        steps = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc]
        length = math.hypot(goal[0] - start[0], goal[1] - start[1])
        lane_r, lane_c = (goal[0] - start[0]) / length, (goal[1] - start[1]) / length
        off_cost = self.params.off_lane_cost * self.cell_m
        blocked = self.blocked.ravel().tolist()  # plain lookups: this loop is hot

        def off(c: tuple[int, int]) -> float:
            return abs(lane_r * (c[1] - start[1]) - lane_c * (c[0] - start[0]))

        def h(c: tuple[int, int]) -> float:
            dr, dc = abs(c[0] - goal[0]), abs(c[1] - goal[1])
            return max(dr, dc) + (math.sqrt(2) - 1) * min(dr, dc)

        best = {start: 0.0}
        came: dict[tuple[int, int], tuple[int, int]] = {}
        heap = [(h(start), 0.0, start)]
        while heap:
            _f, g, cur = heapq.heappop(heap)
            if cur == goal:
                out = [cur]
                while cur in came:
                    cur = came[cur]
                    out.append(cur)
                return out[::-1]
            if g > best.get(cur, math.inf):
                continue
            for dr, dc in steps:
                nxt = (cur[0] + dr, cur[1] + dc)
                if (
                    not (0 <= nxt[0] < rows and 0 <= nxt[1] < cols)
                    or blocked[nxt[0] * cols + nxt[1]]
                ):
                    continue
                step = math.sqrt(2) if dr and dc else 1.0
                ng = g + step * (1.0 + off_cost * off(nxt))
                if ng < best.get(nxt, math.inf):
                    best[nxt] = ng
                    came[nxt] = cur
                    heapq.heappush(heap, (ng + h(nxt), ng, nxt))
        return None

    def simplify(self, cells: list[tuple[int, int]]) -> list[tuple[int, int]]:
        """The cells to keep: from each kept cell, the farthest one the straight line
        reaches free of obstacles and within ``simplify_m`` of the cells between."""
        tol = self.params.simplify_m / self.cell_m
        pts = np.array(cells, float)
        out = [cells[0]]
        i = 0
        while i < len(cells) - 1:
            j = len(cells) - 1
            while j > i + 1 and not (
                self.line_free(cells[i], cells[j]) and _max_off(pts[i : j + 1]) <= tol
            ):
                j -= 1
            out.append(cells[j])
            i = j
        return out


def _max_off(pts: np.ndarray) -> float:
    """The largest distance of ``pts`` from the line through the first and the last."""
    d = pts[-1] - pts[0]
    n = float(np.hypot(*d))
    if n == 0.0:
        return 0.0
    rel = pts - pts[0]
    return float(np.abs(d[0] * rel[:, 1] - d[1] * rel[:, 0]).max() / n)


def drivable_route(
    world: World, route: tuple[PointNE, ...], params: PlanParams | None = None
) -> tuple[PointNE, ...]:
    """``route``, from the world's start, with every leg going around the obstacles
    (module docstring). Where nothing can be reached (a floor all obstacle, a start
    walled in), the route as given."""
    obstacles = Obstacles(world, params)
    start = world.start_ne_m
    here = obstacles.nearest_free(obstacles.cell(start))
    if here is None:
        return route  # nowhere to drive: the floor is all obstacle
    out: list[PointNE] = []
    if here != obstacles.cell(start):
        out.append(obstacles.point(here))  # out of the obstacle the rover starts in
    for waypoint in route:
        goal = obstacles.nearest_free(obstacles.cell(waypoint))
        if goal is None:
            continue
        cells = obstacles.path(here, goal)
        if cells is None:
            continue  # cut off from here: go on to the next waypoint
        out += [obstacles.point(c) for c in obstacles.simplify(cells)[1:-1]]
        # The leg's end: the waypoint itself where it is free, else the nearest free cell.
        out.append(waypoint if goal == obstacles.cell(waypoint) else obstacles.point(goal))
        here = goal
    return tuple(out) if out else route
