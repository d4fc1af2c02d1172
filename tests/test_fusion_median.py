"""The geometric median: it minimises the sum of distances, moves with the points,
and does not follow a minority of strays however far they lie."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.median import geometric_median

coord = st.floats(-20.0, 20.0, allow_nan=False)
points = st.lists(st.tuples(coord, coord), min_size=1, max_size=40).map(np.array)


def _cost(z: np.ndarray, y: np.ndarray) -> float:
    return float(np.linalg.norm(z - y, axis=1).sum())


@settings(max_examples=200, deadline=None)
@given(points, st.integers(0, 2**32 - 1))
def test_no_other_point_is_nearer_to_all_the_points(z: np.ndarray, seed: int) -> None:
    """Not a fix, nor the mean, nor any point nearby is nearer to all the fixes, by
    more than the smoothing allows (1 mm a fix)."""
    y = geometric_median(z)
    best = _cost(z, y)
    rng = np.random.default_rng(seed)
    others = [*z, z.mean(axis=0), *(y + rng.normal(0.0, 0.05, (20, 2)))]
    assert all(best <= _cost(z, o) + 0.001 * len(z) for o in others)


@settings(max_examples=200, deadline=None)
@given(points, coord, coord, st.floats(0.0, 2 * np.pi))
def test_it_moves_and_turns_with_the_points(
    z: np.ndarray, dn: float, de: float, angle: float
) -> None:
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    shift = np.array([dn, de])
    expected = geometric_median(z) @ rot.T + shift
    assert geometric_median(z @ rot.T + shift) == pytest.approx(expected, abs=1e-3)


@settings(max_examples=200, deadline=None)
@given(st.integers(5, 30), st.integers(0, 2**32 - 1), st.floats(10.0, 1e4))
def test_a_minority_of_strays_cannot_drag_it_away(n: int, seed: int, far_m: float) -> None:
    """Fixes of one victim around (0, 0) with sigma 0.3 m, and fewer strays than
    fixes, all on one side as far as you like: the median stays among the fixes."""
    rng = np.random.default_rng(seed)
    fixes = rng.normal(0.0, 0.3, (n, 2))
    strays = np.array([far_m, 0.0]) + rng.normal(0.0, 0.3, (n // 3, 2))
    y = geometric_median(np.vstack([fixes, strays]))
    assert np.linalg.norm(y) <= np.linalg.norm(fixes, axis=1).max()


@pytest.mark.parametrize(
    "fixes",
    [
        # Fixes 2 mm apart, or one 1e-5 m from the start (the coordinate-wise
        # median): Weiszfeld's iteration crawled there, 2 and 20 cm off the median.
        [(0.0, 0.0), (0.0, 1.0), (0.0, 1.0), (0.0, 0.002), (1.0, 0.0)],
        [(0.0, 1e-5), (0.0, -1.0), (1.0, 0.0)],
    ],
)
def test_it_is_not_stuck_near_fixes_that_lie_together(fixes: list[tuple[float, float]]) -> None:
    z = np.array(fixes)
    y = geometric_median(z)
    # The true median, by brute force on a 2.5 mm grid around it.
    axis = np.linspace(-0.5, 0.5, 401)
    g = np.stack(np.meshgrid(axis, axis), -1)
    costs = np.linalg.norm(g[:, :, None, :] - z, axis=-1).sum(-1)
    true = g.reshape(-1, 2)[int(np.argmin(costs))]
    assert np.linalg.norm(y - true) < 0.01


def test_one_point_and_repeated_points() -> None:
    assert geometric_median(np.array([[2.0, -3.0]])) == pytest.approx([2.0, -3.0])
    assert geometric_median(np.array([[1.0, 1.0]] * 4)) == pytest.approx([1.0, 1.0])
    # Three of five on one fix: that fix is the median (to within the smoothing).
    z = np.array([[1.0, 1.0]] * 3 + [[4.0, 0.0], [0.0, 9.0]])
    assert geometric_median(z) == pytest.approx([1.0, 1.0], abs=0.001)


@pytest.mark.parametrize("bad", [np.zeros((0, 2)), np.zeros((3, 3)), np.zeros(4)])
def test_it_needs_floor_points(bad: np.ndarray) -> None:
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        geometric_median(bad)
