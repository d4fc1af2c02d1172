"""The SQLite state file: transactions, the outbox, corruption."""

from __future__ import annotations

import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from companion.storage.store import Store, StoreError
from mavlink_io import dialect
from mavlink_io.reliable import Outbox


def test_state_and_outbox_survive_reopening(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    store = Store(path)
    store.set("tracker", {"victims": [1, 2]})
    store.put(43100, 7, b"frame7")
    store.put(43100, 7, b"other")  # idempotent: the first copy stays
    store.put(43100, 8, b"frame8")
    assert store.ack(43100, 8)
    assert not store.ack(43100, 8)
    store.close()
    store.close()  # safe twice
    again = Store(path)
    assert again.get("tracker") == {"victims": [1, 2]}
    assert again.pending() == [(43100, 7, b"frame7")]
    assert sqlite3.connect(path).execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_a_failed_transaction_writes_nothing(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    with pytest.raises(RuntimeError), store.transaction():
        store.set("report_seq", 5)
        store.put(43100, 5, b"x")
        raise RuntimeError("crash between writes")
    assert store.get("report_seq") is None
    assert store.pending() == []


def test_outbox_resends_what_a_killed_process_left(tmp_path: Path) -> None:
    """A real process stores a report and is killed before any ack; a new outbox
    on the same file sends it again."""
    path = tmp_path / "s.sqlite"
    script = textwrap.dedent(
        f"""
        import os, signal
        from companion.storage.store import Store
        from mavlink_io import dialect
        from mavlink_io.reliable import Outbox
        m = dialect.load()
        from pathlib import Path
        store = Store(Path({str(path)!r}))
        outbox = Outbox(lambda msg: None, store=store)
        with store.transaction():
            outbox.submit(m.MAVLink_rescue_operator_action_message(1, 191, 3, 42, 1), send=False)
        os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    result = subprocess.run([sys.executable, "-c", script], timeout=60)
    assert result.returncode == -9
    sent: list[object] = []
    outbox = Outbox(sent.append, store=Store(path), initial_s=0.01, max_s=0.02)
    assert outbox.pending_count == 1
    assert outbox.poll() == 1
    (msg,) = sent
    assert msg.get_msgId() == dialect.RESCUE_OPERATOR_ACTION_ID and msg.action_seq == 42


def test_corrupt_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "s.sqlite"
    path.write_bytes(b"this is not a database" * 100)
    with pytest.raises(StoreError, match=str(path)):
        Store(path)
