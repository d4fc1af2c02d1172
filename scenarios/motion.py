"""How the simulated rover moves: routes, its true trajectory, and its estimate's error.

Times are simulation seconds ``t_s`` since the simulation started (not boot time:
the autopilot's boot clock restarts when it reboots, the world's clock does not).

- ``lawnmower(world)``: lanes along the floor's long side (north), ``lane_spacing_m``
  apart, inside a margin.
- ``route_of(world)``: the world's route (or the lawnmower) as a rover drives it:
  around tall debris, piles on people and the people themselves
  (``scenarios.pathplan``), back on the lane after each detour.
- ``Trajectory``: a skid-steer rover following waypoints at ``speed_m_s`` with a
  turn-rate limit, slowing for and turning in place at sharp corners, with a
  little roll and pitch from the rough floor. Deterministic: the state is
  integrated at a fixed step from the start and cached, so ``pose_at(t)`` is a pure
  function of t whatever order it is asked in.
- ``PoseError``: the autopilot's estimate = truth + a slow drift (sums of slow
  sinusoids with seeded phases) + white noise (drawn by the caller).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from scenarios.camera import VEHICLE_HEIGHT_M
from scenarios.pathplan import drivable_route
from scenarios.world import PointNE, World

_DT_S = 0.02  # integration step
_ARRIVE_M = 0.12  # a waypoint counts as reached this close
_TURN_IN_PLACE_RAD = math.radians(50.0)  # heading errors above this stop forward motion
_HEADING_GAIN = 2.5  # yaw-rate command per radian of heading error, 1/s
_ACCEL_M_S2 = 0.4


@dataclass(frozen=True)
class TruePose:
    """The vehicle's true state (local NED of the world) at simulation time t_s."""

    t_s: float
    north_m: float
    east_m: float
    down_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    vn_m_s: float = 0.0
    ve_m_s: float = 0.0
    vd_m_s: float = 0.0
    yaw_rate_rad_s: float = 0.0


def lawnmower(
    world: World, lane_spacing_m: float = 2.0, margin_m: float = 0.6
) -> tuple[PointNE, ...]:
    """Lanes north and back, stepping east, covering the floor inside the margin."""
    n_lo, n_hi = margin_m, world.size_m[0] - margin_m
    e_lo, e_hi = margin_m, world.size_m[1] - margin_m
    if n_hi <= n_lo or e_hi <= e_lo:
        raise ValueError(f"floor {world.size_m} is too small for a margin of {margin_m} m")
    lanes = max(1, math.ceil((e_hi - e_lo) / lane_spacing_m) + 1)
    step = (e_hi - e_lo) / (lanes - 1) if lanes > 1 else 0.0
    points: list[PointNE] = []
    for i in range(lanes):
        e = round(e_lo + i * step, 4)
        ends = (n_lo, n_hi) if i % 2 == 0 else (n_hi, n_lo)
        points += [(ends[0], e), (ends[1], e)]
    return tuple(points)


def route_of(world: World) -> tuple[PointNE, ...]:
    """The world's own route, or the default lawnmower, driven around obstacles and
    bodies (scenarios.pathplan)."""
    return drivable_route(world, world.route_ne_m or lawnmower(world))


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


class _Wobble:
    """Roll and pitch from the rough floor: seeded sums of sinusoids, scaled by speed."""

    def __init__(self, seed: int) -> None:
        rng = np.random.default_rng([seed, 0x30B])
        self.freq_hz = rng.uniform(0.3, 2.5, (2, 4))
        self.amp_rad = np.radians(rng.uniform(0.2, 0.7, (2, 4)))
        self.phase = rng.uniform(0, 2 * math.pi, (2, 4))
        self.tilt_rad = np.radians(rng.uniform(-0.5, 0.5, 2))  # the floor is not level

    def at(self, t_s: float, speed_share: float) -> tuple[float, float]:
        s = (self.amp_rad * np.sin(2 * math.pi * self.freq_hz * t_s + self.phase)).sum(axis=1)
        return (
            float(self.tilt_rad[0] + speed_share * s[0]),
            float(self.tilt_rad[1] + speed_share * s[1]),
        )


class Trajectory:
    """The rover's true motion along a route (see the module docstring)."""

    def __init__(
        self,
        start_ne_m: PointNE,
        start_heading_rad: float,
        route: tuple[PointNE, ...],
        *,
        speed_m_s: float = 0.4,
        turn_rate_rad_s: float = math.radians(45.0),
        seed: int = 0,
        height_m: float = VEHICLE_HEIGHT_M,
        start_speed_m_s: float = 0.0,
        final_heading_rad: float | None = None,
        blocked: tuple[tuple[float, float, float], ...] = (),
    ) -> None:
        """``start_speed_m_s``, ``final_heading_rad`` (turn in place to it once the
        route is done) and ``blocked`` (discs (north_m, east_m, radius_m) the rover
        cannot enter: it stops at their edge, wheels spinning) serve the simulated
        autopilot's GUIDED driving (scenarios/autopilot_drive.py); their defaults
        leave the motion exactly as it always was."""
        if speed_m_s <= 0 or turn_rate_rad_s <= 0:
            raise ValueError("speed_m_s and turn_rate_rad_s must be positive")
        self.route = tuple(route)
        self.final_heading_rad = final_heading_rad
        self.blocked = tuple(blocked)
        self.speed_m_s = speed_m_s
        self.turn_rate_rad_s = turn_rate_rad_s
        self.height_m = height_m
        self._wobble = _Wobble(seed)
        # Integrated states: columns n, e, yaw, speed, yaw_rate; one row per _DT_S.
        self._states = [
            np.array([start_ne_m[0], start_ne_m[1], start_heading_rad, start_speed_m_s, 0.0])
        ]
        self._target = 0
        self._target_steps: list[int] = []  # the state index at which each waypoint was reached
        self.finished_at_s: float | None = None if self.route else 0.0

    @classmethod
    def for_world(cls, world: World, **kwargs: Any) -> Trajectory:
        return cls(
            world.start_ne_m, world.start_heading_rad, route_of(world), seed=world.seed, **kwargs
        )

    def _step(self) -> None:
        n, e, yaw, v, _ = self._states[-1]
        if self._target >= len(self.route):
            v_cmd, yaw_rate = 0.0, 0.0
            if self.final_heading_rad is not None and abs(v) < 1e-3:
                err = _wrap(self.final_heading_rad - yaw)
                yaw_rate = max(
                    -self.turn_rate_rad_s, min(self.turn_rate_rad_s, _HEADING_GAIN * err)
                )
        else:
            tn, te = self.route[self._target]
            dist = math.hypot(tn - n, te - e)
            if dist < _ARRIVE_M:
                self._target += 1
                self._target_steps.append(len(self._states))
                if self._target >= len(self.route) and self.finished_at_s is None:
                    self.finished_at_s = (len(self._states) - 1) * _DT_S
                self._states.append(np.array([n, e, yaw, v, 0.0]))
                return
            err = _wrap(math.atan2(te - e, tn - n) - yaw)
            yaw_rate = max(-self.turn_rate_rad_s, min(self.turn_rate_rad_s, _HEADING_GAIN * err))
            share = max(0.0, 1.0 - abs(err) / _TURN_IN_PLACE_RAD)
            v_cmd = self.speed_m_s * share * min(1.0, dist / 0.3 + 0.3)
        dv = max(-_ACCEL_M_S2 * _DT_S, min(_ACCEL_M_S2 * _DT_S, v_cmd - v))
        v = v + dv
        yaw_new = _wrap(yaw + yaw_rate * _DT_S)
        mid = yaw + 0.5 * yaw_rate * _DT_S
        n_new, e_new = n + v * math.cos(mid) * _DT_S, e + v * math.sin(mid) * _DT_S
        if self.blocked and any(
            math.hypot(n_new - bn, e_new - be) < br for bn, be, br in self.blocked
        ):
            n_new, e_new, v = n, e, 0.0  # against the obstacle: no progress
        self._states.append(np.array([n_new, e_new, yaw_new, v, yaw_rate]))

    def _ensure(self, index: int) -> None:
        while len(self._states) <= index:
            self._step()

    def pose_at(self, t_s: float) -> TruePose:
        if t_s < 0:
            raise ValueError(f"t_s must be >= 0, got {t_s}")
        x = t_s / _DT_S
        i = int(x)
        self._ensure(i + 1)
        a, b = self._states[i], self._states[i + 1]
        f = x - i
        n = a[0] + (b[0] - a[0]) * f
        e = a[1] + (b[1] - a[1]) * f
        yaw = _wrap(a[2] + _wrap(b[2] - a[2]) * f)
        v = a[3] + (b[3] - a[3]) * f
        roll, pitch = self._wobble.at(t_s, min(1.0, v / self.speed_m_s))
        return TruePose(
            t_s=t_s,
            north_m=float(n),
            east_m=float(e),
            down_m=-self.height_m,
            roll_rad=roll,
            pitch_rad=pitch,
            yaw_rad=float(yaw),
            vn_m_s=float(v * math.cos(yaw)),
            ve_m_s=float(v * math.sin(yaw)),
            yaw_rate_rad_s=float(b[4]),
        )

    def target_at(self, t_s: float) -> int:
        """The index of the route point the rover is driving to at t_s (len(route)
        once it has reached the last)."""
        i = int(max(0.0, t_s) / _DT_S) + 1
        self._ensure(i)
        return sum(1 for step in self._target_steps if step <= i)

    def duration_s(self, limit_s: float = 3600.0) -> float:
        """Time to finish the route (integrating up to limit_s)."""
        while self.finished_at_s is None and len(self._states) * _DT_S < limit_s:
            self._step()
        return self.finished_at_s if self.finished_at_s is not None else limit_s


class PoseError:
    """The estimate's slow drift, a deterministic function of simulation time."""

    def __init__(
        self, seed: int, drift_m: float = 0.08, drift_yaw_rad: float = math.radians(1.0)
    ) -> None:
        rng = np.random.default_rng([seed, 0xD21F7])
        self.period_s = rng.uniform(40.0, 240.0, (3, 3))
        self.phase = rng.uniform(0, 2 * math.pi, (3, 3))
        self.amp = np.array([[drift_m] * 3, [drift_m] * 3, [drift_yaw_rad] * 3]) / math.sqrt(3)

    def drift(self, t_s: float) -> tuple[float, float, float]:
        """(north_m, east_m, yaw_rad) error of the estimate at t_s."""
        s = (self.amp * np.sin(2 * math.pi * t_s / self.period_s + self.phase)).sum(axis=1)
        return float(s[0]), float(s[1]), float(s[2])


class SimClock:
    """Simulation time for a live run: monotonic time since start times ``time_scale``.

    ``unix_s(t_s)`` puts simulation time on the wall clock; with time_scale 1 it is
    time.time() at that instant, so frames and telemetry share the companion's clock.
    """

    def __init__(self, time_scale: float = 1.0) -> None:
        if time_scale <= 0:
            raise ValueError(f"time_scale must be positive, got {time_scale}")
        self.time_scale = time_scale
        self._mono0 = time.monotonic()
        self._unix0 = time.time()

    def now_s(self) -> float:
        return (time.monotonic() - self._mono0) * self.time_scale

    def unix_s(self, t_s: float) -> float:
        return self._unix0 + t_s

    def wall_delay_s(self, sim_s: float) -> float:
        """Wall seconds for sim_s of simulation time."""
        return sim_s / self.time_scale
