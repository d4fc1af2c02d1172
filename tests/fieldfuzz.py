"""Random MAVLink messages of any type with valid CRCs, for the vehicle-link fuzz test.

``random_message`` builds one message of the dialect (common.xml + ours) with every
field drawn from the values that break code: NaN, infinities, huge and tiny floats,
each integer type's limits, random bytes in text fields. The frame it encodes to
passes every check a receiver makes (CRC with CRC_EXTRA, length), so the fuzz
reaches the code after decoding: conversion, validation, state. (tests/mavfuzz.py
builds the hostile report frames the HQ's fuzz test sends.)
"""

from __future__ import annotations

import random
from types import ModuleType
from typing import Any

from mavlink_io.tunnel import TUNNEL_PAYLOAD_TYPE

_INT_RANGES = {
    "int8_t": (-(2**7), 2**7 - 1),
    "uint8_t": (0, 2**8 - 1),
    "int16_t": (-(2**15), 2**15 - 1),
    "uint16_t": (0, 2**16 - 1),
    "int32_t": (-(2**31), 2**31 - 1),
    "uint32_t": (0, 2**32 - 1),
    "int64_t": (-(2**63), 2**63 - 1),
    "uint64_t": (0, 2**64 - 1),
    "uint8_t_mavlink_version": (0, 2**8 - 1),
}
_FLOATS = (float("nan"), float("inf"), float("-inf"), 0.0, -0.0, 1e38, -1e38, 1e-38, 3.4e38)


def _number(rng: random.Random, field_type: str) -> Any:
    if field_type in ("float", "double"):
        if rng.random() < 0.4:
            return rng.choice(_FLOATS)
        return rng.uniform(-1e3, 1e3) * 10 ** rng.randint(-3, 9)
    low, high = _INT_RANGES[field_type]
    if rng.random() < 0.4:
        return rng.choice([low, high, 0, min(high, 1), max(low, -1)])
    return rng.randint(low, high)


def _value(rng: random.Random, field_type: str, length: int) -> Any:
    if field_type == "char":
        return bytes(rng.randrange(256) for _ in range(max(1, length)))
    if length:
        return [_number(rng, field_type) for _ in range(length)]
    return _number(rng, field_type)


def random_message(module: ModuleType, rng: random.Random, msg_ids: list[int]) -> Any:
    """One message of a type in ``msg_ids`` with random fields."""
    cls = module.mavlink_map[rng.choice(msg_ids)]
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
    values = {
        name: _value(rng, ftype, lengths[name])
        for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True)
    }
    if cls.msgname == "TUNNEL" and rng.random() < 0.5:
        values["payload_type"] = TUNNEL_PAYLOAD_TYPE  # reach the unwrapping code
    return cls(**values)
