"""MAVLink 2 message signing: the key file and the acceptance policy.

The key is 32 bytes, stored either raw (32 bytes) or as 64 hex characters (with an
optional trailing newline). The file must not be readable or writable by group or
others (mode 0600 or stricter), like an SSH private key; otherwise SigningError.
The key never appears in logs, reprs or error messages.

Policy when signing is on: every outgoing message is signed. Incoming messages
that would change our state (RESCUE_ACK, RESCUE_OPERATOR_ACTION) are accepted only
with a valid signature; others (the autopilot's telemetry, which ArduPilot may not
sign) are accepted unsigned. Rejections are counted by the codec.

Replay protection (MAVLink 2 signing): each stream (link_id, system, component)
must carry increasing timestamps. pymavlink's ``check_signature`` records a frame's
timestamp before it checks the signature, so one forged frame with a far-future
timestamp made every later genuine frame of that stream look like a replay, and
raised our own outgoing timestamp. ``enable`` replaces it with ``check_signature``
below: the signature is verified first, and only a verified frame may advance a
stream's timestamp or ours.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import stat
import time
import types
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mavlink_io.dialect import RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID
from mavlink_io.errors import SigningError

log = logging.getLogger(__name__)

KEY_BYTES = 32
STATE_CHANGING_IDS = frozenset({RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID})
"""Message IDs that must be signed when signing is on."""

# MAVLink signing timestamps count 10 us units since 2015-01-01 00:00:00 UTC.
_SIGNING_EPOCH_UNIX_S = 1420070400
_NEW_STREAM_SLACK = 6_000_000  # a new stream may start up to 60 s behind our timestamp
_SIGNATURE_BLOCK = 13  # link_id (1), timestamp (6), signature (6)


@dataclass(frozen=True)
class Signing:
    """A signing key and its link ID. ``repr`` hides the key."""

    key: bytes = field(repr=False)
    link_id: int = 0
    must_sign_ids: frozenset[int] = STATE_CHANGING_IDS

    def __post_init__(self) -> None:
        if len(self.key) != KEY_BYTES:
            raise SigningError(f"signing key must be {KEY_BYTES} bytes, got {len(self.key)}")
        if not 0 <= self.link_id <= 255:
            raise SigningError(f"signing link_id must be in 0..255, got {self.link_id}")


def load_key(path: Path) -> bytes:
    """Read a 32-byte key (raw or 64 hex chars) from a file with mode 0600 or stricter."""
    try:
        st = path.stat()
    except OSError as exc:
        raise SigningError(f"signing key file {path}: cannot read: {exc.strerror}") from None
    if not stat.S_ISREG(st.st_mode):
        raise SigningError(f"signing key file {path}: not a regular file")
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SigningError(
            f"signing key file {path} has mode {stat.S_IMODE(st.st_mode):04o}: it must not be "
            f"accessible by group or others; run: chmod 600 {path}"
        )
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SigningError(f"signing key file {path}: cannot read: {exc.strerror}") from None
    if len(data) == KEY_BYTES:
        return data
    text = data.strip()
    if len(text) == 2 * KEY_BYTES:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    raise SigningError(
        f"signing key file {path}: expected {KEY_BYTES} raw bytes or {2 * KEY_BYTES} hex "
        f"characters, found {len(data)} bytes that are neither"
    )


def load_signing(path: Path, link_id: int = 0) -> Signing:
    """The Signing for a key file (see load_key)."""
    return Signing(load_key(path), link_id)


def signing_timestamp(unix_s: float | None = None) -> int:
    """The MAVLink signing timestamp (10 us units since 2015-01-01) for a wall time."""
    now = time.time() if unix_s is None else unix_s
    return max(0, int((now - _SIGNING_EPOCH_UNIX_S) * 100_000))


def enable(mav: Any, signing: Signing) -> None:
    """Turn on signing for a pymavlink MAVLink object (outgoing and the incoming policy)."""
    must_sign = signing.must_sign_ids

    def allow_unsigned(_mav: Any, msg_id: int) -> bool:
        return msg_id not in must_sign

    mav.signing.secret_key = signing.key
    mav.signing.link_id = signing.link_id
    mav.signing.timestamp = signing_timestamp()
    mav.signing.sign_outgoing = True
    mav.signing.allow_unsigned_callback = allow_unsigned
    mav.check_signature = types.MethodType(check_signature, mav)
    log.info("MAVLink 2 signing on (link_id %d)", signing.link_id)


def check_signature(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """True when a signed frame verifies and is not a replay (pymavlink's contract).

    Unlike pymavlink's own, nothing is recorded for a frame whose signature does
    not verify: a forger cannot move a stream's timestamp, or ours, forward.
    """
    state = mav.signing
    block = bytes(msgbuf[-_SIGNATURE_BLOCK:])
    link_id = block[0]
    timestamp = int.from_bytes(block[1:7], "little")
    digest = hashlib.sha256(state.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, block[7:]):
        return False
    stream = (link_id, src_system, src_component)
    last = state.stream_timestamps.get(stream)
    if last is not None and timestamp <= last:
        return False  # a replay, or older than what this stream already sent
    if last is None and timestamp + _NEW_STREAM_SLACK < state.timestamp:
        return False  # a new stream starting with an old frame: a replay
    state.stream_timestamps[stream] = timestamp
    state.timestamp = max(state.timestamp, timestamp)
    return True
