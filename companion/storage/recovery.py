"""The companion's saved state at start-up: use it, or set a bad file aside.

``load_state`` opens ``companion.sqlite`` in the state directory and restores the
tracker, what was reported and the report sequence number from it, all validated.
A file that cannot be used (0 bytes, not SQLite, a malformed snapshot, bad JSON) is
not a reason to stop: the service would only fail the same way at every restart.
It is moved aside as ``companion.sqlite.corrupt-<UTC time>`` (with its -wal and
-shm files), said once in the log, and the service starts a new, empty state in a
new *ID epoch*.

ID epochs: victim IDs and report sequence numbers of epoch ``e`` start at
``e * EPOCH_SPAN + 1``, so a fresh start after a lost state never reuses an ID or a
sequence number the HQ already knows from this robot (the HQ drops a report whose
sequence number it has seen, and keys victims by robot and ID). The epoch lives in
its own small file, ``id_epoch``, beside the database, written before the new
database: a state file that is lost or corrupt does not take the epoch with it.
Epoch 0 is the first run (IDs 1, 2, 3 ...). If the whole state directory is
wiped, IDs start again at epoch 0: that is a new robot to the HQ's eyes only if its
own records are wiped too.

``StoreError`` is left for what moving aside cannot fix or need not: a state
directory that cannot be created or written, a database locked by another process,
a newer schema version (exit status 3; the file is left as it is).
"""

from __future__ import annotations

import datetime as dt
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.reporting.policy import ReportPolicy
from companion.storage.store import Store, StoreCorrupt, StoreError
from fusion.errors import FusionError
from fusion.params import TrackerParams
from fusion.tracker import VictimTracker

log = logging.getLogger(__name__)

STATE_FILE = "companion.sqlite"
EPOCH_FILE = "id_epoch"
EPOCH_SPAN = 1 << 24  # IDs and sequence numbers per epoch; 256 epochs fit a uint32
MAX_EPOCH = (1 << 32) // EPOCH_SPAN - 1


@dataclass
class LoadedState:
    store: Store
    tracker: VictimTracker
    report_seq: int  # the last sequence number used
    epoch: int
    moved_aside: Path | None = None  # where a bad state file went
    problem: str | None = None  # what was wrong with it


def first_id(epoch: int) -> int:
    """The first victim ID (and report sequence number) of an epoch."""
    return epoch * EPOCH_SPAN + 1


def load_state(state_dir: Path, params: TrackerParams, policy: ReportPolicy) -> LoadedState:
    """The saved state, or a new one in a new epoch after moving a bad file aside."""
    try:
        state_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(
            f"{state_dir}: cannot create the state directory: {exc.strerror}"
        ) from None
    path = state_dir / STATE_FILE
    epoch_path = state_dir / EPOCH_FILE
    problem: str | None = None
    if path.exists():
        if path.stat().st_size == 0:
            problem = "is empty (0 bytes)"
        else:
            try:
                return _restore(path, params, policy, _read_epoch(epoch_path) or 0)
            except (StoreCorrupt, FusionError, ValueError) as exc:
                problem = f"cannot be used: {exc}"
    moved = _move_aside(path) if problem is not None else None
    known = _read_epoch(epoch_path)
    if problem is None and known is None:
        epoch = 0  # the first run
    else:
        epoch = min(MAX_EPOCH, (known if known is not None else 0) + 1)
    _write_epoch(epoch_path, epoch)
    store = Store(path)
    with store.transaction():
        store.set("id_epoch", epoch)
        store.set("report_seq", first_id(epoch) - 1)
    if problem is not None:
        log.error(
            "state file %s %s; moved aside to %s. Starting with no saved victims in ID "
            "epoch %d: new victim IDs start at %d, so none is reused",
            path,
            problem,
            moved,
            epoch,
            first_id(epoch),
        )
        if epoch == MAX_EPOCH:
            log.error("the last ID epoch (%d) is in use: IDs may repeat after this", epoch)
    return LoadedState(
        store,
        VictimTracker(params, first_id=first_id(epoch)),
        first_id(epoch) - 1,
        epoch,
        moved,
        problem,
    )


def _restore(path: Path, params: TrackerParams, policy: ReportPolicy, epoch: int) -> LoadedState:
    store = Store(path)
    try:
        snapshot = store.get("tracker")
        tracker = (
            VictimTracker.restore(params, snapshot)
            if snapshot is not None
            else VictimTracker(params, first_id=first_id(epoch))
        )
        reported = store.get("reported")
        if reported is not None:
            policy.restore(reported)
        seq: Any = store.get("report_seq")
        if seq is None:
            seq = first_id(epoch) - 1
        if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq < 1 << 32:
            raise ValueError(f"stored report_seq = {seq!r} is not a sequence number")
        stored_epoch = store.get("id_epoch")
        if isinstance(stored_epoch, int) and 0 <= stored_epoch <= MAX_EPOCH:
            epoch = stored_epoch
            epoch_path = path.with_name(EPOCH_FILE)
            if (_read_epoch(epoch_path) or 0) < epoch:  # the epoch file was lost
                _write_epoch(epoch_path, epoch)
        if snapshot is not None:
            log.info(
                "restored %d victims from %s (next report %d)",
                len(tracker.victims()),
                path,
                seq + 1,
            )
    except BaseException:
        store.close()
        raise
    return LoadedState(store, tracker, seq, epoch)


def _move_aside(path: Path) -> Path:
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ")
    target = path.with_name(f"{path.name}.corrupt-{stamp}")
    n = 1
    while target.exists():
        n += 1
        target = path.with_name(f"{path.name}.corrupt-{stamp}-{n}")
    try:
        for suffix in ("-wal", "-shm"):  # else a new file would replay the old journal
            side = path.with_name(path.name + suffix)
            if side.exists():
                side.rename(target.with_name(target.name + suffix))
        path.rename(target)
    except OSError as exc:
        raise StoreError(f"{path}: unusable, and cannot be moved aside: {exc.strerror}") from None
    return target


def _read_epoch(path: Path) -> int | None:
    try:
        text = path.read_text(encoding="ascii").strip()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        log.warning("%s unreadable (%s); the ID epoch is taken as unknown", path, exc)
        return None
    if not text.isdigit() or int(text) > MAX_EPOCH:
        log.warning("%s holds %r, not an ID epoch; taken as unknown", path, text[:20])
        return None
    return int(text)


def _write_epoch(path: Path, epoch: int) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("w", encoding="ascii") as f:
            f.write(f"{epoch}\n")
            f.flush()
            os.fsync(f.fileno())
        tmp.replace(path)
    except OSError as exc:
        raise StoreError(f"{path}: cannot write the ID epoch: {exc.strerror}") from None
