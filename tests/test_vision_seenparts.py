"""The share of a body its joint heatmaps see (companion/vision/seenparts.py)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.vision.seenparts import MAIN_JOINTS, joint_evidence, seen_share

LEGS = (23, 24, 25, 26, 27, 28)  # hips, knees, ankles
SEEN, COVERED = 2.0, -2.0


def _lying_body() -> np.ndarray:
    """33 landmarks of a body lying across a 640x480 frame, head on the left."""
    pts = np.zeros((33, 2))
    pts[:11] = (100, 240)  # head and face
    pts[11], pts[12] = (180, 220), (180, 260)  # shoulders
    pts[13], pts[14] = (240, 200), (240, 280)  # elbows
    pts[15:23] = (300, 200)  # wrists and hands
    pts[23], pts[24] = (340, 225), (340, 255)  # hips
    pts[25], pts[26] = (440, 225), (440, 255)  # knees
    pts[27:33] = (540, 240)  # ankles, heels, feet
    return pts


def test_a_body_seen_whole_is_seen_whole() -> None:
    assert seen_share(_lying_body(), np.full(33, SEEN), (640, 480), 0.0) == 1.0


def test_covered_legs_take_their_share_of_the_body_away() -> None:
    ev = np.full(33, SEEN)
    ev[list(LEGS)] = COVERED
    share = seen_share(_lying_body(), ev, (640, 480), 0.0)
    assert share == pytest.approx(1.0 - len(LEGS) / len(MAIN_JOINTS))


def test_the_threshold_is_on_the_heatmap_peak() -> None:
    ev = np.full(33, -0.5)
    assert seen_share(_lying_body(), ev, (640, 480), -0.4) == 0.0
    assert seen_share(_lying_body(), ev, (640, 480), -0.5) == 1.0


def test_a_body_cut_by_the_frame_is_not_buried_there() -> None:
    """Legs beyond the frame's right edge have weak heatmaps (the model sees padding):
    unknown, so the part in the frame, seen whole, is seen whole."""
    pts = _lying_body()
    pts[:, 0] += 250  # knees (690) and ankles (790) beyond x = 640
    ev = np.full(33, SEEN)
    ev[[25, 26, 27, 28]] = COVERED
    assert seen_share(pts, ev, (640, 480), 0.0) == 1.0


def test_nothing_in_the_frame_is_unknown() -> None:
    pts = _lying_body() + 1000.0
    assert seen_share(pts, np.full(33, SEEN), (640, 480), 0.0) is None


def test_joint_evidence_is_each_heatmaps_peak() -> None:
    heat = np.full((64, 64, 39), -3.0, np.float32)
    heat[10, 20, 0] = 1.5
    heat[5, 5, 38] = 9.0  # beyond the body's joints: ignored
    ev = joint_evidence(heat, 33)
    assert ev.shape == (33,)
    assert ev[0] == pytest.approx(1.5) and ev[1:].max() == pytest.approx(-3.0)
