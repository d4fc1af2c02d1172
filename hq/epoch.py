"""ID epochs of a registry path, and moving a damaged registry aside.

HQ victim IDs are what operators write on maps and say on the radio, so an ID must
never name two people, even when the registry file is lost. Each registry created
at a path gets the next *epoch* E of that path, and its HQ victim IDs start at
``(E - 1) * IDS_PER_EPOCH + 1``: epoch 1 counts 1, 2, 3..., epoch 2 counts from
1000001. The highest epoch given out is kept beside the registry in
``<registry>.epoch`` (written atomically), which survives the registry itself
being emptied or corrupted. Deleting both starts again at epoch 1. The same file
keeps the highest operator action_seq given out, so that a new registry at the
path numbers its actions above every earlier one (a robot drops a number it has
seen from this HQ as a duplicate).

``move_aside`` renames a damaged registry (and its -wal/-shm files) to
``<registry>.corrupt-<UTC time stamp>`` so that nothing is deleted and a person
can still try to recover it.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

from hq.errors import HqError

log = logging.getLogger(__name__)

IDS_PER_EPOCH = 1_000_000
_SIDE_FILES = ("-wal", "-shm")


class EpochError(HqError):
    """The epoch file cannot be written; the message names it."""


def epoch_file(db: Path) -> Path:
    return db.with_name(db.name + ".epoch")


def first_id(epoch: int) -> int:
    """The first HQ victim ID of an epoch."""
    return (epoch - 1) * IDS_PER_EPOCH + 1


@dataclass(frozen=True)
class Record:
    """What ``<registry>.epoch`` holds: the highest epoch and action_seq given out."""

    epoch: int = 0
    action_seq: int = 0


def read(db: Path) -> Record:
    """The record beside ``db`` (zeros when there is none).

    An unreadable record is said once and replaced by a safe guess: the epoch after
    the registries moved aside at this path, and no action_seq (the clock floor of
    hq.registry still applies).
    """
    path = epoch_file(db)
    try:
        text = path.read_text(encoding="ascii")
    except FileNotFoundError:
        return Record()
    except (OSError, UnicodeDecodeError) as exc:
        return _guess(path, db, str(exc))
    parts = text.split()
    if not 1 <= len(parts) <= 2 or not all(part.isdigit() for part in parts):
        return _guess(path, db, f"holds {text[:40]!r}, not one or two numbers")
    return Record(int(parts[0]), int(parts[1]) if len(parts) == 2 else 0)


def last_epoch(db: Path) -> int:
    """The highest epoch given out at this path (0: none)."""
    return read(db).epoch


def record(db: Path, epoch: int = 0, action_seq: int = 0) -> None:
    """Record ``epoch`` and ``action_seq`` as given out at this path (never lowers either).

    Written to a temporary file, synced and renamed: the record is whole or old.
    """
    old = read(db)
    new = Record(max(old.epoch, epoch), max(old.action_seq, action_seq))
    if new == old:
        return
    path = epoch_file(db)
    staging = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with staging.open("w", encoding="ascii") as f:
            f.write(f"{new.epoch} {new.action_seq}\n")
            f.flush()
            os.fsync(f.fileno())
        staging.replace(path)
    except OSError as exc:
        staging.unlink(missing_ok=True)
        raise EpochError(f"epoch file {path}: cannot write: {exc.strerror or exc}") from None


def _guess(path: Path, db: Path, why: str) -> Record:
    log.error("epoch file %s unusable (%s); counting the moved-aside registries", path, why)
    return Record(_moved_aside_count(db) + 1, 0)


def move_aside(db: Path) -> Path:
    """Rename a damaged registry and its -wal/-shm files; the new name of the registry."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    target = db.with_name(f"{db.name}.corrupt-{stamp}")
    n = 1
    while target.exists():
        n += 1
        target = db.with_name(f"{db.name}.corrupt-{stamp}-{n}")
    for suffix in _SIDE_FILES:
        side = db.with_name(db.name + suffix)
        if side.exists():
            side.replace(target.with_name(target.name + suffix))
    db.replace(target)
    return target


def _moved_aside_count(db: Path) -> int:
    return sum(
        1 for p in db.parent.glob(f"{db.name}.corrupt-*") if not p.name.endswith(_SIDE_FILES)
    )
