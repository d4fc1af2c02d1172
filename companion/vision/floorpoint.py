"""Where a body the person models found lies on the floor: its floor point.

Not the image centroid of its mask, which sits above the floor and projects short.
From a camera 0.3 m up every centimetre of height error moves a floor point by
range / 0.3 centimetres, so the point comes from where the body meets the floor:

- a lying body with landmarks: the lowest mask pixel of each column is where its
  near side meets the floor (``contact_height_m`` up); the footprint's centre lies
  beyond that near edge, along the view, by half the body's extent in that
  direction (``_near_edge``, ``_beyond_edge``). Where the frame cuts that edge, the mean of its
  joints taken to a plane ``joint_height_m`` above the floor. Where fewer than half
  its joints meet that plane in view (the frame cuts the body, or the pose's
  attitude puts it above the horizon), the joints tell neither its extent nor its
  axis: the near edge and half a body's width. So too where the body is mostly
  hidden (the heatmaps see at most half its main joints, or its mask covers less
  than half of what a whole lying adult would there): the rest of it may go on
  beyond what shows on any side, towards the camera too (under a slab, behind a
  wall), and the joints there are the model's guesses;
- a standing body (its nose more than ``standing_height_m`` above its ankles at the
  ankles' range): its ankles;
- a lone hand or face: where its box meets the floor;
- a body without landmarks: the same near edge with half a body's width, else the
  person detector's hip centre at joint height.

``floor_pixel`` returns the pixel of that point, for the geolocation, and the
body's heading where its landmarks show it lying.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from companion.vision.base import FrameGeometry

N_BODY_POINTS = 33
# BlazePose indices: nose 0, shoulders 11/12, hips 23/24, knees 25/26, ankles 27/28.
SHOULDERS, HIPS, KNEES, ANKLES = (11, 12), (23, 24), (25, 26), (27, 28)


@dataclass(frozen=True)
class FloorParams:
    joint_height_m: float = 0.10  # a lying adult's joints above the floor
    contact_height_m: float = 0.03  # where a lying body's near side leaves the floor
    body_width_m: float = 0.35  # a lying adult across the view (shoulders, hips)
    max_half_extent_m: float = 0.9  # half a lying adult's length
    joint_span_m: float = 1.45  # nose to ankles of a lying adult
    landmark_seen: float = 0.5  # a landmark counts as in sight from this visibility
    standing_height_m: float = 1.0  # nose this far above the ankles: standing
    # The joints' span tells a lying body's extent beyond its near edge only when most
    # of the body is seen: the heatmaps see more than this share of its main joints
    # (the rest are the model's guesses) ...
    extent_min_seen_share: float = 0.5
    # ... and its mask covers at least this share of the area a whole lying adult
    # would cover there.
    extent_min_visible: float = 0.5


class BodyLike(Protocol):
    """What the floor point needs of a body (people_bodies.Body)."""

    mask: np.ndarray  # bool, visible body pixels
    points: np.ndarray | None  # (33, 2) landmarks in frame pixels, when trusted
    seen: np.ndarray | None  # (33,) each landmark's visibility, 0..1
    hip_px: np.ndarray  # (2,) hip centre
    box: tuple[float, float, float, float]  # x0, y0, x1, y1
    part: str  # "face" / "hand" for a lone part
    seen_share: float | None  # share of its main joints the heatmaps see (seenparts.py)


class FloorPixel(NamedTuple):
    """Where a body lies, as a pixel of the floor, with what the joints tell of it."""

    u_px: float  # the pixel of the body's floor point
    v_px: float
    heading_rad: float | None  # NED yaw, feet to head, where its landmarks show it lying
    # A mostly hidden body is placed where it shows; its visibility is still judged
    # against the whole body its joints describe, centred here (None: at u, v).
    whole_uv_px: tuple[float, float] | None = None


def floor_pixel(
    b: BodyLike, geometry: FrameGeometry | None, p: FloorParams, w: int, h: int
) -> FloorPixel:
    """The pixel of the body's floor point (see the module docstring), and the
    body's heading where its landmarks show it lying."""
    heading = None
    x0, _y0, x1, y1 = b.box
    if geometry is None:
        if b.points is not None:
            u = float(np.clip(b.points[:, 0].mean(), 0, w - 1))
            return FloorPixel(u, float(np.clip(y1 - 1, 0, h - 1)), None)
        return FloorPixel((x0 + x1) / 2, min(y1, h) - 0.5, None)
    centre = np.array([np.nan, np.nan])
    whole_uv = None
    if b.points is not None:
        joints = geometry.plane_ne_m(b.points, p.joint_height_m)
        finite = joints[np.all(np.isfinite(joints), axis=1)]
        if not _standing(b.points, geometry, p):
            # Lying. Where most joints miss the floor in view (a body cut by the frame,
            # or seen above the horizon the pose gives), they tell neither its heading
            # nor its extent: its near edge and half a body's width do.
            enough = len(finite) >= N_BODY_POINTS // 2
            if enough:
                heading = _heading(b, joints, p)
            contact = _near_edge(b.mask, geometry, h, p)
            centre = _beyond_edge(contact, finite if enough else None, p)
            # A body mostly hidden (under debris, behind a wall) may go on beyond what
            # shows on any side, towards the camera too: it is placed where it shows.
            guessed = b.seen_share is not None and b.seen_share <= p.extent_min_seen_share
            if enough:
                whole_uv = _pixel(geometry, centre)
                if guessed or _mostly_hidden(b, geometry, whole_uv, heading, p):
                    centre = _beyond_edge(contact, None, p)
                else:
                    whole_uv = None  # placed as the whole body: no other reference
            if not np.all(np.isfinite(centre)) and enough:
                centre = finite.mean(axis=0)
        else:
            feet = geometry.floor_ne_m(b.points[list(ANKLES)])
            feet = feet[np.all(np.isfinite(feet), axis=1)]
            if len(feet):
                centre = feet.mean(axis=0)
    elif b.part:
        centre = geometry.floor_ne_m(np.array([[(x0 + x1) / 2, min(y1, h) - 0.5]]))[0]
    else:
        centre = _beyond_edge(_near_edge(b.mask, geometry, h, p), None, p)
        if not np.all(np.isfinite(centre)):
            centre = geometry.plane_ne_m(b.hip_px.reshape(1, 2), p.joint_height_m)[0]
    uv = _pixel(geometry, centre)
    if uv is None:
        return FloorPixel((x0 + x1) / 2, min(y1, h) - 0.5, heading)
    return FloorPixel(uv[0], uv[1], heading, whole_uv)


def _pixel(geometry: FrameGeometry, ne_m: np.ndarray) -> tuple[float, float] | None:
    """The pixel of a floor point; None where it has none."""
    if not np.all(np.isfinite(ne_m)):
        return None
    px = geometry.pixels_of_floor(ne_m.reshape(1, 2))
    if px is None or not np.all(np.isfinite(px[0])):
        return None
    return float(px[0, 0]), float(px[0, 1])


def _heading(b: BodyLike, joints_ne: np.ndarray, p: FloorParams) -> float | None:
    """The body's axis (NED yaw, feet to head) from the first pair of body points
    that are both in sight: nose-ankles, shoulders-hips, hips-ankles. The model
    places hidden (buried) points by guesswork, so those are never used."""
    if b.seen is None:
        return None
    seen = b.seen >= p.landmark_seen
    for head_end, foot_end in (((0,), ANKLES), (SHOULDERS, HIPS), (HIPS, ANKLES)):
        idx = [*head_end, *foot_end]
        if not (np.all(seen[idx]) and np.all(np.isfinite(joints_ne[idx]))):
            continue
        d_ne = joints_ne[list(head_end)].mean(axis=0) - joints_ne[list(foot_end)].mean(axis=0)
        if float(np.hypot(*d_ne)) > 1e-3:
            return math.atan2(float(d_ne[1]), float(d_ne[0]))
    return None


def _mostly_hidden(
    b: BodyLike,
    geometry: FrameGeometry,
    uv: tuple[float, float] | None,
    heading: float | None,
    p: FloorParams,
) -> bool:
    """Whether the body's mask covers less than ``extent_min_visible`` of the area a
    whole lying adult centred at pixel ``uv`` of the floor would cover in the frame."""
    if uv is None:
        return False
    expected = geometry.expected_body_area_px(uv[0], uv[1], heading)
    return expected is not None and float(b.mask.sum()) < p.extent_min_visible * expected


def _standing(points: np.ndarray, geometry: FrameGeometry, p: FloorParams) -> bool:
    """Whether the body stands: its nose stands higher above its ankles than
    ``standing_height_m``, measured at the ankles' range (a pixel across the view
    there spans range / focal length metres, on the floor as upright)."""
    ankles = points[list(ANKLES)].mean(axis=0)
    both = geometry.floor_ne_m(np.vstack([ankles, ankles + np.array([1.0, 0.0])]))
    if not np.all(np.isfinite(both)):
        return False  # the feet are not on the usable floor in view
    metres_per_px = float(np.hypot(*(both[1] - both[0])))
    upright_m = float(ankles[1] - points[0, 1]) * metres_per_px
    return upright_m > p.standing_height_m


def blob_floor_pixel(
    mask: np.ndarray, geometry: FrameGeometry, part: bool, p: FloorParams
) -> tuple[float, float] | None:
    """The floor point's pixel of a body seen as a region without landmarks (the
    thermal camera's warm groups): its near edge and half a body's width beyond it,
    or for a lone part (a hand, a face) where its region meets the floor. None where
    the region has no near edge in view (its bottom cut by the frame) or no floor."""
    h = mask.shape[0]
    if part:
        ys, xs = np.nonzero(mask)
        if len(xs) == 0:
            return None
        bottom = float(min(int(ys.max()) + 1, h)) - 0.5
        centre = geometry.floor_ne_m(np.array([[float(xs.mean()) + 0.5, bottom]]))[0]
    else:
        centre = _beyond_edge(_near_edge(mask, geometry, h, p), None, p)
    return _pixel(geometry, centre)


def _near_edge(
    mask: np.ndarray, geometry: FrameGeometry, h: int, p: FloorParams
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the body meets the floor: its near edge and the unit view direction
    there (both NE metres), or None when the mask's bottom is cut by the frame.

    From a low camera a joint's height above the floor is uncertain, and every
    centimetre of it moves a ray's floor point by range / camera height
    centimetres. The lowest mask pixel of each column is where the body's near
    side meets the floor (``contact_height_m`` up): exact whatever the body's
    height.
    """
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    bottom = np.full(int(xs.max()) + 1, -1)
    np.maximum.at(bottom, xs, ys)
    cols = np.nonzero(bottom >= 0)[0]
    rows = bottom[cols]
    keep = rows < h - 2  # a column running off the frame has no contact in view
    if keep.sum() < max(3, 0.5 * len(cols)):
        return None
    pix = np.column_stack([cols[keep] + 0.5, rows[keep] + 0.5]).astype(np.float64)
    near = geometry.plane_ne_m(pix, p.contact_height_m)
    nearer = geometry.plane_ne_m(pix + np.array([0.0, 40.0]), p.contact_height_m)
    ok = np.all(np.isfinite(near), axis=1) & np.all(np.isfinite(nearer), axis=1)
    if ok.sum() < 3:
        return None
    edge = np.median(near[ok], axis=0)
    view = np.median(near[ok] - nearer[ok], axis=0)
    norm = float(np.hypot(*view))
    if norm < 1e-6:
        return None
    return edge, view / norm


def _beyond_edge(
    contact: tuple[np.ndarray, np.ndarray] | None, joints_ne: np.ndarray | None, p: FloorParams
) -> np.ndarray:
    """The footprint's centre: beyond the near edge (``_near_edge``), along the
    view, by half the body's extent in that direction (from its joints' footprint
    when given, else half a lying body's width). NaN without a near edge."""
    if contact is None:
        return np.array([np.nan, np.nan])
    edge, view = contact
    if joints_ne is not None and len(joints_ne) >= 2:
        # Across the view the joints' footprint is true to scale (unlike along it);
        # a body of joint span S that spans A across the view spans sqrt(S^2 - A^2)
        # along it.
        across = (joints_ne - joints_ne.mean(axis=0)) @ np.array([-view[1], view[0]])
        span = float(across.max() - across.min())
        along = math.sqrt(max(p.joint_span_m**2 - span**2, 0.0))
        half = 0.5 * along + 0.5 * p.body_width_m
    else:
        half = 0.5 * p.body_width_m
    return np.asarray(edge + view * min(half, p.max_half_extent_m), dtype=np.float64)
