"""A corrupt or emptied registry: moved aside, said once, and no HQ victim ID reused.

Operators write HQ victim IDs on maps and radio them to rescue teams. When the
registry file is lost (0 bytes after a crash of the file system) or corrupt,
`rescue-hq run` moves it aside with a time stamp, says so in one line, and starts a
new registry in a new ID epoch, whose IDs lie above every ID of the old ones.
The read-only tools (list, export, mark) still refuse such a file with exit 2.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hqproc import ACCEPTED, REPO, HqProcess, ack_for, hq_starter

from hq.registry import Registry
from hq.simrobot import SimRobot
from hq.view import hq_victims


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


def _report_victims(hq: HqProcess, sysid: int, count: int) -> None:
    with SimRobot(sysid, hq.address) as robot:
        for v in range(1, count + 1):
            msg = robot.report_msg(robot.victim(v, 10.0 * v, 0.0))
            robot.send(msg)
            assert ack_for(robot, msg.report_seq).result == ACCEPTED


def _moved_aside(directory: Path) -> list[Path]:
    """Registries moved aside (``.corrupt-<stamp>``, ``-N`` when two share a second)."""
    found = directory.glob("hq.sqlite.corrupt-*")
    return sorted(p for p in found if not p.name.endswith(("-wal", "-shm")))


def _hq_ids(db: Path) -> list[int]:
    with Registry(db) as reg:
        return sorted(v.hq_id for v in hq_victims(reg))


@pytest.mark.parametrize(
    "damage",
    [
        pytest.param(lambda db: db.write_bytes(b""), id="emptied"),
        pytest.param(lambda db: db.write_bytes(b"shopping list\n" * 500), id="garbage"),
        pytest.param(
            lambda db: db.write_bytes(db.read_bytes()[:100] + bytes(4000)), id="truncated"
        ),
    ],
)
def test_damaged_registry_is_moved_aside_and_ids_are_not_reused(
    start_hq, tmp_path: Path, damage: Callable[[Path], None]
) -> None:
    db = tmp_path / "hq.sqlite"
    hq = start_hq(db=db)
    _report_victims(hq, 1, 3)
    assert hq.stop() == 0
    old_ids = _hq_ids(db)
    damage(db)

    hq2 = start_hq(db=db)
    _report_victims(hq2, 2, 1)
    assert hq2.stop() == 0
    said = [line for line in hq2.stderr if "moved it to" in line]
    assert len(said) == 1, hq2.stderr
    assert "Traceback" not in "".join(hq2.stderr)
    (aside,) = _moved_aside(tmp_path)
    assert aside.name in said[0] and "new ID epoch 2" in said[0]
    (new_id,) = _hq_ids(db)
    assert new_id > max(old_ids)

    # Twice in a row: the third registry's IDs lie above the second's.
    db.write_bytes(b"")
    hq3 = start_hq(db=db)
    _report_victims(hq3, 3, 1)
    assert hq3.stop() == 0
    assert _hq_ids(db)[0] > new_id
    assert len(_moved_aside(tmp_path)) == 2  # the first one is still there


def test_read_only_tools_refuse_a_damaged_registry_without_moving_it(tmp_path: Path) -> None:
    db = tmp_path / "hq.sqlite"
    db.write_bytes(b"this is not a database, it is a shopping list\n" * 100)
    result = subprocess.run(
        [sys.executable, "-m", "hq.cli", "list", "--db", str(db)],
        cwd=REPO, capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(db) in lines[0] and "Traceback" not in result.stderr
    assert db.exists() and not list(tmp_path.glob("*.corrupt-*"))


def test_two_moves_in_one_second_keep_both_files(tmp_path: Path) -> None:
    from hq import epoch

    db = tmp_path / "hq.sqlite"
    names = []
    for content in (b"first", b"second"):  # well within one second
        db.write_bytes(content)
        (tmp_path / "hq.sqlite-wal").write_bytes(content + b" wal")
        names.append(epoch.move_aside(db))
    assert names[1].name == names[0].name + "-2"
    assert [p.read_bytes() for p in names] == [b"first", b"second"]
    assert [p.name for p in _moved_aside(tmp_path)] == [n.name for n in names]
    assert (tmp_path / (names[1].name + "-wal")).read_bytes() == b"second wal"
    assert not db.exists()
