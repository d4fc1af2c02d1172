"""MediaPipe's single-shot detector head: anchors, box decoding, weighted NMS.

The BlazePose person detector, the palm detector and the face detector share one
output format: per anchor, a box (centre offset and size, in input pixels) followed
by keypoints (offsets in input pixels), and one logit. Anchors follow MediaPipe's
SsdAnchorsCalculator with ``fixed_anchor_size`` (every anchor is 1x1, only its
centre matters): layers with the same stride share a feature map, and each layer
adds two anchors per cell (the aspect-1 one and the interpolated scale), except
where ``interpolated_scale`` is off (one anchor per cell).

Decoded boxes and keypoints are in [0, 1] of the (letterboxed) model input.
Weighted NMS (MediaPipe's WEIGHTED suppression): overlapping boxes are averaged,
weighted by score, which steadies the box of one object seen by many anchors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SsdSpec:
    input_px: int
    strides: tuple[int, ...]
    num_keypoints: int
    min_score: float
    interpolated_scale: bool = True


def anchors(spec: SsdSpec) -> np.ndarray:
    """Anchor centres (N, 2) as (x, y) in [0, 1], in the model's output order."""
    out: list[np.ndarray] = []
    i = 0
    per_layer = 2 if spec.interpolated_scale else 1
    while i < len(spec.strides):
        stride = spec.strides[i]
        n = 0
        while i < len(spec.strides) and spec.strides[i] == stride:
            n += per_layer
            i += 1
        cells = -(-spec.input_px // stride)  # ceil
        ys, xs = np.mgrid[0:cells, 0:cells]
        centres = np.stack([(xs + 0.5) / cells, (ys + 0.5) / cells], axis=-1).reshape(-1, 1, 2)
        out.append(np.repeat(centres, n, axis=1).reshape(-1, 2))
    return np.concatenate(out).astype(np.float32)


@dataclass(frozen=True)
class SsdDetection:
    score: float
    box: tuple[float, float, float, float]  # x0, y0, x1, y1 in [0, 1] of the input
    keypoints: np.ndarray  # (K, 2) x, y in [0, 1] of the input


def decode(
    spec: SsdSpec, anchor_xy: np.ndarray, raw_boxes: np.ndarray, raw_scores: np.ndarray
) -> list[SsdDetection]:
    """Boxes above ``spec.min_score``, after weighted NMS (IoU 0.3), best first."""
    logits = np.clip(raw_scores.reshape(-1), -100.0, 100.0)
    scores = 1.0 / (1.0 + np.exp(-logits.astype(np.float64)))
    keep = np.nonzero(scores >= spec.min_score)[0]
    if keep.size == 0:
        return []
    raw = raw_boxes.reshape(len(scores), -1)[keep].astype(np.float64) / spec.input_px
    anc = anchor_xy[keep].astype(np.float64)
    cx = raw[:, 0] + anc[:, 0]
    cy = raw[:, 1] + anc[:, 1]
    w, h = raw[:, 2], raw[:, 3]
    boxes = np.column_stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2])
    kps = raw[:, 4 : 4 + 2 * spec.num_keypoints].reshape(-1, spec.num_keypoints, 2) + anc[:, None]
    return weighted_nms(boxes, scores[keep], kps, 0.3)


def iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    ix0 = np.maximum(box[0], boxes[:, 0])
    iy0 = np.maximum(box[1], boxes[:, 1])
    ix1 = np.minimum(box[2], boxes[:, 2])
    iy1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(ix1 - ix0, 0, None) * np.clip(iy1 - iy0, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    union = area + areas - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def weighted_nms(
    boxes: np.ndarray, scores: np.ndarray, keypoints: np.ndarray, iou_threshold: float
) -> list[SsdDetection]:
    order = np.argsort(-scores)
    boxes, scores, keypoints = boxes[order], scores[order], keypoints[order]
    alive = np.ones(len(scores), dtype=bool)
    out = []
    for i in range(len(scores)):
        if not alive[i]:
            continue
        overlap = alive & (iou(boxes[i], boxes) > iou_threshold)
        overlap[i] = True
        w = scores[overlap]
        box = (boxes[overlap] * w[:, None]).sum(axis=0) / w.sum()
        kps = (keypoints[overlap] * w[:, None, None]).sum(axis=0) / w.sum()
        alive &= ~overlap
        out.append(SsdDetection(float(scores[i]), tuple(float(b) for b in box), kps))  # type: ignore[arg-type]
    return out
