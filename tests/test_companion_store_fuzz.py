"""Fuzz the companion's state file (SQLite): any value of any SQLite type in any cell of
its outbox and pictures, as a damaged or hand-edited file holds, leaves the frames and
pictures still usable readable at start, the others skipped and said, never an
exception. (The stored tracker, reports and IDs are fuzzed at their own entry:
test_fusion_snapshot_fuzz.py, test_companion_state.py.)"""

from __future__ import annotations

import logging
import math
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.storage.store import Store, StoredPicture
from tests.jsonfuzz import fuzz_settings
from tests.sqlitefuzz import Cell, cell_values, cells, damaged_copy, template_dir

FRAMES = [(12920, seq, bytes([0xFD, 9, 0, 0, seq % 256]) + b"payload") for seq in (5, 6, 9)]
JPEG = b"\xff\xd8\xff\xe0" + bytes(60) + b"\xff\xd9"


def _template() -> Path:
    path = template_dir("store-fuzz-") / "state.sqlite"
    store = Store(path)
    for msgid, seq, frame in FRAMES:
        store.put(msgid, seq, frame)
    store.put_picture(StoredPicture(1, 3, 0.8, 1.7e9, JPEG))
    store.put_picture(StoredPicture(2, 4, 0.6, 1.7e9 + 5, JPEG, delivered=True))
    store.picture_delivered(2, 4)
    store.close()
    return path


TEMPLATE = _template()


CELLS = cells(TEMPLATE, ("outbox", "pictures"))
VALUES = cell_values | st.sampled_from([b"", bytes(400)])  # frames too short and too long


@fuzz_settings(150)
@given(edits=st.lists(st.tuples(st.sampled_from(CELLS), VALUES), min_size=1, max_size=3))
def test_any_value_in_any_cell_is_read_or_skipped(
    edits: list[tuple[Cell, Any]],
) -> None:
    with tempfile.TemporaryDirectory(prefix="store-fuzz-", ignore_cleanup_errors=True) as tmp:
        work = Path(tmp)
        path = work / "state.sqlite"
        touched = {(table, rowid) for table, _, rowid in damaged_copy(TEMPLATE, path, edits)}
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


def test_a_text_frame_is_skipped_and_said(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "state.sqlite"
    damaged_copy(
        TEMPLATE,
        path,
        [(("outbox", "frame", 2), "not a frame"), (("pictures", "score", 1), "x")],
    )
    store = Store(path)
    with caplog.at_level(logging.WARNING):
        assert [seq for _, seq, _ in store.pending()] == [5, 9]
        assert [p.victim_id for p in store.pictures()] == [2]
    store.close()
    said = [r.getMessage() for r in caplog.records]
    assert any("1 row(s) of outbox unusable" in m for m in said), said
    assert any("1 row(s) of pictures unusable" in m for m in said), said
