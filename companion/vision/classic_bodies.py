"""One body, one detection: the classic backend's regions (skin seeds, clothing
parts) and how they cluster into bodies on the floor (companion.vision.classic,
step 6)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.vision.classic_params import ClassicParams


@dataclass
class Node:
    """A skin seed or a clothing part (or a cluster of them)."""

    labels: list[tuple[int, int]]  # (mask kind 0 skin / 1 cloth, label)
    frame_px: float
    su: float  # sums of frame u and v, weighted by frame pixels
    sv: float
    floor: np.ndarray  # outline points on the floor (M, 2)
    area_m2: float
    seeds: int
    x0: int
    y0: int
    x1: int
    y1: int

    def join(self, other: Node) -> Node:
        return Node(
            self.labels + other.labels,
            self.frame_px + other.frame_px,
            self.su + other.su,
            self.sv + other.sv,
            np.vstack([self.floor, other.floor]),
            self.area_m2 + other.area_m2,
            self.seeds + other.seeds,
            min(self.x0, other.x0),
            min(self.y0, other.y0),
            max(self.x1, other.x1),
            max(self.y1, other.y1),
        )


def gap_m(a: Node, b: Node) -> float:
    """The smallest floor distance between the two outlines (inf if one has none)."""
    if len(a.floor) == 0 or len(b.floor) == 0:
        return math.inf
    d = a.floor[:, None, :] - b.floor[None, :, :]
    return float(np.sqrt((d * d).sum(axis=2).min()))


def body_sized(n: Node, p: ClassicParams) -> bool:
    """At most ``body_area_max_m2`` on the floor and ``body_extent_max_m`` across."""
    if n.area_m2 > p.body_area_max_m2:
        return False
    pts = n.floor
    if len(pts) > 2:
        pts = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
    d = pts[:, None, :] - pts[None, :, :]
    extent = float(np.sqrt((d * d).sum(axis=2).max())) if len(pts) else 0.0
    return extent <= p.body_extent_max_m


def bodies(seeds: list[Node], parts: list[Node], p: ClassicParams) -> list[Node]:
    """One cluster per body: clothing parts join the seed cluster they touch, then
    clusters merge while each union is still one body."""
    clusters = list(seeds)
    free = list(parts)
    changed = True
    while changed and free:  # clothing joins the body it touches, transitively
        changed = False
        for part in list(free):
            gaps = [gap_m(c, part) for c in clusters]
            j = int(np.argmin(gaps))
            if gaps[j] <= p.part_gap_m:
                joined = clusters[j].join(part)
                if body_sized(joined, p):
                    clusters[j] = joined
                    free.remove(part)
                    changed = True
    return _merge(clusters, p)


def _merge(clusters: list[Node], p: ClassicParams) -> list[Node]:
    """Closest pairs first, while the union is still one body."""
    while len(clusters) > 1:
        best: tuple[float, int, int] | None = None
        for i in range(len(clusters)):
            for j in range(i + 1, len(clusters)):
                gap = gap_m(clusters[i], clusters[j])
                if gap <= p.seed_gap_m and (best is None or gap < best[0]):
                    joined = clusters[i].join(clusters[j])
                    if body_sized(joined, p):
                        best = (gap, i, j)
        if best is None:
            break
        _, i, j = best
        clusters[i] = clusters[i].join(clusters[j])
        del clusters[j]
    return clusters
