"""Autopilot telemetry into PoseSamples and a GlobalOrigin.

``PoseAssembler`` joins ATTITUDE and LOCAL_POSITION_NED, which arrive separately:
each message yields a PoseSample at its own boot time, completed with the latest of
the other kind if that is recent (``max_gap_s``); a position is carried forward by
its velocity to the attitude's time. Boot times map onto the companion's monotonic
clock through a ``BootClock``.

``OriginTracker`` keeps the EKF origin, by preference from GPS_GLOBAL_ORIGIN (the
origin itself), else from HOME_POSITION (home minus home's local position), else
from GLOBAL_POSITION_INT minus LOCAL_POSITION_NED at the same boot time. 0/0 is
never an origin.

``TelemetryDecoder`` validates every message once as it becomes typed values
(``convert``'s checks, and ``BootClock``'s refusal of a boot time off the current
timeline): a refused message changes nothing, is counted in ``refused`` by type,
and logged (the first of each type, then at most once per ``_LOG_EVERY_S``).
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from dataclasses import dataclass

from fusion.types import GlobalOrigin, PoseSample
from mavlink_io import convert
from mavlink_io.clock import BootClock, Sample
from mavlink_io.codec import MavMessage

log = logging.getLogger(__name__)

SOURCE_GPS_GLOBAL_ORIGIN = 3
SOURCE_HOME_POSITION = 2
SOURCE_DERIVED = 1
_SAME_INSTANT_S = 0.02  # GLOBAL_POSITION_INT and LOCAL_POSITION_NED of one EKF step
_LOG_EVERY_S = 10.0  # refused messages of one type are logged at most this often


class PoseAssembler:
    """Builds PoseSamples from ATTITUDE and LOCAL_POSITION_NED (one thread)."""

    def __init__(self, clock: BootClock, max_gap_s: float = 0.5) -> None:
        self._clock = clock
        self._max_gap_s = max_gap_s
        self._attitude: convert.AttitudeFields | None = None
        self._position: convert.LocalPositionFields | None = None

    def reset(self) -> None:
        self._attitude = None
        self._position = None

    def on_attitude(self, att: convert.AttitudeFields) -> PoseSample | None:
        self._attitude = att
        pos = self._position
        if pos is None or abs(att.t_boot_s - pos.t_boot_s) > self._max_gap_s:
            return None
        dt = att.t_boot_s - pos.t_boot_s
        return self._sample(
            att,
            pos,
            att.t_boot_s,
            (
                pos.north_m + pos.vn_m_s * dt,
                pos.east_m + pos.ve_m_s * dt,
                pos.down_m + pos.vd_m_s * dt,
            ),
        )

    def on_local_position(self, pos: convert.LocalPositionFields) -> PoseSample | None:
        self._position = pos
        att = self._attitude
        if att is None or abs(att.t_boot_s - pos.t_boot_s) > self._max_gap_s:
            return None
        return self._sample(att, pos, pos.t_boot_s, (pos.north_m, pos.east_m, pos.down_m))

    def _sample(
        self,
        att: convert.AttitudeFields,
        pos: convert.LocalPositionFields,
        t_boot_s: float,
        ned: tuple[float, float, float],
    ) -> PoseSample | None:
        if not self._clock.synced:
            return None
        return PoseSample(
            t_boot_s=t_boot_s,
            t_mono_s=self._clock.to_mono(t_boot_s),
            north_m=ned[0],
            east_m=ned[1],
            down_m=ned[2],
            roll_rad=att.roll_rad,
            pitch_rad=att.pitch_rad,
            yaw_rad=att.yaw_rad,
            vn_m_s=pos.vn_m_s,
            ve_m_s=pos.ve_m_s,
            vd_m_s=pos.vd_m_s,
        )


class OriginTracker:
    """The best-known EKF origin. Thread-safe reads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._origin: GlobalOrigin | None = None
        self._source = 0
        self._global: convert.GlobalPositionFields | None = None
        self.changes = 0

    @property
    def origin(self) -> GlobalOrigin | None:
        with self._lock:
            return self._origin

    def reset(self) -> None:
        with self._lock:
            self._origin = None
            self._source = 0
            self._global = None

    def _offer(self, origin: GlobalOrigin | None, source: int) -> bool:
        if origin is None:
            return False
        with self._lock:
            if source < self._source or (source == self._source == SOURCE_DERIVED):
                return False
            changed = origin != self._origin
            self._origin = origin
            self._source = source
            if changed:
                self.changes += 1
            return changed

    def on_gps_global_origin(self, msg: MavMessage) -> bool:
        """True when the origin changed; BadField when the message is out of range."""
        return self._offer(convert.parse_gps_global_origin(msg), SOURCE_GPS_GLOBAL_ORIGIN)

    def on_home_position(self, msg: MavMessage) -> bool:
        return self._offer(convert.parse_home_position(msg), SOURCE_HOME_POSITION)

    def on_global_position(self, glob: convert.GlobalPositionFields | None) -> None:
        self._global = glob

    def on_local_position(self, local: convert.LocalPositionFields | None) -> bool:
        """Derive an origin when a global and a local position describe one instant."""
        glob = self._global
        if local is None or glob is None or abs(glob.t_boot_s - local.t_boot_s) > _SAME_INSTANT_S:
            return False
        return self._offer(convert.origin_from_global_and_local(glob, local), SOURCE_DERIVED)


# -- one vehicle's telemetry, without a link ------------------------------------------

_MSG_ATTITUDE = 30
_MSG_LOCAL_POSITION_NED = 32
_MSG_GLOBAL_POSITION_INT = 33
_MSG_GPS_GLOBAL_ORIGIN = 49
_MSG_HOME_POSITION = 242
_MAV_TYPE_GCS = 6
_MAV_TYPE_ONBOARD_CONTROLLER = 18
_MAV_AUTOPILOT_INVALID = 8
AUTOPILOT_COMPONENT = 1


def is_autopilot_heartbeat(msg: MavMessage, system_id: int = 0) -> bool:
    """A HEARTBEAT from a flight/rover controller (component 1, not a GCS or a
    companion), of ``system_id`` when that is not 0."""
    return bool(
        msg.get_msgId() == 0
        and msg.get_srcComponent() == AUTOPILOT_COMPONENT
        and msg.type not in (_MAV_TYPE_GCS, _MAV_TYPE_ONBOARD_CONTROLLER)
        and msg.autopilot != _MAV_AUTOPILOT_INVALID
        and system_id in (0, msg.get_srcSystem())
    )


@dataclass(frozen=True)
class TelemetryUpdate:
    """What one autopilot message changed."""

    pose: PoseSample | None = None
    rebooted: bool = False  # boot time went backwards: poses before this are void
    origin_changed: bool = False


class TelemetryDecoder:
    """Pose samples, clock and origin from one autopilot's messages (one thread).

    The caller passes only the autopilot's own messages and their arrival times on
    its clock (the companion's monotonic clock live, the tlog's clock in replay).
    """

    def __init__(self, clock: BootClock | None = None) -> None:
        self.clock = clock if clock is not None else BootClock()
        self.origins = OriginTracker()
        self._assembler = PoseAssembler(self.clock)
        self.refused: Counter[str] = Counter()  # by message type
        self._last_log_s: dict[str, float] = {}

    def reset(self) -> None:
        self.clock.reset()
        self._assembler.reset()
        self.origins.reset()

    def handle(self, msg: MavMessage, t_arrival_s: float) -> TelemetryUpdate:
        try:
            return self._handle(msg, t_arrival_s)
        except convert.BadField as exc:
            self._refuse(msg.get_type(), str(exc), t_arrival_s)
            return TelemetryUpdate()

    def _handle(self, msg: MavMessage, t_arrival_s: float) -> TelemetryUpdate:
        msg_id = msg.get_msgId()
        if msg_id in (_MSG_ATTITUDE, _MSG_LOCAL_POSITION_NED):
            # Fields first: a message with absurd fields must not move the clock either.
            fields = (
                convert.attitude(msg) if msg_id == _MSG_ATTITUDE else convert.local_position(msg)
            )
            sample = self.clock.observe(fields.t_boot_s, t_arrival_s)
            if sample is Sample.REJECTED:
                self._refuse(
                    msg.get_type(),
                    f"time_boot_ms = {msg.time_boot_ms} is off the autopilot's timeline",
                    t_arrival_s,
                )
                return TelemetryUpdate()
            rebooted = sample is Sample.NEW_BOOT
            if rebooted:
                self._assembler.reset()
                self.origins.reset()
            if isinstance(fields, convert.AttitudeFields):
                return TelemetryUpdate(self._assembler.on_attitude(fields), rebooted)
            pose = self._assembler.on_local_position(fields)
            try:
                changed = self.origins.on_local_position(fields)
            except convert.BadField as exc:  # the pose stands; the derived origin does not
                self._refuse("GLOBAL_POSITION_INT", str(exc), t_arrival_s)
                changed = False
            return TelemetryUpdate(pose, rebooted, changed)
        if msg_id == _MSG_GLOBAL_POSITION_INT:
            self.origins.on_global_position(convert.global_position(msg))
        elif msg_id == _MSG_GPS_GLOBAL_ORIGIN:
            return TelemetryUpdate(origin_changed=self.origins.on_gps_global_origin(msg))
        elif msg_id == _MSG_HOME_POSITION:
            return TelemetryUpdate(origin_changed=self.origins.on_home_position(msg))
        return TelemetryUpdate()

    def _refuse(self, msg_type: str, reason: str, t_s: float) -> None:
        self.refused[msg_type] += 1
        last = self._last_log_s.get(msg_type)
        if last is None or not 0 <= t_s - last < _LOG_EVERY_S:
            self._last_log_s[msg_type] = t_s
            log.warning(
                "autopilot message refused: %s (%d %s refused so far)",
                reason,
                self.refused[msg_type],
                msg_type,
            )
