"""A seeded generator of valid-CRC MAVLink 2 frames with hostile field values.

Every frame carries a correct header and CRC (with the message's CRC_EXTRA), so it
passes framing and the checksum and reaches the code that reads the fields; the
payload is where the fuzzing is. Dialect messages start from a valid message (a
report a robot would send) with one to three fields overwritten by an extreme value
(NaN, infinities, 0, the type's minimum and maximum, 2^62/2^63 for times, 0/0
lat/lon with the GLOBAL_VALID flag) or random bytes, so most of them reach deep
into the HQ instead of failing the first check. Standard messages get a random
payload. Some frames go inside our TUNNEL envelope.

Used by tests/test_hq_fuzz.py: a few seconds in the default run, and
``make fuzz`` (FUZZ_MESSAGES, FUZZ_SEED) for a longer run.
"""

from __future__ import annotations

import math
import random
import re
import struct
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from mavlink_io import picture
from mavlink_io.dialect import (
    RESCUE_ACK_ID,
    RESCUE_OPERATOR_ACTION_ID,
    RESCUE_PICTURE_ACK_ID,
    RESCUE_PICTURE_CHUNK_ID,
    RESCUE_STATUS_ID,
    RESCUE_VICTIM_REPORT_ID,
)
from mavlink_io.tunnel import TUNNEL_PAYLOAD_BYTES, TUNNEL_PAYLOAD_TYPE

GPS_GLOBAL_ORIGIN_ID = 49
TUNNEL_ID = 385
_FIELD = re.compile(r"(\d*)([a-zA-Z])")
_INT_RANGES = {
    "b": (-(2**7), 2**7 - 1),
    "B": (0, 2**8 - 1),
    "h": (-(2**15), 2**15 - 1),
    "H": (0, 2**16 - 1),
    "i": (-(2**31), 2**31 - 1),
    "I": (0, 2**32 - 1),
    "q": (-(2**63), 2**63 - 1),
    "Q": (0, 2**64 - 1),
}
_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 3.4e38, -3.4e38, 1e-45, -1.0, 1e9)


@dataclass(frozen=True)
class Slot:
    """One field's place in the wire payload."""

    name: str
    code: str  # struct code
    offset: int
    count: int  # array length (1 for a scalar)


def slots(cls: Any) -> list[Slot]:
    """The fields of a generated message class in wire order, with their byte offsets."""
    out = []
    offset = 0
    names = list(cls.ordered_fieldnames)
    for (count_text, code), name in zip(
        _FIELD.findall(cls.native_format.decode()[1:]), names, strict=True
    ):
        count = int(count_text or 1)
        size = struct.calcsize("<" + code) * count
        out.append(Slot(name, code, offset, count if code not in "sc" else 1))
        offset += size
    return out


class FrameFuzzer:
    """Seeded source of hostile frames for one dialect module."""

    def __init__(self, module: ModuleType, seed: int, hq_sysid: int = 245) -> None:
        self.m = module
        self.rng = random.Random(seed)
        self.hq_sysid = hq_sysid
        self._seq = 0
        self._classes = sorted(module.mavlink_map.items())
        self._slots = {msg_id: slots(cls) for msg_id, cls in self._classes}
        # Small pictures (1 to 4 chunks) whose chunks often all arrive: the HQ then
        # joins, checks and stores them, also after a mutated chunk went in.
        self._pictures = [
            picture.split(pid, pid % 7 + 1, b"\xff\xd8" + self.rng.randbytes(n) + b"\xff\xd9")
            for pid, n in enumerate((10, 100, 200, 300), start=1)
        ]

    # -- frames -----------------------------------------------------------------

    def frame(self, msg_id: int, payload: bytes, sysid: int, compid: int) -> bytes:
        """A MAVLink 2 frame with a correct CRC around ``payload`` (trailing zeros cut)."""
        cls = self.m.mavlink_map[msg_id]
        body = payload.rstrip(b"\0") or b"\0"
        self._seq = (self._seq + 1) % 256
        header = struct.pack(
            "<BBBBBBBHB", 0xFD, len(body), 0, 0, self._seq, sysid, compid,
            msg_id & 0xFFFF, msg_id >> 16,
        )  # fmt: skip
        crc = self.m.x25crc(header[1:] + body)
        crc.accumulate(bytes([cls.crc_extra]))
        return header + body + struct.pack("<H", crc.crc)

    def payload_of(self, msg: Any) -> bytes:
        """The full (untruncated) wire payload of a message object."""
        cls = type(msg)
        values = []
        for name in cls.ordered_fieldnames:
            v = getattr(msg, name)
            values.extend(v if isinstance(v, list) else [v])
        return cls.unpacker.pack(*values)

    # -- values -----------------------------------------------------------------

    def _value(self, code: str, name: str) -> bytes:
        rng = self.rng
        if code in "fd":
            v = rng.choice((*_FLOATS, rng.uniform(-1e6, 1e6)))
            return struct.pack("<" + code, v)
        if code in _INT_RANGES:
            low, high = _INT_RANGES[code]
            special = [low, high, 0, 1]
            if code in "qQ":
                special += [2**62, 2**63 - 1] + ([2**63, 2**63 + 5] if code == "Q" else [])
            return struct.pack("<" + code, rng.choice((*special, rng.randint(low, high))))
        return bytes([rng.randrange(256)])

    def mutate(self, msg_id: int, payload: bytes, max_fields: int = 3) -> bytes:
        """``payload`` with 1..max_fields fields replaced by extreme or random values."""
        buf = bytearray(payload)
        for slot in self.rng.sample(self._slots[msg_id], self.rng.randint(1, max_fields)):
            size = struct.calcsize("<" + slot.code)
            for i in range(slot.count):
                at = slot.offset + i * size
                if self.rng.random() < 0.3:
                    buf[at : at + size] = self.rng.randbytes(size)
                else:
                    buf[at : at + size] = self._value(slot.code, slot.name)
        return bytes(buf)

    def random_payload(self, msg_id: int) -> bytes:
        return self.rng.randbytes(self.m.mavlink_map[msg_id].unpacker.size)

    # -- messages a robot would send, as starting points --------------------------

    def _report(self) -> Any:
        rng = self.rng
        t = 1_700_000_000 + rng.uniform(0, 1e8)
        geo = rng.random() < 0.5
        return self.m.MAVLink_rescue_victim_report_message(
            time_usec=int(t * 1e6), first_seen_usec=int((t - 5) * 1e6),
            last_seen_usec=int(t * 1e6), report_seq=rng.randint(1, 10**6),
            victim_id=rng.randint(1, 50), merged_into_id=rng.choice((0, 0, rng.randint(1, 50))),
            robot_sysid=rng.randint(1, 6), state=rng.randint(0, 5), urgency=rng.randint(1, 3),
            flags=(1 if geo else 0) | rng.choice((0, 2, 4, 8)), visibility=rng.uniform(0, 100),
            north=rng.uniform(-500, 500), east=rng.uniform(-500, 500), down=rng.uniform(-5, 5),
            cov_nn=rng.uniform(0.01, 25), cov_ne=0.0, cov_ee=rng.uniform(0.01, 25),
            lat=int(rng.uniform(-89, 89) * 1e7) if geo else 0,
            lon=int(rng.uniform(-179, 179) * 1e7) if geo else 0,
            alt=rng.randint(-100_000, 3_000_000) if geo else 0,
            observations=rng.randint(0, 500),
        )  # fmt: skip

    def _valid(self, msg_id: int) -> Any:
        m, rng = self.m, self.rng
        if msg_id == RESCUE_VICTIM_REPORT_ID:
            return self._report()
        if msg_id == RESCUE_STATUS_ID:
            ended = [rng.randint(0, 5) for _ in range(4)]  # the closer looks' outcomes
            looks = [sum(ended) + rng.randint(0, 2), *ended] if rng.random() < 0.7 else []
            return m.MAVLink_rescue_status_message(
                rng.randint(0, 10**6), rng.uniform(0, 30), rng.uniform(0, 100),
                rng.uniform(0, 500), rng.randint(0, 255), rng.randint(0, 50), rng.randint(0, 50),
                rng.randint(0, 50), *looks,
            )  # fmt: skip
        if msg_id == RESCUE_ACK_ID:
            return m.MAVLink_rescue_ack_message(
                self.hq_sysid,
                190,
                RESCUE_OPERATOR_ACTION_ID,
                rng.randint(0, 100),
                rng.randint(0, 3),
            )
        if msg_id == RESCUE_PICTURE_CHUNK_ID:
            chunk = rng.choice(rng.choice(self._pictures))
            return (chunk.asking() if rng.random() < 0.3 else chunk).to_msg(m)
        if msg_id == RESCUE_PICTURE_ACK_ID:  # HQ-to-robot: the HQ must ignore it
            return picture.ack_msg(m, 1, 191, rng.randint(0, 9), rng.randint(0, 3), {0, 1})
        if msg_id == RESCUE_OPERATOR_ACTION_ID:
            return m.MAVLink_rescue_operator_action_message(
                rng.randint(0, 255), 191, rng.randint(0, 50), rng.randint(0, 100), rng.randint(0, 8)
            )
        assert msg_id == GPS_GLOBAL_ORIGIN_ID
        return m.MAVLink_gps_global_origin_message(
            int(rng.uniform(-90, 90) * 1e7), int(rng.uniform(-180, 180) * 1e7),
            rng.randint(-(2**31), 2**31 - 1), 0,
        )  # fmt: skip

    def _dialect_payload(self) -> tuple[int, bytes]:
        msg_id = self.rng.choice(
            (RESCUE_VICTIM_REPORT_ID,) * 5
            + (RESCUE_PICTURE_CHUNK_ID,) * 3
            + (RESCUE_STATUS_ID, RESCUE_ACK_ID, RESCUE_OPERATOR_ACTION_ID, GPS_GLOBAL_ORIGIN_ID)
            + (RESCUE_PICTURE_ACK_ID,)
        )
        payload = self.payload_of(self._valid(msg_id))
        if self.rng.random() < 0.85:
            payload = self.mutate(msg_id, payload)
        return msg_id, payload

    def _sender(self) -> tuple[int, int]:
        if self.rng.random() < 0.9:
            return self.rng.randint(1, 6), 191
        return self.rng.randint(0, 255), self.rng.randint(0, 255)

    def next_frame(self) -> bytes:
        """One hostile frame: a mutated dialect message, a TUNNEL, or any common message."""
        rng = self.rng
        sysid, compid = self._sender()
        roll = rng.random()
        if roll < 0.6:
            msg_id, payload = self._dialect_payload()
            return self.frame(msg_id, payload, sysid, compid)
        if roll < 0.8:
            msg_id, payload = self._dialect_payload()
            inner = self.frame(msg_id, payload, sysid, compid)
            if rng.random() < 0.2:
                inner = rng.randbytes(rng.randint(0, TUNNEL_PAYLOAD_BYTES))
            length = len(inner) if rng.random() < 0.9 else rng.randint(0, 255)
            tunnel = self.m.MAVLink_tunnel_message(
                rng.choice((0, self.hq_sysid, rng.randint(0, 255))), 0,
                TUNNEL_PAYLOAD_TYPE if rng.random() < 0.9 else rng.randint(0, 65535),
                min(length, 255), list(inner.ljust(TUNNEL_PAYLOAD_BYTES, b"\0")[:128]),
            )  # fmt: skip
            return self.frame(TUNNEL_ID, self.payload_of(tunnel), sysid, compid)
        msg_id = rng.choice(self._classes)[0]
        return self.frame(msg_id, self.random_payload(msg_id), sysid, compid)

    def datagram(self) -> bytes:
        """One to three frames, now and then cut short (a truncated datagram)."""
        data = b"".join(self.next_frame() for _ in range(self.rng.choice((1, 1, 1, 2, 3))))
        if self.rng.random() < 0.05:
            data = data[: self.rng.randint(1, len(data))]
        return data
