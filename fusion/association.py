"""Which observation belongs to which track, and which two tracks are one victim.

Every test is the squared Mahalanobis distance d^2 = y^T S^-1 y against a
chi-square threshold, and never for a pair further apart than
``max_match_distance_m``, whatever its d^2: that is the metric bound on how far a
person's fix strays from itself. The tracker (``fusion.tracker``) decides what
follows from each answer.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from fusion.camera import FloatArray
from fusion.kalman import mahalanobis2
from fusion.params import TrackerParams
from fusion.track import Track
from fusion.types import Observation

_INFEASIBLE = 1e12  # cost of a pair outside the gate


def associate(
    live: list[Track], p: FloatArray, observations: Sequence[Observation], params: TrackerParams
) -> tuple[list[tuple[int, int]], np.ndarray]:
    """Gated Hungarian assignment; returns (track index, obs index) pairs and the
    matrix of squared Mahalanobis distances. ``p`` is the tracks' stacked predicted
    covariance (T, 2, 2)."""
    n_t, n_o = len(live), len(observations)
    if n_t == 0 or n_o == 0:
        return [], np.zeros((n_t, n_o))
    x = np.array([t.x for t in live])  # (T, 2)
    z = np.array([(o.north_m, o.east_m) for o in observations])  # (O, 2)
    r = np.array([o.cov_ne_m2 for o in observations])  # (O, 2, 2)
    # S = P + R and y = z - x for every pair
    d2, det = mahalanobis2(z[None, :, :] - x[:, None, :], p[:, None] + r[None, :])
    gated = (d2 <= params.gate_chi2) & near(live, observations, params.max_match_distance_m)
    cost = np.where(gated, d2 + np.log(det), _INFEASIBLE)
    return _assign(gated, cost), d2


def near(
    live: list[Track], observations: Sequence[Observation], max_distance_m: float
) -> np.ndarray:
    """(T, O): which track-observation pairs are within max_distance_m."""
    if not live or not observations:
        return np.zeros((len(live), len(observations)), dtype=bool)
    x = np.array([t.x for t in live])
    z = np.array([(o.north_m, o.east_m) for o in observations])
    dist = np.linalg.norm(z[None, :, :] - x[:, None, :], axis=-1)
    return np.asarray(dist <= max_distance_m)


def same_point(a: Observation, b: Observation, params: TrackerParams) -> bool:
    """Two observations of one frame that are one victim detected twice."""
    dz = np.array([a.north_m - b.north_m, a.east_m - b.east_m])
    if float(np.hypot(*dz)) > params.max_match_distance_m:
        return False
    d2, _ = mahalanobis2(dz, np.array(a.cov_ne_m2) + np.array(b.cov_ne_m2))
    return float(d2) <= params.merge_chi2


def _assign(gated: np.ndarray, cost: np.ndarray) -> list[tuple[int, int]]:
    """Minimum-cost assignment among gated pairs. Pairs alone in their row and
    column are taken directly; the rest go through linear_sum_assignment."""
    rows_n = gated.sum(axis=1)
    cols_n = gated.sum(axis=0)
    lone = gated & (rows_n[:, None] == 1) & (cols_n[None, :] == 1)
    pairs = [(int(i), int(j)) for i, j in zip(*np.nonzero(lone), strict=True)]
    rows = np.nonzero((rows_n > 0) & ~lone.any(axis=1))[0]
    cols = np.nonzero((cols_n > 0) & ~lone.any(axis=0))[0]
    if len(rows) and len(cols):
        sub = cost[np.ix_(rows, cols)]
        ri, ci = linear_sum_assignment(sub)
        for i, j in zip(ri, ci, strict=True):
            if gated[rows[i], cols[j]]:
                pairs.append((int(rows[i]), int(cols[j])))
    return pairs


def closest_pair(
    first: list[Track], second: list[Track], merge_chi2: float, max_distance_m: float
) -> tuple[Track, Track] | None:
    """The pair (one from each list, two different tracks) with the smallest
    d^2 = dx^T (P1 + P2)^-1 dx, if within merge_chi2 and max_distance_m."""
    if not first or not second:
        return None
    x1, x2 = np.array([t.x for t in first]), np.array([t.x for t in second])
    p1, p2 = np.array([t.kf.P for t in first]), np.array([t.kf.P for t in second])
    dx = x1[:, None, :] - x2[None, :, :]
    d2, _ = mahalanobis2(dx, p1[:, None] + p2[None, :])
    ids1 = np.array([t.track_id for t in first])
    ids2 = np.array([t.track_id for t in second])
    d2[ids1[:, None] == ids2[None, :]] = np.inf  # a track is not its own twin
    d2[np.linalg.norm(dx, axis=-1) > max_distance_m] = np.inf  # too far to be one person
    k = int(np.argmin(d2))
    i, j = divmod(k, d2.shape[1])
    if d2[i, j] > merge_chi2:
        return None
    return first[i], second[j]
