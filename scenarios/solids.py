"""The 3-D pass of the renderer: solid bodies and debris over the rendered floor.

After the floor is sampled (scenarios.render), every camera ray is intersected with
the victims' solid bodies (scenarios.body3d) and the debris prisms (the convex hull
of each piece's outline, from the floor up to its height). The nearest hit in front
of the floor wins (a z-buffer per pixel); it is shaded with the light of the zone it
stands in, a sky term for surfaces facing up, and the headlight. Debris that lies on
a victim is raised above the body, so the part of the body under it is hidden from
every view: the ground-truth visibility (the uncovered share of the body's
footprint, scenarios.world) and what the camera sees agree.

Which victim each pixel shows is returned, so the renderer's ground truth ("in
view", visible pixels) counts what is really drawn, occlusion included.

The solid warm objects (scenarios.world.WarmObject: a radiator panel and machinery
as prisms, a pipe as a capsule, a lying dog as ellipsoids and a tail) are drawn as
plain shapes in their colour. ``trace`` is the ray casting and z-buffer alone (what
each pixel hits: owner, material, depth, normal); the thermal renderer
(scenarios.thermal) uses it through any camera and maps what is hit to temperatures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.camera import CameraModel
from scenarios import body3d, shapes
from scenarios.raster import FloorRaster
from scenarios.world import Debris, Victim, WarmObject, World, compute_visibility

F = NDArray[np.float64]
PROP_BASE = 1 << 20  # owner ids of warm objects' parts: PROP_BASE + index into props

_PILE_CLEARANCE_M = 0.04  # a pile's top above the body it buries
_SOLID_MIN_M = 0.02  # thinner debris is drawn flat, by the floor raster
_SKY = 0.45  # share of a zone's light on a vertical surface (1 on one facing up)
_CULL_MARGIN = 1.3  # bounding-sphere pixel radius, for the lens distortion


@dataclass(frozen=True)
class _Prism:
    planes: tuple[F, F]  # shapes.prism_planes of the hull, floor to top
    corners: F  # (2N, 3) NED: the hull at the floor and at the top
    top_m: float
    centre: F  # bounding sphere (NED)
    radius_m: float


def _body_top_m(body: body3d.Body3D) -> float:
    top = 0.0
    for s in body.solids:
        if s.kind == "capsule":
            top = max(top, -float(s.a[2]) + s.radius_m, -float(s.b[2]) + s.radius_m)
        else:
            top = max(top, -float(s.a[2]) + float(np.linalg.norm(s.axes[2, :])))
    return top


def _prism(d: Debris, victims: tuple[Victim, ...], bodies: list[body3d.Body3D]) -> _Prism:
    poly = d.polygon
    top = d.height_m
    for v, b in zip(victims, bodies, strict=True):
        if compute_visibility(v, (d,))[0] < 100.0:
            top = max(top, _body_top_m(b) + _PILE_CLEARANCE_M)
    c2 = poly.mean(axis=0)
    r = float(np.linalg.norm(poly - c2, axis=1).max())
    corners = np.vstack(
        [
            np.column_stack([poly, np.zeros(len(poly))]),
            np.column_stack([poly, np.full(len(poly), -top)]),
        ]
    )
    return _Prism(
        shapes.prism_planes(poly, 0.0, top),
        corners,
        top,
        np.array([c2[0], c2[1], -top / 2]),
        math.hypot(r, top / 2),
    )


def _box_prism(poly: F, bottom_m: float, top_m: float) -> _Prism:
    c2 = poly.mean(axis=0)
    r = float(np.linalg.norm(poly - c2, axis=1).max())
    corners = np.vstack(
        [
            np.column_stack([poly, np.full(len(poly), -bottom_m)]),
            np.column_stack([poly, np.full(len(poly), -top_m)]),
        ]
    )
    return _Prism(
        shapes.prism_planes(poly, bottom_m, top_m),
        corners,
        top_m,
        np.array([c2[0], c2[1], -(top_m + bottom_m) / 2]),
        math.hypot(r, (top_m - bottom_m) / 2),
    )


def prop_parts(w: WarmObject) -> list[body3d.Solid | _Prism]:
    """The solids a solid warm object is drawn with (none for warmth on the floor)."""
    h = w.heading_rad
    u = np.array([math.cos(h), math.sin(h), 0.0])
    v = np.array([-math.sin(h), math.cos(h), 0.0])
    down = np.array([0.0, 0.0, 1.0])
    centre = np.array([w.north_m, w.east_m, 0.0])
    if w.kind in ("radiator", "machinery"):
        return [_box_prism(w.polygon, w.elevation_m, w.elevation_m + w.height_m)]
    if w.kind == "pipe":
        r = w.width_m / 2
        axis = centre - down * max(w.elevation_m, r)
        a, b = axis - u * w.length_m / 2, axis + u * w.length_m / 2
        return [body3d.Solid("capsule", 0, a, b, r, np.eye(3), "pipe")]
    if w.kind == "dog":  # lying down: a body, a head at the front, a tail
        k = w.length_m / 0.8
        half_w = w.width_m / 2

        def ell(name: str, c: F, ax: float, ay: float, az: float) -> body3d.Solid:
            axes = np.column_stack([u * ax, v * ay, down * az])
            return body3d.Solid("ellipsoid", 0, c, c, max(ax, ay, az), axes, name)

        body_c = centre - u * 0.05 * k - down * 0.12 * k
        head_c = centre + u * 0.3 * k - down * 0.15 * k
        tail_a = centre - u * 0.33 * k - down * 0.06 * k
        tail_b = tail_a - u * 0.12 * k + v * 0.1 * k - down * 0.03 * k
        return [
            ell("dog_body", body_c, 0.3 * k, half_w, 0.12 * k),
            ell("dog_head", head_c, 0.11 * k, 0.075 * k, 0.08 * k),
            ell("dog_snout", head_c + u * 0.1 * k + down * 0.02 * k, 0.06 * k, 0.04 * k, 0.04 * k),
            body3d.Solid("capsule", 0, tail_a, tail_b, 0.025 * k, np.eye(3), "dog_tail"),
        ]
    return []


@dataclass(frozen=True)
class Hits:
    """What each pixel's ray hits first (``Solids.trace``). owner: 0 none (the floor or
    nothing), k >= 1 body k-1, -k debris prism k-1, PROP_BASE + q warm-object part q."""

    owner: NDArray[np.int32]  # (H, W)
    depth_m: F  # (H, W) distance along the ray (the floor's where owner is 0)
    normal: NDArray[np.float32]  # (H, W, 3)
    material: NDArray[np.int8]  # (H, W) a body's material (body3d.SKIN ...), else 0


def _cone_rect(
    rays: F, oc: F, radius_m: float, window: tuple[int, int, int, int]
) -> tuple[int, int, int, int] | None:
    """The bounding pixel rectangle, inside ``window`` (x0, y0, x1, y1), of the rays that
    pass within radius_m of the point ``oc`` (relative to the camera), tested on every
    4th pixel and widened by 4."""
    x0, y0, x1, y1 = window
    dist2 = float(oc @ oc)
    along = rays[y0:y1:4, x0:x1:4] @ oc
    near = along * along >= dist2 - radius_m * radius_m
    if dist2 > radius_m * radius_m:
        near &= along > 0
    ys, xs = np.nonzero(near)
    if len(ys) == 0:
        return None
    h, w = rays.shape[:2]
    return (
        max(x0 + int(xs.min()) * 4 - 4, 0),
        max(y0 + int(ys.min()) * 4 - 4, 0),
        min(x0 + int(xs.max()) * 4 + 5, w),
        min(y0 + int(ys.max()) * 4 + 5, h),
    )


def _anchors(item: body3d.Solid | _Prism) -> tuple[F, float, F, float]:
    """Anchor points, their radius, and the bounding sphere of a solid or prism."""
    if isinstance(item, _Prism):
        return item.corners, 0.0, item.centre, item.radius_m
    centre, bound = item.bound()
    if item.kind == "capsule":
        return np.vstack([item.a, item.b]), item.radius_m, centre, bound
    return item.a[None, :], bound, centre, bound


class Solids:
    """The world's bodies and debris prisms, ready to draw. Built once per world."""

    def __init__(self, world: World, raster: FloorRaster | None, camera: CameraModel) -> None:
        """``raster``: the floor's paint, for the debris colour (None: ``trace`` only)."""
        self.world = world
        self.raster = raster
        self.camera = camera
        self.bodies = [v.body() for v in world.victims]
        self.looks = [v.look() for v in world.victims]
        self.victim_ids = tuple(v.victim_id for v in world.victims)
        prisms = [_prism(d, world.victims, self.bodies) for d in world.debris]
        # Thinner pieces (sheets, tarps, cables, paint) stay in the floor raster.
        keep = [i for i, pr in enumerate(prisms) if pr.top_m >= _SOLID_MIN_M]
        self.prisms = [prisms[i] for i in keep]
        self.prism_debris = [world.debris[i] for i in keep]  # the piece each prism draws
        # The solid warm objects' parts, and which object each part belongs to.
        self.props: list[body3d.Solid | _Prism] = []
        self.prop_object: list[int] = []
        for q, w in enumerate(world.warm_objects):
            parts = prop_parts(w)
            self.props += parts
            self.prop_object += [q] * len(parts)
        self._items: list[tuple[int, body3d.Solid | _Prism]] = []
        for k, body in enumerate(self.bodies, start=1):
            self._items += [(k, solid) for solid in body.solids]
        self._items += [(-k, pr) for k, pr in enumerate(self.prisms, start=1)]
        self._items += [(PROP_BASE + q, part) for q, part in enumerate(self.props)]
        self._anchors = [_anchors(it) for _, it in self._items]
        # Groups of items culled together when their bounding sphere is out of view: a
        # body's solids, each prism, each warm object's parts.
        groups: list[tuple[F, float, int]] = []
        for body in self.bodies:
            groups.append((body.centre, body.bound_radius_m, len(body.solids)))
        for pr in self.prisms:
            groups.append((pr.centre, pr.radius_m, 1))
        for part in self.props:
            _a, _r, centre, bound = _anchors(part)
            groups.append((centre, bound, 1))
        self._group_centres = np.array([g[0] for g in groups], float).reshape(-1, 3)
        self._group_radii = np.array([g[1] for g in groups], float)
        self._group_sizes = np.array([g[2] for g in groups], int)

    def _in_view(self, cam_centre: F, r_nc: F) -> NDArray[np.bool_]:
        """Per item: whether its group's bounding sphere may reach into the image."""
        k = self.camera.intrinsics
        rel = (self._group_centres - cam_centre) @ r_nc  # camera frame, z forward
        r = self._group_radii
        z = rel[:, 2]
        keep = z > -r
        far = z > r + 0.05  # wholly in front: test the sphere's image against the frame
        if far.any():
            uv = self.camera.project_camera(rel[far])
            dist = np.linalg.norm(rel[far], axis=1)
            zf = z[far]
            r_px = _CULL_MARGIN * max(k.fx_px, k.fy_px) * r[far] * dist / (zf * (zf - r[far]))
            inside = (
                (uv[:, 0] + r_px + 2 >= 0)
                & (uv[:, 0] - r_px - 2 <= k.width_px)
                & (uv[:, 1] + r_px + 2 >= 0)
                & (uv[:, 1] - r_px - 2 <= k.height_px)
            )
            keep[np.nonzero(far)[0][~inside]] = False
        return np.repeat(keep, self._group_sizes)

    def _rects(
        self, anchors: list[tuple[F, float, F, float]], cam_centre: F, r_nc: F, rays: F
    ) -> list[tuple[int, int, int, int] | None]:
        """The pixel rectangle (x0, y0, x1, y1) each item may cover, or None.

        An item is given as anchor points (K, 3) with a radius around each (the solid
        lies within those spheres' hull) and its bounding sphere (centre, radius).
        """
        k = self.camera.intrinsics
        f_px = max(k.fx_px, k.fy_px)
        counts = np.array([len(a) for a, _, _, _ in anchors])
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        radii = np.repeat(np.array([r for _, r, _, _ in anchors], float), counts)
        points = np.vstack([a for a, _, _, _ in anchors])
        rel = (points - cam_centre) @ r_nc  # camera frame
        safe = rel.copy()
        safe[:, 2] = np.maximum(safe[:, 2], 1e-3)
        uv = self.camera.project_camera(safe)
        z = rel[:, 2]
        # The image of a sphere at distance dist, depth z: within f r dist / (z (z - r)).
        dist = np.sqrt((rel * rel).sum(axis=1))
        with np.errstate(divide="ignore", invalid="ignore"):
            r_px = _CULL_MARGIN * f_px * radii * dist / (z * (z - radii)) + 2.0
        # Per item (numpy's reduceat over each item's anchors): rectangle and nearness.
        x0s = np.minimum.reduceat(uv[:, 0] - r_px, starts)
        x1s = np.maximum.reduceat(uv[:, 0] + r_px, starts)
        y0s = np.minimum.reduceat(uv[:, 1] - r_px, starts)
        y1s = np.maximum.reduceat(uv[:, 1] + r_px, starts)
        beside = np.logical_or.reduceat(z < radii + 0.02, starts)
        centres = np.array([c for _, _, c, _ in anchors], float)
        bounds = np.array([bd for _, _, _, bd in anchors], float)
        behind = (centres - cam_centre) @ r_nc[:, 2] < -bounds
        out: list[tuple[int, int, int, int] | None] = []
        for j, (_pts, radius, centre, bound) in enumerate(anchors):
            if behind[j]:
                out.append(None)  # behind the camera
            elif beside[j]:  # beside the camera
                full = (0, 0, k.width_px, k.height_px)
                out.append(_cone_rect(rays, centre - cam_centre, bound, full))
            else:
                x0 = max(int(x0s[j]), 0)
                x1 = min(int(x1s[j]) + 1, k.width_px)
                y0 = max(int(y0s[j]), 0)
                y1 = min(int(y1s[j]) + 1, k.height_px)
                if x0 >= x1 or y0 >= y1:
                    out.append(None)
                elif radius > 0:  # tighten a round solid's rectangle by its cone
                    out.append(_cone_rect(rays, centre - cam_centre, bound, (x0, y0, x1, y1)))
                else:
                    out.append((x0, y0, x1, y1))
        return out

    def trace(self, depth_m: np.ndarray, cam_centre: F, r_nc: F, rays: F) -> Hits:
        """The first hit of every ray among the bodies, debris prisms and warm objects,
        nearer than the floor. ``depth_m``: the floor's distance along each ray (inf
        off the floor), (H, W); ``rays``: unit NED rays (H, W, 3)."""
        h, w = depth_m.shape
        depth = depth_m.astype(np.float64)
        owner = np.zeros((h, w), np.int32)
        normal = np.zeros((h, w, 3), np.float32)
        material = np.zeros((h, w), np.int8)
        if not self._items:
            return Hits(owner, depth, normal, material)
        live = np.nonzero(self._in_view(cam_centre, r_nc))[0]
        if len(live) == 0:
            return Hits(owner, depth, normal, material)
        rects = self._rects([self._anchors[i] for i in live], cam_centre, r_nc, rays)
        for i, rect in zip(live, rects, strict=True):
            item_id, item = self._items[i]
            if rect is None:
                continue
            x0, y0, x1, y1 = rect
            rect_rays = rays[y0:y1, x0:x1].reshape(-1, 3)
            if isinstance(item, body3d.Solid):
                t_hit, nrm = item.intersect(cam_centre, rect_rays)
            else:
                t_hit, nrm = shapes.prism(cam_centre, rect_rays, item.planes)
            t_rect = t_hit.reshape(y1 - y0, x1 - x0)
            closer = t_rect < depth[y0:y1, x0:x1]
            if not closer.any():
                continue
            depth[y0:y1, x0:x1][closer] = t_rect[closer]
            owner[y0:y1, x0:x1][closer] = item_id
            normal[y0:y1, x0:x1][closer] = nrm.reshape(y1 - y0, x1 - x0, 3)[closer]
            if isinstance(item, body3d.Solid):
                material[y0:y1, x0:x1][closer] = item.material
        return Hits(owner, depth, normal, material)

    def draw(
        self,
        signal: np.ndarray,
        depth_m: np.ndarray,
        cam_centre: F,
        r_nc: F,
        rays: F,
        headlight: float,
    ) -> dict[int, int]:
        """Draw over ``signal`` (H, W, 3 float, 0..1) in place; visible pixels per victim.

        ``depth_m``: the floor's distance along each ray (inf off the floor), (H, W).
        ``rays``: unit NED rays (H, W, 3).
        """
        hits = self.trace(depth_m, cam_centre, r_nc, rays)
        hit = np.nonzero(hits.owner.ravel())[0]
        if len(hit) == 0:
            return {}
        t = hits.depth_m.ravel()[hit]
        d = rays.reshape(-1, 3)[hit]
        p = cam_centre + d * t[:, None]
        albedo = np.empty((len(hit), 3))
        who = hits.owner.ravel()[hit]
        mat = hits.material.ravel()[hit]
        for k, body in enumerate(self.bodies, start=1):
            m = who == k
            if m.any():
                albedo[m] = body3d.paint(body, self.looks[k - 1], p[m], mat[m])
        debris = who < 0
        if debris.any():
            albedo[debris] = self._debris_colour(p[debris])
        prop = who >= PROP_BASE
        if prop.any():
            colours = np.array(
                [self.world.warm_objects[q].colour_rgb[::-1] for q in self.prop_object], float
            )
            albedo[prop] = colours[who[prop] - PROP_BASE]
        n = hits.normal.reshape(-1, 3)[hit].astype(np.float64)
        zone = self.world.light_at(p[:, 0], p[:, 1])
        sky = _SKY + (1.0 - _SKY) * np.clip(-n[:, 2], 0.0, 1.0)
        facing = np.clip(-(n * d).sum(axis=1), 0.0, 1.0)
        light = zone * sky + headlight * facing * np.minimum(1.0, 1.0 / np.square(t))
        flat = signal.reshape(-1, 3)
        flat[hit] = (albedo * (light / 255.0)[:, None]).astype(np.float32)
        body_px = who[(who > 0) & (who < PROP_BASE)]
        counts = np.bincount(body_px, minlength=len(self.bodies) + 1)
        return {
            vid: int(counts[k]) for k, vid in enumerate(self.victim_ids, start=1) if counts[k] > 0
        }

    def _debris_colour(self, p: F) -> F:
        """The debris surface colour: the floor raster's paint at the point's footprint."""
        if self.raster is None:
            raise ValueError("Solids built without a floor raster cannot draw")
        res = self.raster.res_m
        rows, cols = self.raster.bgrl.shape[:2]
        r = np.clip((p[:, 0] / res).astype(int), 0, rows - 1)
        c = np.clip((p[:, 1] / res).astype(int), 0, cols - 1)
        colour = self.raster.bgrl[r, c, :3].astype(np.float64)
        # Side faces show the piece's grain in the vertical (height) as well.
        return colour * (0.9 + 0.1 * np.sin(-p[:, 2] * 60.0))[:, None]
