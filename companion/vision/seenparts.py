"""How much of a body the landmark model actually sees.

The BlazePose landmark model's mask fills in the parts of a body it has found that
are covered by debris (bench/burial.py: its area over the person's box is a median
0.41 uncovered and 0.45 with 80 % of the box covered), so the mask alone reads a
buried body as mostly visible. Its per-joint heatmaps (64x64, one per landmark) do
not fill in the same way: the heatmap's peak logit of a joint under debris is lower
(on the real burial benchmark, 2026-11-27: uncovered joints median +0.17, covered
-0.57; as a test of covered against uncovered, area under the ROC curve 0.79). The
joints' visibility scores hardly tell them apart (0.56-0.60).

The seen share of a body is the share of its main joints in the frame (nose,
shoulders, elbows, wrists, hips, knees, ankles) whose heatmap peaks at
``min_logit`` or more. A joint outside the frame is unknown, not covered: it counts
for neither side.
"""

from __future__ import annotations

import numpy as np

# BlazePose indices: nose, shoulders, elbows, wrists, hips, knees, ankles.
MAIN_JOINTS = (0, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)


def joint_evidence(heatmaps: np.ndarray, n_joints: int) -> np.ndarray:
    """Each joint's heatmap peak logit, from the model's (H, W, >= n_joints) output."""
    flat = heatmaps.reshape(-1, heatmaps.shape[-1])[:, :n_joints]
    peaks: np.ndarray = flat.max(axis=0).astype(np.float64)
    return peaks


def seen_share(
    points_px: np.ndarray, evidence: np.ndarray, frame_wh: tuple[int, int], min_logit: float
) -> float | None:
    """The share of the body's main joints in the frame that the heatmaps see, 0..1.

    ``points_px``: (33, 2) landmarks in frame pixels; ``evidence``: (33,) heatmap
    peak logits. None when no main joint is in the frame."""
    w, h = frame_wh
    joints = list(MAIN_JOINTS)
    x, y = points_px[joints, 0], points_px[joints, 1]
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    if not inside.any():
        return None
    return float(np.mean(evidence[joints][inside] >= min_logit))
