"""How the HQ's messages go out: a reply the way its message came, or to every link.

A reply travels the same link, to the same peer address, and, when its message
arrived inside a TUNNEL (through an autopilot or MAVProxy), wrapped in a TUNNEL
addressed to the robot.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from hq import wire
from mavlink_io.codec import Codec
from mavlink_io.hub import Endpoint, Peer


@dataclass(frozen=True)
class Route:
    """How to reach a robot: the link and peer it spoke from, and the envelope it used."""

    endpoint: int
    peer: Peer
    tunnel: bool
    sysid: int  # the outer sender (the TUNNEL's sender when tunnelled)
    compid: int


class Sender:
    """Encodes the HQ's messages (signed when the HQ has a key) and sends them."""

    def __init__(self, encoder: Codec, endpoints: Sequence[Endpoint]) -> None:
        self._encoder = encoder
        self._endpoints = list(endpoints)
        self.m = encoder.module  # the dialect's message classes and constants

    def send(self, msg: Any, route: Route) -> None:
        if route.tunnel:
            msg = wire.wrap_tunnel(self._encoder, msg, route.sysid, route.compid)
        data = self._encoder.encode(msg)
        self._endpoints[route.endpoint].send_to(data, route.peer)

    def broadcast(self, msg: Any) -> None:
        data = self._encoder.encode(msg)
        for ep in self._endpoints:
            ep.broadcast(data)
