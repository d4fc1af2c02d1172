"""The burial generator covers each person's box to the asked share, reproducibly."""

from __future__ import annotations

import numpy as np
import pytest

from bench.burial import bury


def _textures() -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    return [rng.integers(0, 255, (300, 400, 3), dtype=np.uint8)]


@pytest.mark.parametrize("visible_pct", [50.0, 20.0, 5.0])
def test_box_is_covered_to_the_level(visible_pct: float) -> None:
    image = np.full((240, 320, 3), 255, np.uint8)  # white: every changed pixel is debris
    box = [100.0, 60.0, 80.0, 120.0]
    out = bury(image, [box], visible_pct, _textures(), seed=3)
    inside = out[60:180, 100:180]
    shown_pct = 100.0 * np.all(inside == 255, axis=2).mean()
    assert shown_pct <= visible_pct
    assert shown_pct >= visible_pct - 15.0  # buried to the level, not past it


def test_same_seed_same_burial() -> None:
    image = np.full((240, 320, 3), 200, np.uint8)
    box = [[40.0, 40.0, 60.0, 100.0]]
    a = bury(image, box, 20.0, _textures(), seed=7)
    b = bury(image, box, 20.0, _textures(), seed=7)
    c = bury(image, box, 20.0, _textures(), seed=8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
