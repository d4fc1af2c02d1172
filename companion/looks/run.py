"""Closer looks on the live vehicle link: companion/looks/machine.py's steps, sent and heard.

``Looks`` runs on the processing thread (``tick`` after the ground's requests, a few
times a second), which owns the tracker: it takes the candidates from the tracker's
snapshots, the rover's position from the pose history and what the autopilot said
from an ``AutopilotWatch`` the vehicle link's reader thread fills, and sends the
commands (mavlink_io/guided.py) on the vehicle link. When the reader thread sees a
heartbeat with a mode the companion did not ask for, it marks the look taken over
at once: nothing more is sent, and the next tick ends the look and switches looks
off (``switch_off``: RC_LOOK_ON is set to 0, which the operator sets to 1 again).
The lines for people go through the announcer (STATUSTEXT); ``line`` is the count
of looks and what they settled, for the status, and ``tally`` the same in numbers
(RESCUE_STATUS). ``ask`` is the HQ operator's "look closer at victim N"
(companion/service/ground.py hands it over on the processing thread).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, assert_never

from companion.config import LooksConfig
from companion.looks.choose import candidates
from companion.looks.machine import LookMachine
from companion.looks.steps import (
    Command,
    Face,
    GoTo,
    RequestMissionCurrent,
    Rover,
    SetCurrent,
    SetMode,
)
from fusion.pose import PoseHistory
from fusion.registry import Victim
from mavlink_io import guided
from mavlink_io.codec import Codec, MavMessage

log = logging.getLogger(__name__)

_POSE_MAX_AGE_S = 2.0  # an older pose is no position for a look


@dataclass(frozen=True)
class Tally:
    """What the status says of the looks (RESCUE_STATUS): replaced whole, so the
    reporter thread reads one consistent value."""

    on: bool = False  # looks allowed now (RC_LOOK_ON and no take-over)
    made: int = 0
    confirmed: int = 0
    rejected: int = 0
    urgency_changed: int = 0
    aborted: int = 0


def tally(machine: LookMachine) -> Tally:
    c = machine.counts
    return Tally(
        on=machine.allowed,
        made=c.started,
        confirmed=c.settled.get("confirmed", 0),
        rejected=c.settled.get("rejected", 0),
        urgency_changed=c.settled.get("urgency changed", 0),
        aborted=sum(c.aborted.values()),
    )


class Vehicle(Protocol):
    """What the looks need of the vehicle link (mavlink_io.vehicle.VehicleLink; the
    simulator's closed loop, scenarios/inloop.py, has its own)."""

    poses: PoseHistory
    codec: Codec

    @property
    def sysid(self) -> int: ...

    @property
    def connected(self) -> bool: ...

    def listen(self, callback: Callable[[MavMessage, float], None]) -> None: ...

    def send(self, msg: MavMessage) -> bool: ...


class Announces(Protocol):
    def announce(self, text: str, severity: int) -> None: ...


class Looks:
    def __init__(
        self,
        settings: LooksConfig,
        vehicle: Vehicle,
        announcer: Announces,
        switch_off: Callable[[], None],
        *,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.machine = LookMachine(settings)
        self._vehicle = vehicle
        self._announcer = announcer
        self._switch_off = switch_off
        self._clock = clock
        self._wall = wall
        self._taken_over = threading.Event()  # set by the reader thread
        self.watch = guided.AutopilotWatch(lambda: vehicle.sysid)
        self.watch.on_foreign_mode = self._foreign_mode
        vehicle.listen(self.watch.on_message)
        self.line = ""  # "2 looks, 1 confirmed, ..." (replaced whole; read by the status)
        self.tally = tally(self.machine)  # replaced whole; read by the status
        if settings.enabled:
            log.info("closer looks are on (RC_LOOK_ON = 1)")

    def set_enabled(self, enabled: bool) -> None:
        """RC_LOOK_ON changed (or another parameter: then nothing changes here)."""
        m = self.machine
        if enabled != m.enabled or (enabled and m.switched_off):
            self._announcer.announce(f"closer looks {'on' if enabled else 'off'}", 6)
        m.set_enabled(enabled)
        self.tally = tally(m)

    def ask(self, victim: Victim) -> bool:
        """The operator asked for a closer look at ``victim`` (processing thread): it
        is the next look, when looks are on; with looks off nothing changes and the
        operator hears that they must switch them on. Whether it was taken."""
        m = self.machine
        vid = victim.victim_id
        if not m.allowed:
            self._announcer.announce(
                f"closer looks are off: no look at victim {vid}; the operator must switch "
                "them on (RC_LOOK_ON = 1, or looks on at the HQ)",
                4,
            )
            return False
        after = " after the one under way" if m.look is not None else ""
        m.ask(victim.track_id, vid, self._clock())
        self._announcer.announce(f"closer look at victim {vid} next{after} (the operator asked)", 6)
        return True

    def _foreign_mode(self, mode: int) -> None:
        """Reader thread: the operator (or a failsafe) changed the mode mid-look."""
        if not self._taken_over.is_set():
            log.warning("mode %s during a closer look: letting go", guided.mode_name(mode))
        self._taken_over.set()

    def tick(self, tracked: Callable[[], Sequence[Victim]]) -> None:
        """One step (processing thread); ``tracked``: the tracker's snapshots with the
        tentative ones (asked for only while looks are on or one is under way)."""
        m = self.machine
        now = self._clock()
        pose = self._vehicle.poses.latest()
        if pose is not None and now - pose.t_mono_s > _POSE_MAX_AGE_S:
            pose = None
        if not m.enabled and m.look is None:
            if pose is not None:  # the path driven is known free, for later looks
                m.path.add(pose.north_m, pose.east_m)
            return
        victims = tracked()
        was_off = m.switched_off
        if self._taken_over.is_set():
            m.operator_took_over()
        if pose is not None:
            rover = Rover(self._vehicle.connected, pose.north_m, pose.east_m, pose.yaw_rad)
        else:
            rover = Rover(self._vehicle.connected)
        found = candidates(victims, self._wall(), m.settings) if m.look is None else []
        by_track = {v.track_id: v for v in victims}
        commands, lines = m.step(now, rover, self.watch.snapshot(), found, by_track)
        self.watch.expect(m.expected_modes)
        if not self._taken_over.is_set():
            for c in commands:
                self._send(c)
        if m.look is None:
            self._taken_over.clear()
        for line in lines:
            log.info("closer looks: %s", line.text)
            self._announcer.announce(line.text, line.severity)
        if m.counts.started:
            self.line = m.counts.summary()
        self.tally = tally(m)
        if m.switched_off and not was_off:
            self._switch_off()

    def _send(self, c: Command) -> None:
        mod = self._vehicle.codec.module
        sysid = self._vehicle.sysid
        msg: MavMessage
        if isinstance(c, SetMode):
            msg = guided.set_mode(mod, sysid, c.mode)
        elif isinstance(c, GoTo):
            msg = guided.goto(mod, sysid, c.north_m, c.east_m)
        elif isinstance(c, Face):
            msg = guided.face(mod, sysid, c.yaw_rad)
        elif isinstance(c, SetCurrent):
            msg = guided.set_current(mod, sysid, c.seq)
        elif isinstance(c, RequestMissionCurrent):
            msg = guided.request_mission_current(mod, sysid)
        else:
            assert_never(c)
        log.debug("closer look sends %s", c)
        self._vehicle.send(msg)
