"""The companion's links to the world, and where its messages to the ground go.

The vehicle link (the autopilot, and through it the ground) and the optional direct
link to rescue-hq (``[hq] url``) each start their reader thread when opened; what
they hear goes to ``on_dialect`` (the service queues it), so whatever that fills
must exist before ``Links`` is made.

Our dialect's messages (victim reports, acknowledgements of operator actions,
picture chunks, RESCUE_STATUS) go over the direct HQ link when there is one and,
with ``[hq] tunnel``, inside TUNNEL on the vehicle link for the autopilot to route.
Plain messages (STATUSTEXT) go on the vehicle link, where QGC hears them, and on the
direct HQ link. The reporter and processing threads both send.
"""

from __future__ import annotations

from collections.abc import Callable

from companion.config import Config
from mavlink_io.codec import Codec, MavMessage
from mavlink_io.hqlink import HqLink
from mavlink_io.linkspec import parse_link
from mavlink_io.reconnect import ReconnectingLink
from mavlink_io.signing import Signing
from mavlink_io.tlog import TlogWriter
from mavlink_io.vehicle import VehicleLink, VehicleSettings


class Links:
    def __init__(
        self,
        config: Config,
        signing: Signing | None,
        tlog: TlogWriter,
        *,
        health: Callable[[], int],
        on_dialect: Callable[[MavMessage], None],
    ) -> None:
        v = config.vehicle
        self.vehicle = VehicleLink(
            ReconnectingLink(parse_link(v.url), max_backoff_s=v.reopen_max_backoff_s),
            VehicleSettings(
                system_id=v.system_id,
                component_id=v.component_id,
                heartbeat_timeout_s=v.heartbeat_timeout_s,
                heartbeat_period_s=config.reporting.status_period_s,
                attitude_rate_hz=v.attitude_rate_hz,
                local_position_rate_hz=v.local_position_rate_hz,
                global_position_rate_hz=v.global_position_rate_hz,
                pose_history_s=v.pose_history_s,
            ),
            codec=Codec(v.system_id or 1, v.component_id, signing),
            health=health,
            tlog=tlog,
            on_dialect=on_dialect,
        )
        self.hq: HqLink | None = None
        if config.hq.url:
            self.hq = HqLink(
                ReconnectingLink(parse_link(config.hq.url), max_backoff_s=v.reopen_max_backoff_s),
                Codec(v.system_id or 1, v.component_id, signing),
                on_dialect,
                tlog,
            )
        self.tunnel = config.hq.tunnel

    def send_dialect(self, msg: MavMessage) -> None:
        if self.hq is not None:
            if self.vehicle.sysid:
                self.hq.codec.src_system = self.vehicle.sysid
            self.hq.send(msg)
        if self.tunnel:
            self.vehicle.send_tunnel(msg)

    def send_plain(self, msg: MavMessage) -> None:
        self.vehicle.send(msg)
        if self.hq is not None:
            self.hq.send(msg)

    def close(self) -> None:
        """The direct HQ link, then the vehicle link; safe twice."""
        if self.hq is not None:
            self.hq.close()
        self.vehicle.close()
