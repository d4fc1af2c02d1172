"""How the simulated autopilot drives: its flight mode, its mission and GUIDED targets.

ArduPilot Rover's behaviour, as far as the companion's closer looks use it:
- AUTO (custom mode 10) drives the mission: the route's points are mission items
  1..n (item 0 is home, as in ArduPilot), and MISSION_CURRENT reports the item the
  rover is driving to. Entering AUTO resumes the mission at its current item;
  setting the current item while in AUTO drives to it from where the rover is.
- GUIDED (15) drives to the last position target (SET_POSITION_TARGET_LOCAL_NED)
  and stops there; a target that ignores the position but not the yaw turns the
  rover in place to that heading. Without a target it stands still.
- HOLD (4) stops. MANUAL (0) is the operator driving with the sticks; the simulator
  has no sticks, so the rover stops as in HOLD.
Changing the current item in another mode only sets where AUTO will resume.

Until the first mode change the motion is the world's route exactly as
scenarios.motion.Trajectory drives it (the recorded missions stay as they were);
every change starts a new segment from the rover's state at that instant. ``pose_at``
is a pure function of time for the times already driven: a segment begins at the
instant its command arrived and the earlier segments are never changed.

``blocked`` discs (north_m, east_m, radius_m) are a test's obstacle: a segment that
starts after a disc was placed cannot enter it (the rover is stuck at its edge).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from scenarios.motion import Trajectory, TruePose

MODE_MANUAL = 0
MODE_HOLD = 4
MODE_AUTO = 10
MODE_GUIDED = 15
MODES = frozenset({MODE_MANUAL, MODE_HOLD, MODE_AUTO, MODE_GUIDED})
MODE_NAMES = {MODE_MANUAL: "MANUAL", MODE_HOLD: "HOLD", MODE_AUTO: "AUTO", MODE_GUIDED: "GUIDED"}


@dataclass(frozen=True)
class _Segment:
    t0_s: float
    trajectory: Trajectory
    first_item: int  # the route index of trajectory.route[0] (AUTO segments)
    auto: bool


class Drive:
    """The autopilot's motion: a base trajectory, then segments after each command."""

    def __init__(self, base: Trajectory) -> None:
        self.base = base
        self.mission = base.route
        self.mode = MODE_AUTO
        self.blocked: tuple[tuple[float, float, float], ...] = ()
        self._segments = [_Segment(0.0, base, 0, True)]
        self._item = 0  # where AUTO resumes (route index) when not in AUTO

    # -- queries -------------------------------------------------------------------------

    def _segment(self, t_s: float) -> _Segment:
        for seg in reversed(self._segments):
            if seg.t0_s <= t_s:
                return seg
        return self._segments[0]

    def pose_at(self, t_s: float) -> TruePose:
        seg = self._segment(t_s)
        return dataclasses.replace(seg.trajectory.pose_at(t_s - seg.t0_s), t_s=t_s)

    def route_index(self, t_s: float) -> int:
        """The route index the mission is at (being driven to in AUTO)."""
        seg = self._segment(t_s)
        if not seg.auto:
            return self._item
        return min(len(self.mission), seg.first_item + seg.trajectory.target_at(t_s - seg.t0_s))

    def mission_seq(self, t_s: float) -> int:
        """MISSION_CURRENT's seq: mission item i + 1 for route index i (0 is home)."""
        return min(self.route_index(t_s), max(0, len(self.mission) - 1)) + 1

    def mission_done(self, t_s: float) -> bool:
        """In AUTO with the whole route driven."""
        seg = self._segment(t_s)
        return seg.auto and self.route_index(t_s) >= len(self.mission)

    @property
    def mission_items(self) -> int:
        return len(self.mission) + 1  # with home

    # -- commands --------------------------------------------------------------------

    def _start(
        self, t_s: float, route: tuple[tuple[float, float], ...], **kw: object
    ) -> Trajectory:
        p = self.pose_at(t_s)
        traj = Trajectory(
            (p.north_m, p.east_m),
            p.yaw_rad,
            route,
            speed_m_s=self.base.speed_m_s,
            turn_rate_rad_s=self.base.turn_rate_rad_s,
            height_m=self.base.height_m,
            start_speed_m_s=math.hypot(p.vn_m_s, p.ve_m_s),
            blocked=self.blocked,
            **kw,  # type: ignore[arg-type]
        )
        return traj

    def _cut(self, t_s: float) -> None:
        """Forget segments that would start after t_s (none: commands come in order)."""
        self._segments = [s for s in self._segments if s.t0_s <= t_s]

    def set_mode(self, mode: int, t_s: float) -> None:
        if mode not in MODES:
            raise ValueError(f"mode {mode} is not simulated")
        if self.mode == MODE_AUTO and mode != MODE_AUTO:
            self._item = self.route_index(t_s)
        self._cut(t_s)
        self.mode = mode
        if mode == MODE_AUTO:
            self._resume(t_s, self._item)
        else:  # GUIDED without a target, HOLD, MANUAL (no sticks): stop where it is
            self._segments.append(_Segment(t_s, self._start(t_s, ()), 0, False))

    def _resume(self, t_s: float, index: int) -> None:
        index = max(0, min(index, len(self.mission)))
        traj = self._start(t_s, self.mission[index:])
        self._segments.append(_Segment(t_s, traj, index, True))

    def set_current(self, seq: int, t_s: float) -> bool:
        """MISSION_SET_CURRENT: False when seq is not a mission waypoint."""
        if not 1 <= seq <= len(self.mission):
            return False
        self._item = seq - 1
        if self.mode == MODE_AUTO:
            self._cut(t_s)
            self._resume(t_s, self._item)
        return True

    def guided_target(
        self, t_s: float, target_ne_m: tuple[float, float] | None, yaw_rad: float | None
    ) -> bool:
        """A GUIDED position and/or heading target; False outside GUIDED."""
        if self.mode != MODE_GUIDED or (target_ne_m is None and yaw_rad is None):
            return False
        self._cut(t_s)
        route = () if target_ne_m is None else (target_ne_m,)
        traj = self._start(t_s, route, final_heading_rad=yaw_rad)
        self._segments.append(_Segment(t_s, traj, 0, False))
        return True
