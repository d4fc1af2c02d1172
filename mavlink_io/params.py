"""The MAVLink parameter protocol for one component (QGC's parameter editor).

Answers, for the component it serves (target_component ours, or 0 = all):

- PARAM_REQUEST_LIST: every parameter as PARAM_VALUE (param_index 0..n-1,
  param_count n);
- PARAM_REQUEST_READ: one parameter, by name (param_index -1) or by index; an
  unknown name or index gets no answer (another component may own it);
- PARAM_SET: the value is handed to the table, which validates, stores and applies
  it; the answer is PARAM_VALUE with the value now in force, which is the old value
  when the new one was refused (the protocol's way of saying "not accepted"; the
  table's reason goes to the caller, who tells people).

Every value is MAV_PARAM_TYPE_REAL32 (a float on the wire, as ArduPilot sends
them; no byte-wise integer encoding to get wrong). Names are at most 16 ASCII
characters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Protocol

from mavlink_io import dialect
from mavlink_io.codec import MavMessage

NAME_BYTES = 16
MAV_PARAM_TYPE_REAL32 = 9
PARAM_MESSAGE_TYPES = frozenset({"PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"})


class ParamTable(Protocol):
    def names(self) -> Sequence[str]: ...

    def get(self, name: str) -> float: ...

    def set(self, name: str, value: float) -> str | None:
        """Store and apply ``value``; None when done, else why it was refused."""
        ...


@dataclass(frozen=True)
class Handled:
    replies: list[MavMessage]
    refused: str | None = None  # PARAM_SET refused: the reason, for people


def param_name(raw: bytes | str) -> str:
    """A param_id as text: NUL-terminated, or all 16 bytes."""
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else raw
    return text.split("\x00", 1)[0]


class ParamServer:
    """The parameter protocol of component ``component_id`` over ``table``."""

    def __init__(self, table: ParamTable, component_id: int, module: ModuleType | None = None):
        for name in table.names():
            if not 0 < len(name) <= NAME_BYTES or not name.isascii():
                raise ValueError(f"parameter name {name!r}: 1..16 ASCII characters")
        self.table = table
        self.component_id = component_id
        self.m = module if module is not None else dialect.load()

    def handle(self, msg: MavMessage) -> Handled | None:
        """The answer to a parameter message for us; None if it is not one."""
        kind = msg.get_type()
        if kind not in PARAM_MESSAGE_TYPES or msg.target_component not in (0, self.component_id):
            return None
        names = list(self.table.names())
        if kind == "PARAM_REQUEST_LIST":
            return Handled([self._value(i, names) for i in range(len(names))])
        if kind == "PARAM_REQUEST_READ":
            index = int(msg.param_index)
            if index < 0:
                name = param_name(msg.param_id)
                index = names.index(name) if name in names else -1
            if not 0 <= index < len(names):
                return Handled([])
            return Handled([self._value(index, names)])
        name = param_name(msg.param_id)  # PARAM_SET
        if name not in names:
            return Handled([])
        refused = self.table.set(name, float(msg.param_value))
        return Handled([self._value(names.index(name), names)], refused)

    def _value(self, index: int, names: list[str]) -> MavMessage:
        name = names[index]
        return self.m.MAVLink_param_value_message(
            name.encode("ascii"),
            float(self.table.get(name)),
            MAV_PARAM_TYPE_REAL32,
            len(names),
            index,
        )
