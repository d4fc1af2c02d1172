"""rescue-hq's command line, shared by its commands: exit codes, defaults, the
argument value checks, usage errors and opening the registry file."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from fusion.types import GlobalOrigin
from hq import epoch
from hq.errors import HqError
from hq.registry import Registry
from hq.registry_file import RegistryCorrupt, RegistryError

log = logging.getLogger("hq")

EXIT_OK = 0
EXIT_RUNTIME = 1
EXIT_USAGE = 2
DEFAULT_LISTEN = "udpin:0.0.0.0:14600"
DEFAULT_DB = "rescue-hq.sqlite"
SBS_OFF = "off"
DEFAULT_WEB = "127.0.0.1:8080"


class UsageError(HqError):
    """Bad usage or configuration: exit 2."""


def parse_origin(text: str) -> GlobalOrigin:
    parts = text.split(",")
    try:
        if len(parts) != 3:
            raise ValueError("expected LAT,LON,ALT")
        return GlobalOrigin(float(parts[0]), float(parts[1]), float(parts[2]))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"origin {text!r}: {exc}") from None


def parse_sysid(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 1 <= value <= 255:
        raise argparse.ArgumentTypeError(f"system ID {value} is outside 1..255")
    return value


def parse_sbs(text: str) -> tuple[str, int] | str:
    if text == SBS_OFF:
        return SBS_OFF
    host, sep, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT (port 0..65535) or off")
    return (host, port)


def parse_duration(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0:
        raise argparse.ArgumentTypeError("duration must be positive")
    return value


def parse_web_address(text: str) -> tuple[str, int]:
    host, sep, port_text = text.rpartition(":")
    host = host.strip("[]")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT, e.g. {DEFAULT_WEB}")
    return host, port


def open_registry(path: Path, *, must_exist: bool, recover: bool = False) -> Registry:
    """The registry; with ``recover`` (run), a damaged file is moved aside, said once."""
    if must_exist and not path.exists():
        raise UsageError(f"database {path}: no such file")
    if path.is_dir():
        raise UsageError(f"database {path}: is a directory")
    try:
        return Registry(path)
    except RegistryCorrupt as exc:
        if not recover:
            raise UsageError(str(exc)) from None
        damage = exc
    except RegistryError as exc:
        raise UsageError(str(exc)) from None
    try:
        aside = epoch.move_aside(path)
        registry = Registry(path)
    except (OSError, RegistryError) as exc:
        raise UsageError(f"{damage}; and it cannot be replaced: {exc}") from None
    log.error(
        "%s; moved it to %s and started a new registry in new ID epoch %d: "
        "HQ victim IDs go on from %d, none of the old file's is reused",
        damage,
        aside.name,
        registry.epoch,
        epoch.first_id(registry.epoch),
    )
    return registry
