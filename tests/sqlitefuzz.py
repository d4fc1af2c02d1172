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

# (table, column, row): the row is its rowid, or its primary key's values in a table
# WITHOUT ROWID.
Cell = tuple[str, str, Any]

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
            key = _row_key(db, table)
            for row in db.execute(f"SELECT {', '.join(key)} FROM {table}"):
                out += [(table, c, row[0] if key == ["rowid"] else tuple(row)) for c in columns]
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
        for (table, column, row), value in edits:
            key = _row_key(db, table)
            where = " AND ".join(f"{k}=?" for k in key)
            args = (row,) if key == ["rowid"] else tuple(row)
            with contextlib.suppress(sqlite3.IntegrityError):
                db.execute(f"UPDATE {table} SET {column}=? WHERE {where}", (value, *args))
                changed.add((table, column, row))
    finally:
        db.close()
    return changed


def _row_key(db: sqlite3.Connection, table: str) -> list[str]:
    """How a row of ``table`` is named: ["rowid"], or a table WITHOUT ROWID's primary
    key columns in key order."""
    try:
        db.execute(f"SELECT rowid FROM {table} LIMIT 1")
        return ["rowid"]
    except sqlite3.OperationalError:
        info = list(db.execute(f"PRAGMA table_info({table})"))
        return [row[1] for row in sorted(info, key=lambda r: r[5]) if row[5] > 0]
