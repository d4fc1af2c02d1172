"""Carry a dialect message through the autopilot inside a standard TUNNEL (id 385).

ArduPilot routes only messages it can CRC-check, so our RESCUE_* messages would die
in the autopilot; TUNNEL is in common.xml and is routed to the ground station. The
payload is one complete MAVLink 2 frame of our dialect (header, payload, CRC and,
with signing on, the signature): the receiver decodes it with the same codec and
the same checks as a frame on a direct link.

``TUNNEL_PAYLOAD_TYPE`` = 32800: the range 32768-65535 is for private experiments
(MAV_TUNNEL_PAYLOAD_TYPE); 32800 is this project's. A frame longer than the 128-byte
TUNNEL payload cannot be carried (every RESCUE_* message fits: a signed
RESCUE_VICTIM_REPORT is at most 108 bytes with its cues, a signed RESCUE_PICTURE_CHUNK
exactly 128).
"""

from __future__ import annotations

from types import ModuleType

from mavlink_io import dialect
from mavlink_io.codec import Codec, MavMessage

TUNNEL_PAYLOAD_TYPE = 32800
TUNNEL_PAYLOAD_BYTES = 128


def pack_tunnel(
    frame: bytes,
    target_system: int = 0,
    target_component: int = 0,
    module: ModuleType | None = None,
) -> MavMessage:
    """A TUNNEL carrying ``frame`` (0/0 targets: broadcast, for whichever GCS listens)."""
    if len(frame) > TUNNEL_PAYLOAD_BYTES:
        raise ValueError(
            f"a {len(frame)}-byte frame does not fit TUNNEL's {TUNNEL_PAYLOAD_BYTES} bytes"
        )
    m = module if module is not None else dialect.load()
    payload = list(frame) + [0] * (TUNNEL_PAYLOAD_BYTES - len(frame))
    return m.MAVLink_tunnel_message(
        target_system, target_component, TUNNEL_PAYLOAD_TYPE, len(frame), payload
    )


def wrap(codec: Codec, msg: MavMessage, target_system: int = 0) -> MavMessage:
    """Encode ``msg`` with ``codec`` (sequence, signing) and pack it into a TUNNEL."""
    return pack_tunnel(codec.encode(msg), target_system, 0, codec.module)


def is_ours(msg: MavMessage) -> bool:
    """True for a TUNNEL with our payload type."""
    return bool(msg.get_type() == "TUNNEL" and msg.payload_type == TUNNEL_PAYLOAD_TYPE)


def unpack_tunnel(msg: MavMessage, codec: Codec) -> MavMessage | None:
    """The dialect message inside one of our TUNNELs; None if not ours or not valid."""
    if not is_ours(msg):
        return None
    length = int(msg.payload_length)
    if not 0 < length <= TUNNEL_PAYLOAD_BYTES:
        return None
    return codec.decode_frame(bytes(msg.payload[:length]))
