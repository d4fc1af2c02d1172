"""Which warm clusters are one person: each skin seed with the clusters near it.

A head out of cold water and the hands beside it are three clusters (the hands
read 14-19 °C, no skin seed of their own); warm clusters within the merge gap of a
seed join it, and seeds within the gap of each other (or of a cluster both reach)
are one person. With a geometry the gap is measured on the floor, between the
clusters' floor boxes (over up to 32 of their pixels each): in a rover's frame a pixel spans 4 mm of floor near the
vehicle and 20 cm at 5 m, so no gap in pixels fits every row. In a photo it is a
share of the frame's width.
"""

from __future__ import annotations

import cv2
import numpy as np

from companion.vision.base import FrameGeometry

_POINTS_PER_CLUSTER = 32  # floor points kept per cluster (a stride over its pixels)


def _components(n: int, edges: np.ndarray, keep: np.ndarray) -> list[np.ndarray]:
    """Connected components of clusters 0..n-1 over the edges (E x 2), those holding
    a kept one, each as its sorted cluster labels."""
    comp = np.arange(n)
    a, b = edges[:, 0], edges[:, 1]
    while a.size:  # the smallest label of each component spreads along the edges
        low = np.minimum(comp[a], comp[b])
        if (comp[a] == low).all() and (comp[b] == low).all():
            break
        np.minimum.at(comp, a, low)
        np.minimum.at(comp, b, low)
        comp = comp[comp]
    wanted = np.unique(comp[keep])
    order = np.argsort(comp, kind="stable")
    order = order[np.isin(comp[order], wanted)]
    cuts = np.flatnonzero(np.diff(comp[order])) + 1
    return [g.astype(np.int64) for g in np.split(order, cuts)]


def group_on_floor(
    labels: np.ndarray,
    seeds: np.ndarray,
    joinable: np.ndarray,
    geometry: FrameGeometry,
    gap_m: float,
) -> list[np.ndarray]:
    """Cluster labels per person, the gap measured between floor boxes. A cluster
    with no pixel on the floor joins nothing (a seed of it stands alone)."""
    n = len(seeds)
    join = joinable.copy()
    join[0] = False  # the background
    idx = np.flatnonzero(join[labels])
    no_edges = np.zeros((0, 2), np.int64)
    if idx.size == 0:
        return _components(n, no_edges, seeds)
    owner = labels.ravel()[idx]
    order = np.argsort(owner, kind="stable")
    idx, owner = idx[order], owner[order]
    starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
    counts = np.diff(np.r_[starts, owner.size])
    step = np.maximum(1, counts // _POINTS_PER_CLUSTER)
    rank = np.arange(owner.size) - np.repeat(starts, counts)
    keep = rank % np.repeat(step, counts) == 0  # a stride over each cluster's pixels
    idx, owner = idx[keep], owner[keep]
    w = labels.shape[1]
    floor = geometry.floor_ne_m(np.column_stack([idx % w, idx // w]).astype(np.float64))
    ok = np.isfinite(floor).all(axis=1)
    floor, owner = floor[ok], owner[ok]
    if owner.size == 0:
        return _components(n, no_edges, seeds)
    starts = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
    ids = owner[starts]
    lo = np.minimum.reduceat(floor, starts, axis=0)  # each cluster's floor box
    hi = np.maximum.reduceat(floor, starts, axis=0)
    # seed to cluster: the distance between their floor boxes (a hand and a head are
    # compact; a long diagonal cluster may join a little early)
    k = np.flatnonzero(seeds[ids])
    apart = np.maximum(0.0, np.maximum(lo[None, :, :] - hi[k, None, :], lo[k, None, :] - hi))
    a, b = np.nonzero(np.hypot(apart[..., 0], apart[..., 1]) <= gap_m)
    return _components(n, np.column_stack([ids[k[a]], ids[b]]), seeds)


def group_in_pixels(
    labels: np.ndarray, seeds: np.ndarray, joinable: np.ndarray, gap_px: float
) -> list[np.ndarray]:
    """Cluster labels per person, the gap in pixels: the clusters that the seeds'
    surroundings (within gap_px, joined where they touch) reach."""
    seed_mask = seeds[labels].astype(np.uint8)
    away = cv2.distanceTransform(1 - seed_mask, cv2.DIST_L2, 3)
    _, zones = cv2.connectedComponents((away <= gap_px).astype(np.uint8), connectivity=8)
    both = (zones > 0) & (labels > 0)
    zone_of = np.zeros(len(seeds), np.int64)
    zone_of[labels[both]] = zones[both]  # a cluster lies in one zone (any of its pixels)
    zone_of[~joinable] = 0
    zone_of[0] = 0
    order = np.argsort(zone_of, kind="stable")
    kept = order[zone_of[order] > 0]
    return [g for g in np.split(kept, np.flatnonzero(np.diff(zone_of[kept])) + 1) if g.size]
