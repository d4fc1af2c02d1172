"""Encode and decode MAVLink frames of our dialect; decoding never raises.

``Codec.feed(bytes)`` returns every complete, valid message in the stream so far.
It frames the stream itself and lets pymavlink's generated ``MAVLink.decode`` check
and unpack each candidate frame (CRC with CRC_EXTRA, signature):

- bytes before a start marker (0xFD for MAVLink 2, 0xFE for MAVLink 1) are garbage;
- a candidate frame that fails its check (bad CRC, bad flags, bad length) gives up
  only its first byte, and the search for a start marker resumes at the next byte,
  so a valid frame hidden inside a corrupt one is still found (pymavlink's robust
  parser drops the whole candidate length and loses it);
- a frame with a message ID we do not know cannot be checked (no CRC_EXTRA); it is
  accepted as ``UNKNOWN_<id>`` only when its header continues a sender we already
  know (same system and component as a checked frame, sequence number 1 to
  ``_MAX_SEQ_GAP`` ahead of that sender's last one), otherwise it is garbage. A false
  start marker in corrupt bytes passes that test with odds of about 1 in 2 million,
  so it cannot swallow the valid frames behind it;
- with signing on, a frame that fails the signature policy is consumed and counted;
  ``decode_frame`` (one whole frame, e.g. a TUNNEL payload) checks signatures in a
  replay window of its own.

Nothing raises out of ``feed``: an unexpected exception from the decoder counts as
a bad frame. ``encode`` is thread-safe (it owns the sequence number).
"""

from __future__ import annotations

import logging
import re
import threading
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from mavlink_io import dialect
from mavlink_io import signing as signing_mod
from mavlink_io.signing import Signing

log = logging.getLogger(__name__)

MavMessage = Any
"""A message object of the generated dialect module (its classes are generated)."""

_V1_MARKER = 0xFE
_V2_MARKER = 0xFD
_V1_HEADER = 6
_V2_HEADER = 10
_CRC_LEN = 2
_SIGNATURE_LEN = 13
_IFLAG_SIGNED = 0x01
_START = re.compile(b"[\xfd\xfe]")
_MAX_SEQ_GAP = 8  # frames of a sender that may be lost between two we see
MAX_SENDERS = 1024  # (system, component) pairs whose last sequence number is kept


@dataclass
class CodecCounters:
    """What the decoder saw (plain ints: read them from any thread)."""

    bytes_in: int = 0
    messages: int = 0  # valid messages returned, including UNKNOWN_*
    unknown_messages: int = 0
    garbage_bytes: int = 0  # bytes skipped while looking for a frame
    bad_crc: int = 0
    bad_frames: int = 0  # bad flags/length or a decoder failure
    signature_rejected: int = 0  # failed the signing policy (unsigned or bad signature)
    messages_out: int = 0
    bytes_out: int = 0


class Codec:
    """A MAVLink encoder/decoder for one link (one sender identity, one parse state)."""

    def __init__(
        self,
        src_system: int,
        src_component: int,
        signing: Signing | None = None,
        module: ModuleType | None = None,
    ) -> None:
        self.module = module if module is not None else dialect.load()
        self.mav = self.module.MAVLink(None, src_system, src_component)
        # Frames decoded one by one (TUNNEL payloads) have their own signing replay
        # window: a robot signs the inner frame before the TUNNEL around it, so the
        # envelope arrives with the later timestamp of the same stream.
        self._frame_mav = self.module.MAVLink(None, src_system, src_component)
        self.counters = CodecCounters()
        self.signing = signing
        if signing is not None:
            signing_mod.enable(self.mav, signing)
            signing_mod.enable(self._frame_mav, signing)
        self._buf = bytearray()
        self._encode_lock = threading.Lock()
        self._decode_lock = threading.Lock()
        self._mavlink_map: dict[int, Any] = self.module.mavlink_map
        self._last_seq: dict[tuple[int, int], int] = {}  # (sysid, compid) -> last seq seen

    @property
    def src_system(self) -> int:
        return int(self.mav.srcSystem)

    @src_system.setter
    def src_system(self, value: int) -> None:
        if not 1 <= value <= 255:
            raise ValueError(f"src_system must be in 1..255, got {value}")
        with self._encode_lock:
            self.mav.srcSystem = value

    @property
    def tracked_senders(self) -> int:
        """How many senders' last sequence numbers are kept (at most MAX_SENDERS)."""
        return len(self._last_seq)

    @property
    def src_component(self) -> int:
        return int(self.mav.srcComponent)

    def encode(self, msg: MavMessage) -> bytes:
        """The wire bytes of ``msg`` (MAVLink 2, signed when signing is on)."""
        with self._encode_lock:
            data = bytes(msg.pack(self.mav))
            self.mav.seq = (self.mav.seq + 1) % 256
        self.counters.messages_out += 1
        self.counters.bytes_out += len(data)
        return data

    def feed(self, data: bytes) -> list[MavMessage]:
        """Messages completed by ``data`` (possibly none). Never raises."""
        with self._decode_lock:
            self.counters.bytes_in += len(data)
            self._buf += data
            out: list[MavMessage] = []
            consumed = self._parse(out)
            if consumed:
                del self._buf[:consumed]
            return out

    def reset(self) -> int:
        """Drop an incomplete frame held from earlier input; the bytes dropped.

        For datagram links: every UDP datagram carries whole frames, so a tail left
        after one is garbage (a truncated packet), and kept it would wait for bytes
        that never come and swallow the frames of the next datagram.
        """
        with self._decode_lock:
            dropped = len(self._buf)
            self._buf.clear()
            self.counters.garbage_bytes += dropped
            return dropped

    def decode_frame(self, frame: bytes) -> MavMessage | None:
        """Decode one complete frame (e.g. from a TUNNEL payload); None if it is not valid."""
        with self._decode_lock:
            msg, _length = self._decode_at(bytearray(frame), 0, len(frame), self._frame_mav)
        if msg is None or msg is _NEED_MORE or msg is _REJECTED:
            return None
        return msg

    def _parse(self, out: list[MavMessage]) -> int:
        """Parse self._buf from the start; append messages; return bytes consumed."""
        buf = self._buf
        pos = 0
        end = len(buf)
        while pos < end:
            match = _START.search(buf, pos)
            if match is None:
                self.counters.garbage_bytes += end - pos
                return end
            start = match.start()
            self.counters.garbage_bytes += start - pos
            msg, length = self._decode_at(buf, start, end)
            if msg is _NEED_MORE:
                return start
            if msg is None:  # not a frame here: resync one byte further
                self.counters.garbage_bytes += 1
                pos = start + 1
                continue
            if msg is not _REJECTED:
                out.append(msg)
                self.counters.messages += 1
            pos = start + length
        return pos

    def _decode_at(self, buf: bytearray, start: int, end: int, mav: Any = None) -> tuple[Any, int]:
        """(message | None | _NEED_MORE | _REJECTED, frame length) for a frame at ``start``."""
        available = end - start
        if available < 3:
            return _NEED_MORE, 0
        marker = buf[start]
        payload_len = buf[start + 1]
        if marker == _V2_MARKER:
            incompat = buf[start + 2]
            if incompat & ~_IFLAG_SIGNED:
                self.counters.bad_frames += 1
                return None, 0
            length = _V2_HEADER + payload_len + _CRC_LEN
            if incompat & _IFLAG_SIGNED:
                length += _SIGNATURE_LEN
            header = _V2_HEADER
        else:
            length = _V1_HEADER + payload_len + _CRC_LEN
            header = _V1_HEADER
        if available < header:
            return _NEED_MORE, 0
        if available < length:
            return _NEED_MORE, 0
        msg_id, seq, sender = _header_fields(buf, start, marker)
        if msg_id not in self._mavlink_map:
            # No CRC_EXTRA to check it with: believe it only if it continues a known sender.
            last = self._last_seq.get(sender)
            if last is None or not 1 <= (seq - last) % 256 <= _MAX_SEQ_GAP:
                return None, 0
            self.counters.unknown_messages += 1
        frame = buf[start : start + length]
        try:
            msg = (mav or self.mav).decode(frame)
        except self.module.MAVError as exc:
            reason = str(getattr(exc, "message", exc))
            if "signature" in reason:
                self.counters.signature_rejected += 1
                log.debug("rejected message id %d: %s", msg_id, reason)
                return _REJECTED, length
            if "CRC" in reason:
                self.counters.bad_crc += 1
            else:
                self.counters.bad_frames += 1
            return None, 0
        except Exception as exc:  # a decoder bug must not take the reader down
            self.counters.bad_frames += 1
            log.debug("decoder failed on message id %d: %r", msg_id, exc)
            return None, 0
        self._last_seq.pop(sender, None)  # most recently heard last
        self._last_seq[sender] = seq
        if len(self._last_seq) > MAX_SENDERS:
            del self._last_seq[next(iter(self._last_seq))]  # the longest silent sender
        return msg, length


class _Marker:
    def __init__(self, name: str) -> None:
        self.name = name

    def __repr__(self) -> str:
        return self.name


_NEED_MORE = _Marker("NEED_MORE")
_REJECTED = _Marker("REJECTED")


def _header_fields(buf: bytearray, start: int, marker: int) -> tuple[int, int, tuple[int, int]]:
    """(message id, sequence number, (system id, component id)) of the frame at start."""
    if marker == _V2_MARKER:
        msg_id = buf[start + 7] | (buf[start + 8] << 8) | (buf[start + 9] << 16)
        return msg_id, buf[start + 4], (buf[start + 5], buf[start + 6])
    return buf[start + 5], buf[start + 2], (buf[start + 3], buf[start + 4])
