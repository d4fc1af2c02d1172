"""Damaged copies of a SQLite file for the fuzz tests of stored state: any value of
any SQLite type in chosen cells, as a file damaged or edited by hand holds."""

from __future__ import annotations

import atexit
import contextlib
import math
import shutil
import sqlite3
import tempfile
from pathlib import Path
from typing import Any

from hypothesis import strategies as st

Cell = tuple[str, str, int]  # (table, column, rowid)

# Every SQLite type (INTEGER, REAL, TEXT, BLOB), with the values that break readers.
cell_values: st.SearchStrategy[Any] = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.floats(),
    st.sampled_from([0, -1, 2**40, 3.5, math.nan, math.inf, 1e308, "", "x", "12", b"\xff"]),
    st.text(max_size=12),
    st.binary(max_size=12),
)


def template_dir(prefix: str) -> Path:
    """A folder for a module's template file, removed when the test process ends."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def cells(path: Path, tables: tuple[str, ...] | None = None) -> list[Cell]:
    """Every cell of the file's tables (or of ``tables``)."""
    db = sqlite3.connect(path)
    try:
        names = tables or tuple(
            name
            for (name,) in db.execute("SELECT name FROM sqlite_master WHERE type='table'")
            if not name.startswith("sqlite_")
        )
        out = []
        for table in names:
            columns = [row[1] for row in db.execute(f"PRAGMA table_info({table})")]
            for (rowid,) in db.execute(f"SELECT rowid FROM {table}"):
                out += [(table, c, rowid) for c in columns]
        return out
    finally:
        db.close()


def damaged_copy(template: Path, path: Path, edits: list[tuple[Cell, Any]]) -> set[Cell]:
    """Copy ``template`` to ``path`` with the edits made; the cells really changed (a
    constraint the file keeps, NOT NULL or UNIQUE, refuses some: no file holds them)."""
    shutil.copy(template, path)
    db = sqlite3.connect(path, isolation_level=None)
    changed = set()
    try:
        for (table, column, rowid), value in edits:
            with contextlib.suppress(sqlite3.IntegrityError):
                db.execute(f"UPDATE {table} SET {column}=? WHERE rowid=?", (value, rowid))
                changed.add((table, column, rowid))
    finally:
        db.close()
    return changed
