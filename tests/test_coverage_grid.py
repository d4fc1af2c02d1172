"""The coverage grid's arithmetic and saved forms (fusion/coverage.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.coverage import CoverageDelta, CoverageError, CoverageGrid, level, quantise

cells_st = st.lists(
    st.tuples(st.integers(-60, 60), st.integers(-60, 60), st.floats(0.0, 1.0)),
    min_size=0,
    max_size=40,
)
looks_st = st.lists(cells_st, min_size=1, max_size=8)


def _apply(grid: CoverageGrid, look: list[tuple[int, int, float]]) -> None:
    cells = np.array([(n, e) for n, e, _ in look], np.int64).reshape(-1, 2)
    grid.add_look(cells, np.array([p for _, _, p in look]))


@settings(max_examples=60, deadline=None)
@given(looks_st)
def test_probabilities_stay_in_range_and_never_fall(
    looks: list[list[tuple[int, int, float]]],
) -> None:
    grid = CoverageGrid()
    probe = np.array([(n, e) for look in looks for n, e, _ in look], np.int64).reshape(-1, 2)
    before = grid.p_at(probe)
    for look in looks:
        _apply(grid, look)
        now = grid.p_at(probe)
        assert np.all((now >= 0.0) & (now <= 1.0))
        assert np.all(now >= before - 1e-7)
        before = now


def test_looks_combine_as_independent_chances() -> None:
    grid = CoverageGrid()
    cell = np.array([[3, -4]])
    for p in (0.5, 0.5, 0.2):
        grid.add_look(cell, np.array([p]))
    assert grid.p_at(cell)[0] == pytest.approx(1 - 0.5 * 0.5 * 0.8, abs=1e-6)
    # The same cell twice in one look counts once, with its larger p.
    other = CoverageGrid()
    other.add_look(np.array([[0, 0], [0, 0]]), np.array([0.3, 0.6]))
    assert other.p_at(np.array([[0, 0]]))[0] == pytest.approx(0.6, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(looks_st, st.integers(0, 7))
def test_deltas_reproduce_the_quantised_grid(
    looks: list[list[tuple[int, int, float]]], split: int
) -> None:
    sender, receiver = CoverageGrid(), CoverageGrid()
    sent = 0
    for k, look in enumerate(looks):
        _apply(sender, look)
        if k == split or k == len(looks) - 1:  # sent in two parts, through bytes
            delta = CoverageDelta.decode(sender.delta_since(sent).encode())
            receiver.apply_delta(delta)
            sent = delta.to_version
    probe = np.array([(n, e) for look in looks for n, e, _ in look], np.int64).reshape(-1, 2)
    got, want = receiver.p_at(probe), sender.p_at(probe)
    assert np.array_equal(level(got), level(want))  # the same class on every map
    assert np.all(quantise(got) <= quantise(want))  # never more than the sender claims
    assert np.all(want - got < 0.1 + 1 / 255)
    assert len(sender.delta_since(sender.version)) == 0


def test_delta_is_only_what_changed_level() -> None:
    grid = CoverageGrid()
    grid.add_look(np.array([[0, 0], [0, 1], [0, 2]]), np.array([0.5, 0.5, 0.55]))
    v = grid.version
    # (0, 1) goes from 0.5 to 0.75, (5, 5) is new; (0, 2) from 0.55 to 0.559 stays in
    # its tenth: not sent.
    grid.add_look(np.array([[0, 1], [5, 5], [0, 2]]), np.array([0.5, 0.01, 0.02]))
    delta = grid.delta_since(v)
    assert sorted(map(tuple, delta.cells.tolist())) == [(0, 1), (5, 5)]
    assert delta.p_q.tolist() == [191, 2]  # floor(0.75 x 255), floor(0.01 x 255)
    assert len(delta.encode()) == 20 + 5 * 2


@settings(max_examples=40, deadline=None)
@given(looks_st)
def test_snapshot_round_trip(looks: list[list[tuple[int, int, float]]]) -> None:
    grid = CoverageGrid()
    for look in looks:
        _apply(grid, look)
    snap = json.loads(json.dumps(grid.snapshot()))  # as SQLite keeps it
    back = CoverageGrid.restore(snap)
    assert back.snapshot() == grid.snapshot()
    # Kept to 1/65535, rounded towards claiming more (within float32: 2e-7).
    assert np.all(back.probabilities() >= grid.probabilities() - 2e-7)
    assert np.all(back.probabilities() - grid.probabilities() < 2e-5)
    assert back.delta_since(0).cells.tolist() == grid.delta_since(0).cells.tolist()


def _snap() -> dict[str, object]:
    grid = CoverageGrid()
    grid.add_look(np.array([[1, 1], [2, 3]]), np.array([0.4, 0.95]))
    return grid.snapshot()


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"format": "other"}, "format"),
        ({"cell_m": "big"}, "cell_m"),
        ({"cell_m": 0.0}, "cell_m"),
        ({"origin": [1]}, "origin"),
        ({"shape": [5000, 5000]}, "shape"),
        ({"shape": [0, 3]}, "shape"),
        ({"miss": "not base64!"}, "miss"),
        ({"shape": [33, 34]}, "miss"),
        ({"grid_version": -1}, "grid_version"),
        ({"grid_version": 0}, "stamp"),
        ({"looks": 1.5}, "looks"),
    ],
)
def test_bad_snapshot_refused_naming_what(change: dict[str, object], named: str) -> None:
    snap = {**_snap(), **change}
    with pytest.raises(CoverageError, match=named) as info:
        CoverageGrid.restore(snap)
    assert "\n" not in str(info.value)


def test_snapshot_that_is_not_a_table_refused() -> None:
    with pytest.raises(CoverageError, match="not a table"):
        CoverageGrid.restore([1, 2])


def test_bad_looks_and_deltas_refused() -> None:
    grid = CoverageGrid()
    with pytest.raises(CoverageError, match=r"not in \[0, 1\]"):
        grid.add_look(np.array([[0, 0]]), np.array([np.nan]))
    with pytest.raises(CoverageError, match="2 cells but 1"):
        grid.add_look(np.array([[0, 0], [1, 1]]), np.array([0.5]))
    with pytest.raises(CoverageError, match="shorter than its header"):
        CoverageDelta.decode(b"RCD")
    data = grid.delta_since(0).encode()
    with pytest.raises(CoverageError, match="expected 20"):
        CoverageDelta.decode(data + b"x")
    with pytest.raises(CoverageError, match="starts with"):
        CoverageDelta.decode(b"XXXX" + data[4:])


def test_growth_is_bounded_by_the_window() -> None:
    grid = CoverageGrid(cell_m=0.25, max_side_cells=64)
    grid.add_look(np.array([[0, 0]]), np.array([0.5]))
    grid.add_look(np.array([[1000, 0], [10, 10]]), np.array([0.5, 0.5]))
    assert max(grid.shape) <= 64
    assert grid.cells_refused == 1  # the far cell is not claimed
    assert grid.p_at(np.array([[1000, 0]]))[0] == 0.0
    assert grid.p_at(np.array([[10, 10], [0, 0]])).tolist() == pytest.approx([0.5, 0.5])


def test_summary_thresholds() -> None:
    grid = CoverageGrid(cell_m=0.5)
    grid.add_look(np.array([[0, 0], [0, 1], [1, 0]]), np.array([0.95, 0.5, 0.1]))
    s = grid.summary((0.0, 2.0, 0.0, 2.0))  # 4 m2: 16 cells of 0.25 m2
    assert s.area_m2 == 4.0
    assert s.searched_well_m2 == 0.25
    assert s.glanced_at_m2 == 0.5
    assert s.looked_at_m2 == 0.75
    assert s.searched_well_share == pytest.approx(0.0625)
