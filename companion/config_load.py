"""Reading the companion's TOML config into its dataclasses (config.py), once.

The loader walks the dataclasses' type hints, so a key that is not a field is an
error (a typo must not be silently ignored) and a value of the wrong type names the
section, the key, the value and what is allowed. The range checks of each
dataclass's ``__post_init__`` surface the same way, as one ``ConfigError`` line.
Relative paths are taken relative to the config file's directory.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal

from companion.config import Config
from companion.errors import CompanionError
from mavlink_io.errors import LinkSpecError


class ConfigError(CompanionError):
    """The configuration cannot be used. The message is one line for a person."""


_TYPE_WORDS = {
    int: "an integer",
    float: "a number",
    bool: "true or false",
    str: "a string",
    Path: "a path string",
}


def _describe(tp: Any) -> str:
    if tp in _TYPE_WORDS:
        return _TYPE_WORDS[tp]
    origin = typing.get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin is tuple:
        return f"a list of {_describe(typing.get_args(tp)[0])}s"
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_describe(a) for a in typing.get_args(tp) if a is not type(None))
    if dataclasses.is_dataclass(tp):
        return "a table"
    return str(tp)


class _Bad(Exception):
    """A value does not fit its type (internal to the loader)."""


def _convert(tp: Any, value: Any, where: str, base_dir: Path) -> Any:
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise _Bad
        return _build(tp, value, where, base_dir)  # type: ignore[arg-type]
    if origin in (types.UnionType, typing.Union):
        for arg in typing.get_args(tp):
            if arg is type(None):
                continue
            try:
                return _convert(arg, value, where, base_dir)
            except _Bad:
                continue
        raise _Bad
    if origin is Literal:
        if value in typing.get_args(tp):
            return value
        raise _Bad
    if origin is tuple:
        if not isinstance(value, list):
            raise _Bad
        (item,) = typing.get_args(tp)[:1]
        return tuple(_convert(item, v, where, base_dir) for v in value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise _Bad
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise _Bad
    if tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            if not math.isfinite(value):  # TOML allows nan and inf; no setting means them
                raise ConfigError(f"{where} = {value!r}: must be a finite number")
            return float(value)
        raise _Bad
    if tp is str:
        if isinstance(value, str):
            return value
        raise _Bad
    if tp is Path:
        if isinstance(value, str) and value:
            path = Path(value).expanduser()
            return path if path.is_absolute() else (base_dir / path)
        raise _Bad
    raise TypeError(f"config loader cannot handle type {tp!r} at {where}")  # a bug, not input


def _build(cls: type[Any], data: dict[str, Any], where: str, base_dir: Path) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(
            f"[{where}] has unknown key {unknown[0]!r}; allowed keys: {', '.join(sorted(known))}"
        )
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        key = f"{where}.{name}" if where else name
        try:
            kwargs[name] = _convert(hints[name], value, key, base_dir)
        except _Bad:
            raise ConfigError(f"{key} = {value!r}: expected {_describe(hints[name])}") from None
    try:
        return cls(**kwargs)
    except (ValueError, LinkSpecError) as exc:
        raise ConfigError(f"[{where}] {exc}" if where else str(exc)) from None


def config_from_dict(data: dict[str, Any], base_dir: Path = Path(".")) -> Config:
    """Build a Config from parsed TOML; raises ConfigError naming the bad key."""
    unknown = sorted(set(data) - {f.name for f in dataclasses.fields(Config)})
    if unknown:
        allowed = ", ".join(f.name for f in dataclasses.fields(Config))
        name = unknown[0] if unknown[0].isprintable() else repr(unknown[0])  # one line
        raise ConfigError(f"unknown section [{name}]; allowed sections: {allowed}")
    hints = typing.get_type_hints(Config)
    sections: dict[str, Any] = {}
    for name, value in data.items():
        if not isinstance(value, dict):
            raise ConfigError(f"{name} = {value!r}: expected a table [{name}]")
        sections[name] = _convert(hints[name], value, name, base_dir)
    return Config(**sections)


def load_config(path: Path) -> Config:
    """Load and validate a config file, including its cameras' calibration files."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read config file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    try:
        config = config_from_dict(data, base_dir=path.resolve().parent)
        # Fail now, not at the first frame, when the calibration cannot be used.
        from companion.calibration import camera_model

        camera_model(config.camera)
        if config.thermal is not None:
            camera_model(config.thermal)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return config
