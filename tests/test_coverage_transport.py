"""The searched-area map from a robot to a real rescue-hq over UDP on 127.0.0.1:
pieces lost both ways are resent until every one is acknowledged, the HQ stores
exactly the robot's levels, bad bytes are refused in one line and lose nothing."""

from __future__ import annotations

import random
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hqproc import REJECTED, HqProcess, hq_starter

from companion.config import CoverageConfig
from companion.coverage import SharedGrid
from companion.reporting.coverage_sender import CoverageSender, piece_wire_bytes
from fusion.coverage import CoverageDelta
from hq.registry import Registry
from hq.simrobot import SimRobot
from mavlink_io import coverage
from mavlink_io.dialect import RESCUE_COVERAGE_ID


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[object]:
    yield from hq_starter(tmp_path)


def _grid(seed: int, looks: int = 12) -> SharedGrid:
    """A grid with overlapping looks: a 6 x 4 m room seen from several places."""
    rng = np.random.default_rng(seed)
    grid = SharedGrid()
    for _ in range(looks):
        n0, e0 = rng.integers(0, 16, 2)
        nn, ee = np.meshgrid(np.arange(n0, n0 + 10), np.arange(e0, e0 + 8), indexing="ij")
        cells = np.column_stack([nn.ravel(), ee.ravel()])
        grid.add_look(cells, rng.uniform(0.2, 0.7, len(cells)))
    return grid


def _stored(db: Path, robot: int) -> dict[tuple[int, int], int]:
    with Registry(db) as reg:
        return {(n, e): q for n, e, q in reg.coverage().get(robot, [])}


def _held(grid: SharedGrid) -> dict[tuple[int, int], int]:
    d = grid.delta_since(0)
    return {(int(n), int(e)): int(q) for (n, e), q in zip(d.cells, d.p_q, strict=True)}


def _run(
    sender: CoverageSender, robot: SimRobot, until_version: int, timeout_s: float = 60.0
) -> None:
    """The reporter's part: poll the sender, hand it the HQ's acknowledgements."""
    deadline = time.monotonic() + timeout_s
    while sender.acked_version < until_version:
        assert time.monotonic() < deadline, f"acked {sender.acked_version} of {until_version}"
        sender.poll()
        for rx in robot.receive(min(0.05, sender.seconds_until_due() + 0.001)):
            msg = rx.msg
            if msg.get_type() == "RESCUE_ACK" and msg.acked_msgid == RESCUE_COVERAGE_ID:
                sender.on_ack(int(msg.seq), int(msg.result))


def test_pieces_lost_both_ways_are_resent_until_the_hq_holds_the_map(
    start_hq, tmp_path: Path
) -> None:
    hq: HqProcess = start_hq()
    grid = _grid(1)
    rnd = random.Random(4)
    with SimRobot(4, hq.address, tunnel=True) as robot:
        m = robot.codec.module
        lost: list[int] = []

        def send(seq: int, piece: CoverageDelta) -> None:
            if rnd.random() < 0.3:  # a third of the pieces never arrive
                lost.append(seq)
                return
            robot.send(coverage.piece_msg(m, seq, piece))

        cfg = CoverageConfig(rate_bytes_s=20_000.0, period_s=1.0)
        sender = CoverageSender(grid, cfg, send, first_seq=1000)
        sender_acks_dropped = 0
        real_on_ack = sender.on_ack

        def lossy_ack(seq: int, result: int) -> None:  # a fifth of the answers are lost
            nonlocal sender_acks_dropped
            if rnd.random() < 0.2:
                sender_acks_dropped += 1
                return
            real_on_ack(seq, result)

        sender.on_ack = lossy_ack  # type: ignore[method-assign]
        first_version = grid.version
        _run(sender, robot, first_version)
        assert lost and sender_acks_dropped and sender.counters.resends >= len(lost)
        # More looks while the map is known: only the changed cells go.
        before, resent = sender.counters.pieces, sender.counters.resends
        rng = np.random.default_rng(9)
        cells = np.column_stack([np.full(6, 40), np.arange(6)])
        grid.add_look(cells, rng.uniform(0.5, 0.6, 6))
        _run(sender, robot, grid.version)
        # one new piece (resent as often as its answer was lost or late)
        assert (sender.counters.pieces - before) - (sender.counters.resends - resent) == 1
        assert hq.stop() == 0
    assert _stored(hq.db, 4) == _held(grid)  # exactly the robot's levels


def test_bad_pieces_are_refused_in_one_line_and_lose_nothing(start_hq) -> None:
    hq: HqProcess = start_hq()
    grid = _grid(2, looks=4)
    with SimRobot(5, hq.address) as robot:
        m = robot.codec.module
        sender = CoverageSender(
            grid,
            CoverageConfig(rate_bytes_s=20_000.0),
            lambda seq, piece: robot.send(coverage.piece_msg(m, seq, piece)),
            first_seq=1,
        )
        _run(sender, robot, grid.version)
        good = coverage.pieces(grid.delta_since(0))[0].encode()
        # Not a delta at all: refused, named, answered REJECTED.
        robot.send(m.MAVLink_rescue_coverage_message(77, 40, list(b"\x01" * 40) + [0] * 58))
        ack = robot.wait_for("RESCUE_ACK", 3.0, acked_msgid=RESCUE_COVERAGE_ID, seq=77).msg
        assert ack.result == REJECTED
        line = hq.wait_line("refused RESCUE_COVERAGE 77 from system 5", 5.0, stderr=True)
        assert "not b'RCD1'" in line and "\n" not in line
        # Random damage to a good piece: every one answered, the HQ keeps running.
        rnd = random.Random(7)
        for seq in range(100, 300):
            data = bytearray(good)
            for _ in range(rnd.randint(1, 6)):
                data[rnd.randrange(len(data))] = rnd.randrange(256)
            length = rnd.choice([len(data), rnd.randint(0, 98)])
            payload = (list(data) + [0] * 98)[:98]
            robot.send(m.MAVLink_rescue_coverage_message(seq, length, payload))
            robot.wait_for("RESCUE_ACK", 3.0, acked_msgid=RESCUE_COVERAGE_ID, seq=seq)
        assert hq.stop() == 0
    stored = _stored(hq.db, 5)
    for cell, q in _held(grid).items():  # nothing known was lowered or lost
        assert stored[cell] >= q


def test_a_damaged_stored_cell_is_skipped_and_said(tmp_path: Path) -> None:
    db = tmp_path / "hq.sqlite"
    with Registry(db) as reg:
        reg.store_coverage(3, [(1, 2, 200), (1, 3, 100)])
        reg.store_coverage(3, [(1, 2, 50)])  # a late, lower piece lowers nothing
    raw = sqlite3.connect(db, isolation_level=None)
    raw.execute("UPDATE coverage SET p_q = 'x' WHERE east_idx = 3")
    raw.close()
    with Registry(db) as reg:
        assert reg.coverage() == {3: [(1, 2, 200)]}
        assert "coverage of robot 3" in " ".join(reg.bad_rows)


def test_the_sender_keeps_to_its_rate_and_sends_fewer_newer_values_when_slow() -> None:
    now = [0.0]
    grid = _grid(3, looks=30)
    sent: list[CoverageDelta] = []
    cfg = CoverageConfig(rate_bytes_s=300.0, period_s=10.0)
    sender = CoverageSender(grid, cfg, lambda _s, p: sent.append(p), clock=lambda: now[0])
    for _ in range(600):  # 60 s, nothing acknowledged: resends too stay in the budget
        sender.poll()
        now[0] += 0.1
    spent = sum(piece_wire_bytes(p, False) for p in sent)
    assert spent <= 300.0 * 60.0 + 2 * 132
    assert spent > 300.0 * 60.0 * 0.9  # and it uses what it has


def test_the_decoder_refuses_random_bytes_with_bad_piece_only() -> None:
    rnd = random.Random(11)

    class Msg:
        def __init__(self, length: int, data: bytes) -> None:
            self.length, self.data = length, data

    good = coverage.pieces(_grid(4, looks=1).delta_since(0))[0].encode()
    for _ in range(3000):
        data = bytearray(good if rnd.random() < 0.7 else rnd.randbytes(98))
        for _ in range(rnd.randint(0, 4)):
            data[rnd.randrange(len(data))] = rnd.randrange(256)
        try:
            piece = coverage.piece_from_msg(Msg(rnd.randint(0, 255), bytes(data)))
        except coverage.BadPiece as exc:
            assert str(exc) and "\n" not in str(exc)
            continue
        assert len(piece) <= coverage.CELLS_PER_PIECE and piece.cell_m > 0


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        ("rate_bytes_s = 10.0", "[coverage] rate_bytes_s = 10.0: must be 50..100000"),
        ("period_s = 0.1", "[coverage] period_s = 0.1: must be 1..3600"),
        ('rate_bytes_s = "fast"', "coverage.rate_bytes_s = 'fast': expected a number"),
    ],
)
def test_check_config_names_a_bad_coverage_setting_in_one_line(
    tmp_path: Path, section: str, expected: str
) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(f"[coverage]\n{section}\n")
    run = subprocess.run(
        [sys.executable, "-m", "companion.commands.cli", "check-config", "--config", str(cfg)],
        capture_output=True, text=True, timeout=60, cwd=Path(__file__).parents[1],
    )  # fmt: skip
    assert run.returncode != 0
    assert expected in run.stderr and "Traceback" not in run.stderr
