"""bench/real_images.py's memory figure is the detector process's own."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bench.real_images import peak_rss_mb


def test_peak_rss_is_the_childs_not_the_benchmarks(tmp_path: Path) -> None:
    """Linux keeps getrusage's peak across exec: a child forked from a large process
    reported the parent's resident set. Here the parent holds 600 MB more than the
    detector needs; the figure must not include it."""
    image = tmp_path / "frame.png"
    cv2.imwrite(str(image), np.full((480, 640, 3), 90, np.uint8))
    ballast = np.ones(600_000_000 // 8)
    assert ballast.sum() > 0  # touched: resident
    assert 50.0 < peak_rss_mb(image) < 500.0
