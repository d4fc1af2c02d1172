"""Operator notes on HQ victims, kept in the registry's SQLite file (table operator_notes).

A note is the operator's free text ("two people, voices heard", "team B on it").
RESCUE_OPERATOR_ACTION has no text field, so notes stay at the HQ: every open
console shows them, they survive a restart, and they are not sent to the robots.
A note belongs to the person: when a robot merges its victim into another and the
HQ victim it was on is left with no one, the registry moves its notes to the HQ
victim that person is now part of (hq.registry). One ``Notes`` per thread (sqlite3
connections are not shared).
"""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path

from hq.errors import HqError
from hq.registry_file import NOTES_SCHEMA
from hq.web.state import Note

MAX_NOTE_CHARS = 500


class BadNote(HqError, ValueError):
    """An empty or too long note; the message says which."""


def clean(text: str) -> str:
    """The note as stored: stripped, one line per line, at most MAX_NOTE_CHARS."""
    text = "\n".join(line.rstrip() for line in text.strip().splitlines())
    if not text:
        raise BadNote("a note needs some text")
    if len(text) > MAX_NOTE_CHARS:
        raise BadNote(f"a note is at most {MAX_NOTE_CHARS} characters, this one {len(text)}")
    return text


class Notes:
    def __init__(self, path: Path, *, busy_timeout_s: float = 1.5) -> None:
        self._db = sqlite3.connect(str(path), isolation_level=None, timeout=busy_timeout_s)
        self._db.execute(NOTES_SCHEMA)

    def close(self) -> None:
        self._db.close()

    def add(self, hq_id: int, text: str) -> Note:
        """Store a note (BadNote for empty or too long text; sqlite3.Error when locked)."""
        body = clean(text)
        now = time.time()
        cur = self._db.execute(
            "INSERT INTO operator_notes (hq_id, text, created_unix_s) VALUES (?, ?, ?)",
            (hq_id, body, now),
        )
        assert cur.lastrowid is not None
        return Note(int(cur.lastrowid), hq_id, body, now)

    def all(self) -> list[Note]:
        rows = self._db.execute(
            "SELECT note_id, hq_id, text, created_unix_s FROM operator_notes ORDER BY note_id"
        ).fetchall()
        return [Note(int(i), int(h), str(t), float(c)) for i, h, t, c in rows]
