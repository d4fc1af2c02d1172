"""The companion's operator-facing settings as MAVLink parameters (QGC's parameter editor).

| parameter          | config key                          | meaning |
|--------------------|-------------------------------------|---------|
| RC_DET_MIN_SCORE   | [detector] min_score                | detection threshold, 0..1 |
| RC_UPD_MIN_S       | [reporting] update_min_interval_s   | quiet updates of one victim at most this often, s |
| RC_ANN_SEV         | [reporting] announce_severity       | MAV_SEVERITY of a new LIGHT/MEDIUM victim (<= 5 spoken) |
| RC_VID_ON          | [video] enabled                     | live video on (1) or off (0) |
| RC_VID_KBPS        | [video] bitrate_kbps                | live video bit rate, kbit/s |
| RC_LOOK_ON         | [looks] enabled                     | closer looks allowed (1) or not (0); set to 0 by the companion when the operator takes over during a look |

The config file is the source of the defaults. A value set from QGC is validated
exactly as the config file's value is (the config dataclass checks it), applied at
once, and saved in the state database with the config value it overrode; it holds
across restarts until the config file's value changes (an edited config file
wins: the override is dropped, and the log says so). A saved override that no
longer validates is dropped with a warning; nothing else is lost.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from companion.config import Config

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Setting:
    name: str  # the MAVLink parameter name (<= 16 characters)
    section: str  # the config section (a field of Config)
    key: str  # the key in that section


SETTINGS = (
    Setting("RC_DET_MIN_SCORE", "detector", "min_score"),
    Setting("RC_UPD_MIN_S", "reporting", "update_min_interval_s"),
    Setting("RC_ANN_SEV", "reporting", "announce_severity"),
    Setting("RC_VID_ON", "video", "enabled"),
    Setting("RC_VID_KBPS", "video", "bitrate_kbps"),
    Setting("RC_LOOK_ON", "looks", "enabled"),
)
_BY_NAME = {s.name: s for s in SETTINGS}


def _value(config: Config, s: Setting) -> Any:
    return getattr(getattr(config, s.section), s.key)


def _with(config: Config, s: Setting, value: float) -> Config:
    """``config`` with one setting changed; ValueError saying why not."""
    if not math.isfinite(value):
        raise ValueError(f"{value} is not a finite number")
    current = _value(config, s)
    typed: Any = value
    if isinstance(current, bool):
        if value not in (0.0, 1.0):
            raise ValueError(f"{value} is not 0 (off) or 1 (on)")
        typed = value == 1.0
    elif isinstance(current, int):
        if not value.is_integer():
            raise ValueError(f"{value} is not a whole number")
        typed = int(value)
    section = dataclasses.replace(getattr(config, s.section), **{s.key: typed})
    return dataclasses.replace(config, **{s.section: section})


class Settings:
    """The parameter table (mavlink_io.params.ParamTable) over the config.

    ``apply(config)`` is called with the new config after every accepted change;
    ``save(snapshot)`` persists ``snapshot()``.
    """

    def __init__(
        self,
        config: Config,
        saved: Any,
        apply: Callable[[Config], None],
        save: Callable[[dict[str, Any]], None],
    ) -> None:
        self.file_config = config
        self._apply = apply
        self._save = save
        self._overrides: dict[str, tuple[float, Any]] = {}  # name: (value, file value then)
        self.config = config
        for name, value, file_value in _saved_entries(saved):
            s = _BY_NAME.get(name)
            if s is None:
                log.warning("saved parameter %s is unknown; dropped", name)
                continue
            if file_value != _value(config, s):
                log.info(
                    "parameter %s: the config file now says %r (was %r when %r was set); "
                    "the config file wins",
                    name,
                    _value(config, s),
                    file_value,
                    value,
                )
                continue
            try:
                self.config = _with(self.config, s, value)
            except ValueError as exc:
                log.warning("saved parameter %s = %r dropped: %s", name, value, exc)
                continue
            self._overrides[name] = (value, file_value)
        if self._overrides:
            log.info(
                "parameters set from the ground: %s",
                ", ".join(f"{n} = {v}" for n, (v, _) in sorted(self._overrides.items())),
            )

    def names(self) -> Sequence[str]:
        return [s.name for s in SETTINGS]

    def get(self, name: str) -> float:
        return float(_value(self.config, _BY_NAME[name]))

    def set(self, name: str, value: float) -> str | None:
        s = _BY_NAME[name]
        try:
            config = _with(self.config, s, value)
        except ValueError as exc:
            reason = f"{name} = {value:g} refused: {exc}"
            log.warning("%s", reason)
            return reason
        self._overrides[name] = (float(_value(config, s)), _value(self.file_config, s))
        self._save(self.snapshot())
        self.config = config
        self._apply(config)
        log.info("parameter %s set to %g", name, value)
        return None

    def snapshot(self) -> dict[str, Any]:
        return {n: [v, file_value] for n, (v, file_value) in self._overrides.items()}


def _saved_entries(saved: Any) -> list[tuple[str, float, Any]]:
    if saved is None:
        return []
    if not isinstance(saved, dict):
        log.warning("saved parameters are not a JSON object; dropped")
        return []
    out = []
    for name, entry in saved.items():
        if (
            isinstance(entry, list)
            and len(entry) == 2
            and isinstance(entry[0], int | float)
            and not isinstance(entry[0], bool)
        ):
            out.append((str(name), float(entry[0]), entry[1]))
        else:
            log.warning("saved parameter %s = %r is malformed; dropped", name, entry)
    return out
