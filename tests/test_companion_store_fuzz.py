"""Fuzz the companion's state file (SQLite): any value of any SQLite type in any cell of
its outbox and pictures, as a damaged or hand-edited file holds, leaves the frames and
pictures still usable readable at start, the others skipped and said, never an
exception. (The stored tracker, reports and IDs are fuzzed at their own entry:
test_fusion_snapshot_fuzz.py, test_companion_state.py.)"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import shutil
import sqlite3
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.store import Store, StoredPicture

FRAMES = [(12920, seq, bytes([0xFD, 9, 0, 0, seq % 256]) + b"payload") for seq in (5, 6, 9)]
JPEG = b"\xff\xd8\xff\xe0" + bytes(60) + b"\xff\xd9"


def _template() -> Path:
    path = Path(tempfile.mkdtemp(prefix="store-fuzz-")) / "state.sqlite"
    store = Store(path)
    for msgid, seq, frame in FRAMES:
        store.put(msgid, seq, frame)
    store.put_picture(StoredPicture(1, 3, 0.8, 1.7e9, JPEG))
    store.put_picture(StoredPicture(2, 4, 0.6, 1.7e9 + 5, JPEG, delivered=True))
    store.picture_delivered(2, 4)
    store.close()
    return path


TEMPLATE = _template()


def _cells() -> list[tuple[str, str, int]]:
    db = sqlite3.connect(TEMPLATE)
    out = []
    for table in ("outbox", "pictures"):
        columns = [row[1] for row in db.execute(f"PRAGMA table_info({table})")]
        for (rowid,) in db.execute(f"SELECT rowid FROM {table}"):
            out += [(table, c, rowid) for c in columns]
    db.close()
    return out


CELLS = _cells()
VALUES = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(),
    st.sampled_from([0, -1, 2**40, 3.5, math.inf, 1e308, "", "x", "12", b"", bytes(400)]),
    st.text(max_size=8),
    st.binary(max_size=8),
)


@settings(
    max_examples=int(os.environ.get("FUZZ_N", "150")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(edits=st.lists(st.tuples(st.sampled_from(CELLS), VALUES), min_size=1, max_size=3))
def test_any_value_in_any_cell_is_read_or_skipped(
    edits: list[tuple[tuple[str, str, int], Any]],
) -> None:
    work = Path(tempfile.mkdtemp(prefix="store-fuzz-"))
    try:
        path = work / "state.sqlite"
        shutil.copy(TEMPLATE, path)
        db = sqlite3.connect(path, isolation_level=None)
        touched = set()
        for (table, column, rowid), value in edits:
            # A constraint the file keeps (NOT NULL, a key's type) refuses some values.
            with contextlib.suppress(sqlite3.IntegrityError):
                db.execute(f"UPDATE {table} SET {column}=? WHERE rowid=?", (value, rowid))
                touched.add((table, rowid))
        db.close()
        store = Store(path)
        try:
            pending = store.pending()
            pictures = store.pictures()
        finally:
            store.close()
        for msgid, seq, frame in pending:
            assert 0 <= msgid < 1 << 24 and 0 <= seq < 1 << 32 and 1 <= len(frame) <= 280
        for p in pictures:
            assert p.jpeg and math.isfinite(p.score) and math.isfinite(p.taken_unix_s)
        # Rows no edit reached are all still there.
        assert len(pending) >= sum(1 for r in (1, 2, 3) if ("outbox", r) not in touched)
        assert len(pictures) >= sum(1 for r in (1, 2) if ("pictures", r) not in touched)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def test_a_text_frame_is_skipped_and_said(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "state.sqlite"
    shutil.copy(TEMPLATE, path)
    db = sqlite3.connect(path, isolation_level=None)
    db.execute("UPDATE outbox SET frame='not a frame' WHERE seq=6")
    db.execute("UPDATE pictures SET score='x' WHERE victim_id=1")
    db.close()
    store = Store(path)
    with caplog.at_level(logging.WARNING):
        assert [seq for _, seq, _ in store.pending()] == [5, 9]
        assert [p.victim_id for p in store.pictures()] == [2]
    store.close()
    said = [r.getMessage() for r in caplog.records]
    assert any("1 row(s) of outbox unusable" in m for m in said), said
    assert any("1 row(s) of pictures unusable" in m for m in said), said
