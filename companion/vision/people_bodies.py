"""The bodies the ``people`` backend finds in one frame, and how the passes' finds
merge into one body each (boxes or masks overlapping)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class View:
    """Where the person detector looks: the frame or a tile (x0, y0, x1, y1) of it,
    turned by ``cv2.ROTATE_*`` or not."""

    turn: int | None
    tile: tuple[int, int, int, int] | None


@dataclass
class Body:
    score: float
    cues: set[str]
    region: np.ndarray  # uint8 mask of the body's region in the frame (crop or part box)
    mask: np.ndarray  # bool, visible body pixels
    points: np.ndarray | None  # (33, 2) landmarks in frame pixels, when trusted
    hip_px: np.ndarray  # (2,) hip centre
    box: tuple[float, float, float, float]  # x0, y0, x1, y1
    part: str = ""  # "face" / "hand" for a lone part
    part_extent_px: float = 0.0  # the part's size, for a body's extent in a photo
    seen: np.ndarray | None = None  # (33,) each landmark's visibility, 0..1
    # The share of the body in the frame its joint heatmaps see (seenparts.py).
    seen_share: float | None = None


def bbox(mask: np.ndarray) -> tuple[float, float, float, float]:
    ys, xs = np.nonzero(mask)
    return float(xs.min()), float(ys.min()), float(xs.max() + 1), float(ys.max() + 1)


def box_overlap(
    a: tuple[float, float, float, float], b: tuple[float, float, float, float]
) -> float:
    """The intersection of two boxes (x0, y0, x1, y1) over the smaller one's area."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    smaller = min((a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1]))
    return iw * ih / smaller if smaller > 0 else 0.0


def mask_overlap(a: Body, b: Body) -> float:
    """The pixels two bodies' masks share over the smaller mask's pixels. A body's
    box holds its mask, so only the boxes' intersection is compared (a full-frame
    comparison of two masks costs 0.3 ms at 640x480)."""
    h, w = a.mask.shape
    x0 = max(0, math.floor(max(a.box[0], b.box[0])))
    y0 = max(0, math.floor(max(a.box[1], b.box[1])))
    x1 = min(w, math.ceil(min(a.box[2], b.box[2])))
    y1 = min(h, math.ceil(min(a.box[3], b.box[3])))
    if x1 <= x0 or y1 <= y0:
        return 0.0
    shared = int(np.count_nonzero(a.mask[y0:y1, x0:x1] & b.mask[y0:y1, x0:x1]))
    if shared == 0:
        return 0.0
    smaller = min(int(np.count_nonzero(a.mask)), int(np.count_nonzero(b.mask)))
    return shared / smaller


def add_body(bodies: list[Body], new: Body, same_overlap: float) -> None:
    """Add ``new`` unless it is a body already found by another pass (boxes or masks
    overlapping by ``same_overlap`` of the smaller): then the one with landmarks,
    else the higher score, stays, with the cues of both. The masks decide where a
    body cut by the frame has its landmarks' box reach far out of it (a 10-minute
    recorded mission: a head at the frame's edge, its box 56 % inside the whole
    body's, its mask 96 %, made a second detection of one body)."""
    for i, b in enumerate(bodies):
        if box_overlap(b.box, new.box) < same_overlap and mask_overlap(b, new) < same_overlap:
            continue
        keep, drop = (
            (b, new)
            if (b.points is not None, b.score) >= (new.points is not None, new.score)
            else (new, b)
        )
        keep.cues |= drop.cues
        bodies[i] = keep
        return
    bodies.append(new)
