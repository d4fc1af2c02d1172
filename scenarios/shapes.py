"""Ray intersection with the solid primitives the simulator draws in 3-D.

Every function takes one ray origin ``o`` (3,) shared by all rays (a pinhole camera)
and unit ray directions ``d`` (N, 3), all in local NED metres, and returns the
distance along each ray to the first hit (``inf`` for a miss) and the unit surface
normal there (N, 3; undefined for a miss). Hits behind the origin are misses.

- ``capsule``: the points within ``radius`` of a segment (limbs, neck, torso);
- ``ellipsoid``: a centre and three semi-axes given as the columns of a matrix
  (head, hands, feet, hips);
- ``prism``: a convex polygon on the floor extruded from ``bottom_m`` up to
  ``top_m`` (debris: bricks, slabs, cartons, pallets, racking uprights).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F = NDArray[np.float64]


def capsule(o: F, d: F, a: F, b: F, radius_m: float) -> tuple[F, F]:
    ba = b - a
    oa = o - a
    baba = float(ba @ ba)
    bard = d @ ba
    baoa = float(ba @ oa)
    rdoa = d @ oa
    oaoa = float(oa @ oa)
    qa = baba - bard * bard
    qb = baba * rdoa - baoa * bard
    qc = baba * oaoa - baoa * baoa - radius_m * radius_m * baba
    disc = qb * qb - qa * qc
    t = np.full(len(d), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_side = (-qb - np.sqrt(disc)) / qa
        y = baoa + t_side * bard
        side = (disc >= 0) & (qa > 1e-12) & (y > 0) & (y < baba) & (t_side > 0)
        t[side] = t_side[side]
        # The spherical caps, where the side missed.
        rest = ~side
        for end in (a, b):
            oc = o - end
            bb = d @ oc
            cc = float(oc @ oc) - radius_m * radius_m
            h = bb * bb - cc
            tc = -bb - np.sqrt(h)
            cap = rest & (h >= 0) & (tc > 0) & (tc < t)
            t[cap] = tc[cap]
    p = o + d * np.where(np.isfinite(t), t, 0.0)[:, None]
    pa = p - a
    k = np.clip((pa @ ba) / baba, 0.0, 1.0)
    n = (pa - k[:, None] * ba) / radius_m
    return t, n


def ellipsoid(o: F, d: F, centre: F, axes: F) -> tuple[F, F]:
    """``axes``: 3x3, columns are the semi-axis vectors (orthogonal)."""
    inv = np.linalg.inv(axes)
    oo = inv @ (o - centre)
    dd = d @ inv.T
    qa = np.einsum("ij,ij->i", dd, dd)
    qb = dd @ oo
    qc = float(oo @ oo) - 1.0
    disc = qb * qb - qa * qc
    t = np.full(len(d), np.inf)
    with np.errstate(invalid="ignore"):
        t0 = (-qb - np.sqrt(disc)) / qa
    hit = (disc >= 0) & (t0 > 0)
    t[hit] = t0[hit]
    local = oo + dd * np.where(hit, t, 0.0)[:, None]
    n = local @ inv  # gradient of |inv (p - c)|^2 is inv^T inv (p - c)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return t, n


def prism_planes(polygon_ne_m: F, bottom_m: float, top_m: float) -> tuple[F, F]:
    """The bounding planes of a vertical prism: outward unit normals (P, 3) and offsets
    (P,), so that a point x is inside when ``normals @ x <= offsets`` for every plane.

    ``polygon_ne_m``: a convex polygon (either winding); heights above the floor
    (NED down = -height).
    """
    poly = np.asarray(polygon_ne_m, float)
    centre = poly.mean(axis=0)
    normals, offsets = [], []
    for i in range(len(poly)):
        p0, p1 = poly[i], poly[(i + 1) % len(poly)]
        e = p1 - p0
        nrm = np.array([e[1], -e[0]])
        if nrm @ (centre - p0) > 0:
            nrm = -nrm
        ln = float(np.hypot(*nrm))
        if ln < 1e-9:
            continue
        nrm /= ln
        normals.append([nrm[0], nrm[1], 0.0])
        offsets.append(float(nrm @ p0))
    normals += [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]]  # top: -down <= top; bottom
    offsets += [top_m, -bottom_m]
    return np.array(normals), np.array(offsets)


def prism(o: F, d: F, planes: tuple[F, F]) -> tuple[F, F]:
    """Entry distance and normal of rays into a convex prism (``prism_planes``)."""
    normals, offsets = planes
    denom = d @ normals.T  # (N, P)
    num = offsets - normals @ o  # (P,)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / denom
    t_enter = np.where(denom < 0, t, -np.inf)
    k_in = np.argmax(t_enter, axis=1)
    t_in = np.maximum(np.take_along_axis(t_enter, k_in[:, None], axis=1)[:, 0], 0.0)
    t_out = np.where(denom > 0, t, np.inf).min(axis=1)
    outside_parallel = ((denom == 0) & (num < 0)).any(axis=1)
    hit = (t_in <= t_out) & ~outside_parallel & (t_in > 0)
    return np.where(hit, t_in, np.inf), normals[k_in]
