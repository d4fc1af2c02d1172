"""Pixels to floor points in local NED, with an honest 2x2 covariance.

A detection's floor-contact pixel becomes a ray in the camera frame (distortion
removed), is turned into NED through the camera mount and the vehicle's attitude,
and starts at the camera's centre (vehicle position plus the rotated mount offset).
Its intersection with the level floor plane ``down = pose.down_m + floor_down_m``
is the victim's position. Rays that point at or above the horizon, or hit the floor
outside [min_range_m, max_range_m] from the camera, are rejected with a reason.

Covariance, first order: with p(u, v, roll, pitch, yaw) the floor point,

    C = J_px diag(s_px^2) J_px^T + J_att diag(s_att^2) J_att^T + s_pos^2 I

where the Jacobians are central differences. Horizontal position noise moves the
point one to one. Vertical position noise does not enter: the floor is placed
relative to the vehicle, whose height above it is known from the mount.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fusion.camera import CameraModel, FloatArray, rotation_zyx
from fusion.errors import GeolocationRejected
from fusion.params import GeolocationParams
from fusion.types import Cov2, PoseSample

_PIXEL_STEP_PX = 0.01  # central-difference steps: small against the noise they model
_ANGLE_STEP_RAD = 1e-6
_MIN_DOWN_COMPONENT = 1e-9  # a ray must descend at least this much per metre
_Z_NEAR_M = 0.01  # body outlines are clipped to this distance in front of the camera
_BODY_HEADINGS = 12  # headings averaged for the expected body area (over 180 degrees)


@dataclass(frozen=True)
class FloorFix:
    """A geolocated floor point and its uncertainty."""

    north_m: float
    east_m: float
    down_m: float
    cov_ne_m2: Cov2
    range_m: float  # camera centre to the floor point


def _vehicle(pose: PoseSample) -> FloatArray:
    return np.array([pose.north_m, pose.east_m, pose.down_m])


def _floor_down(pose: PoseSample, params: GeolocationParams) -> float:
    return pose.down_m + params.floor_down_m


def _intersect(
    centres: FloatArray, dirs: FloatArray, floor_down_m: float
) -> tuple[FloatArray, FloatArray]:
    """Floor points (K, 3) and ranges (K,) of rays centres + t * dirs (unit dirs).

    t = (floor - c_d) / d_d; rows that do not descend onto the floor get t = nan.
    """
    above = floor_down_m - centres[:, 2]
    descends = (dirs[:, 2] > _MIN_DOWN_COMPONENT) & (above > 0.0)
    t = np.where(descends, above / np.where(descends, dirs[:, 2], 1.0), np.nan)
    return centres + t[:, None] * dirs, t


def _rays(
    camera: CameraModel, pose: PoseSample, pixels: FloatArray, attitudes: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Camera centres and unit NED rays for pixel rows paired with attitude rows."""
    rays_cam = camera.rays_camera(pixels)
    r_body_cam = camera.mount.r_body_from_camera
    vehicle = _vehicle(pose)
    centres = np.empty((len(pixels), 3))
    dirs = np.empty((len(pixels), 3))
    for k, (roll, pitch, yaw) in enumerate(attitudes):
        r_ned_body = rotation_zyx(roll, pitch, yaw)
        centres[k] = vehicle + r_ned_body @ camera.mount.position_body_m
        dirs[k] = r_ned_body @ r_body_cam @ rays_cam[k]
    return centres, dirs


def _check_hit(
    centre: FloatArray, direction: FloatArray, range_m: float, params: GeolocationParams
) -> None:
    if not math.isfinite(range_m):
        if direction[2] <= _MIN_DOWN_COMPONENT:
            elevation = math.degrees(math.asin(max(-1.0, min(1.0, -direction[2]))))
            raise GeolocationRejected(
                "ray does not hit the floor in front of the camera "
                f"(it points {elevation:.1f} deg above the horizon)"
            )
        raise GeolocationRejected("the camera is at or below the floor plane")
    if range_m > params.max_range_m:
        raise GeolocationRejected(f"beyond max_range_m {params.max_range_m}: {range_m:.1f} m")
    if range_m < params.min_range_m:
        raise GeolocationRejected(f"nearer than min_range_m {params.min_range_m}: {range_m:.2f} m")


def _perturbed(pose: PoseSample, u_px: float, v_px: float) -> tuple[FloatArray, FloatArray]:
    """Rows: nominal, u+-h, v+-h, roll+-h, pitch+-h, yaw+-h (pixels, attitudes)."""
    hp, ha = _PIXEL_STEP_PX, _ANGLE_STEP_RAD
    pixel_steps = [(0, 0), (hp, 0), (-hp, 0), (0, hp), (0, -hp)] + [(0, 0)] * 6
    pixels = np.array([(u_px + du, v_px + dv) for du, dv in pixel_steps])
    att0 = np.array([pose.roll_rad, pose.pitch_rad, pose.yaw_rad])
    attitudes = np.tile(att0, (11, 1))
    for axis in range(3):
        attitudes[5 + 2 * axis, axis] += ha
        attitudes[6 + 2 * axis, axis] -= ha
    return pixels, attitudes


def _jacobians(
    camera: CameraModel, pose: PoseSample, u_px: float, v_px: float, params: GeolocationParams
) -> tuple[FloatArray, float, FloatArray, FloatArray, FloatArray]:
    """The floor point, its range, d(n, e)/d(u, v), d(n, e)/d(roll, pitch, yaw) and
    the ray's direction (NED)."""
    if not (math.isfinite(u_px) and math.isfinite(v_px)):
        raise GeolocationRejected(f"pixel ({u_px!r}, {v_px!r}) is not finite")
    pixels, attitudes = _perturbed(pose, u_px, v_px)
    centres, dirs = _rays(camera, pose, pixels, attitudes)
    points, ranges = _intersect(centres, dirs, _floor_down(pose, params))
    _check_hit(centres[0], dirs[0], float(ranges[0]), params)
    if not np.all(np.isfinite(ranges)):
        raise GeolocationRejected("ray grazes the horizon: no usable covariance")
    ne = points[:, :2]
    # d p / d q ~= (p(q + h) - p(q - h)) / 2h, column per input.
    j_px = np.column_stack([ne[1] - ne[2], ne[3] - ne[4]]) / (2.0 * _PIXEL_STEP_PX)
    j_att = np.column_stack([ne[5] - ne[6], ne[7] - ne[8], ne[9] - ne[10]]) / (
        2.0 * _ANGLE_STEP_RAD
    )
    return points[0], float(ranges[0]), j_px, j_att, dirs[0]


def geolocate(
    camera: CameraModel,
    pose: PoseSample,
    u_px: float,
    v_px: float,
    params: GeolocationParams,
    cut_by_frame: bool = False,
) -> FloorFix:
    """The floor point seen at pixel (u_px, v_px) from ``pose``, with its covariance.

    ``cut_by_frame``: the point is a body's, and the frame's left or right edge cuts
    that body. Its centre may then lie beyond what shows, on the far side of the
    frame's side plane, which holds the ray: the covariance grows across the ray (on
    the floor) by ``params.frame_cut_sigma_m`` (1-sigma)."""
    point, range_m, j_px, j_att, ray = _jacobians(camera, pose, u_px, v_px, params)
    s_px2 = params.pixel_sigma_px**2
    s_att2 = math.radians(params.attitude_sigma_deg) ** 2
    # C = s_px^2 J_px J_px^T + s_att^2 J_att J_att^T + s_pos^2 I
    cov = s_px2 * j_px @ j_px.T + s_att2 * j_att @ j_att.T
    cov += params.position_sigma_m**2 * np.eye(2)
    if cut_by_frame:
        across = np.array([-ray[1], ray[0]]) / max(float(np.hypot(ray[0], ray[1])), 1e-12)
        cov += params.frame_cut_sigma_m**2 * np.outer(across, across)
    cov = 0.5 * (cov + cov.T)
    if np.linalg.det(cov) <= 0.0:
        raise GeolocationRejected("degenerate covariance (all noise sigmas are zero?)")
    cov2: Cov2 = ((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1])))
    return FloorFix(float(point[0]), float(point[1]), float(point[2]), cov2, range_m)


def ground_sample_distance_m(
    camera: CameraModel, pose: PoseSample, u_px: float, v_px: float, params: GeolocationParams
) -> float:
    """Metres of floor per pixel at (u_px, v_px): geometric mean of the floor lengths
    of one pixel step along u and one along v."""
    _point, _range_m, j_px, _j_att, _ray = _jacobians(camera, pose, u_px, v_px, params)
    return math.sqrt(float(np.linalg.norm(j_px[:, 0]) * np.linalg.norm(j_px[:, 1])))


def ground_sample_distances_m(
    camera: CameraModel, pose: PoseSample, pixels: FloatArray, params: GeolocationParams
) -> FloatArray:
    """``ground_sample_distance_m`` of many pixels (N, 2) at once, NaN where it would
    reject the pixel: the same rays, perturbations (``_perturbed``) and checks, in one
    pass (a frame's far-band search asks for 60 rows; one at a time they took 25 ms)."""
    px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    n = len(px)
    if n == 0:
        return np.zeros(0)
    steps, attitudes = _perturbed(pose, 0.0, 0.0)
    # The pixel steps (rows 0-4) are taken at the pose; each attitude step (rows 5-10)
    # at the pixel itself.
    stepped = (px[:, None, :] + steps[None, :5, :]).reshape(-1, 2)  # (5N, 2), pixel-major
    rays_cam = camera.rays_camera(stepped).reshape(n, 5, 3)
    vehicle = _vehicle(pose)
    floor_down = _floor_down(pose, params)
    ne = np.empty((n, 11, 2))
    ranges = np.empty((n, 11))
    for k in (0, *range(5, 11)):
        r_ned_body = rotation_zyx(*attitudes[k])
        centre = vehicle + r_ned_body @ camera.mount.position_body_m
        r_ned_cam = r_ned_body @ camera.mount.r_body_from_camera
        rows = rays_cam if k == 0 else rays_cam[:, :1]
        dirs = (r_ned_cam[None, None] @ rows[..., None])[..., 0]
        flat = dirs.reshape(-1, 3)
        points, t = _intersect(np.broadcast_to(centre, flat.shape), flat, floor_down)
        cols = slice(0, 5) if k == 0 else slice(k, k + 1)
        ne[:, cols] = points[:, :2].reshape(n, -1, 2)
        ranges[:, cols] = t.reshape(n, -1)
    nominal = ranges[:, 0]
    ok = np.isfinite(ranges).all(axis=1)
    ok &= (nominal <= params.max_range_m) & (nominal >= params.min_range_m)
    ju = (ne[:, 1] - ne[:, 2]) / (2.0 * _PIXEL_STEP_PX)
    jv = (ne[:, 3] - ne[:, 4]) / (2.0 * _PIXEL_STEP_PX)
    gsd = np.sqrt(np.linalg.norm(ju, axis=1) * np.linalg.norm(jv, axis=1))
    return np.where(ok, gsd, np.nan)


def _camera_frame(camera: CameraModel, pose: PoseSample, points_ned: FloatArray) -> FloatArray:
    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    centre, r_ned_cam = camera.camera_pose_ned(_vehicle(pose), r_ned_body)
    return (points_ned - centre) @ r_ned_cam  # rows of R^T (p - c)


@functools.lru_cache(maxsize=8)
def _image_bounds(camera: CameraModel) -> tuple[float, float, float, float]:
    """The image rectangle in normalized undistorted coordinates (x0, x1, y0, y1):
    the median of each edge, undistorted (exact without distortion)."""
    k = camera.intrinsics
    lo_u, hi_u, lo_v, hi_v = -0.5, k.width_px - 0.5, -0.5, k.height_px - 0.5
    along_u = np.linspace(lo_u, hi_u, 9)
    along_v = np.linspace(lo_v, hi_v, 9)
    edges = []
    for pixels in (
        np.column_stack([np.full(9, lo_u), along_v]),
        np.column_stack([np.full(9, hi_u), along_v]),
        np.column_stack([along_u, np.full(9, lo_v)]),
        np.column_stack([along_u, np.full(9, hi_v)]),
    ):
        rays = camera.rays_camera(pixels)
        edges.append(rays[:, :2] / rays[:, 2:3])
    return (
        float(np.median(edges[0][:, 0])),
        float(np.median(edges[1][:, 0])),
        float(np.median(edges[2][:, 1])),
        float(np.median(edges[3][:, 1])),
    )


# A box's 12 edges as pairs of corner indices of _box_vertices' corners (0-3 on its
# bottom, 4-7 above them).
_BOX_EDGES = np.array(
    [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
)
_EPS_M = 1e-9  # on a plane, within rounding


def _view_planes(
    bounds: tuple[float, float, float, float] | None,
) -> tuple[FloatArray, FloatArray]:
    """The view's half-spaces n . p >= offset in the camera frame: the near plane
    and, given image bounds, the frustum's four sides (x0 z <= x <= x1 z, ...)."""
    normals = [(0.0, 0.0, 1.0)]
    if bounds is not None:
        x0, x1, y0, y1 = bounds
        normals += [(1.0, 0.0, -x0), (-1.0, 0.0, x1), (0.0, 1.0, -y0), (0.0, -1.0, y1)]
    offsets = [_Z_NEAR_M] + [0.0] * (len(normals) - 1)
    return np.array(normals), np.array(offsets)


def _view_edges(bounds: tuple[float, float, float, float] | None) -> list[FloatArray]:
    """The frustum's edges as segments (2, 3) in the camera frame: its four side
    edges from the near plane out to far beyond any body, and the near rectangle's."""
    if bounds is None:
        return []
    x0, x1, y0, y1 = bounds
    near = [np.array([x, y, 1.0]) * _Z_NEAR_M for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1))]
    far = [c * (1e4 / _Z_NEAR_M) for c in near]
    return [np.array([near[i], far[i]]) for i in range(4)] + [
        np.array([near[i], near[(i + 1) % 4]]) for i in range(4)
    ]


def _box_vertices(
    camera: CameraModel,
    pose: PoseSample,
    north_m: float,
    east_m: float,
    params: GeolocationParams,
    headings: list[float],
    bounds: tuple[float, float, float, float] | None,
) -> list[FloatArray]:
    """Per heading, the vertices (K, 3) in the camera frame of the part of a lying
    body's box (on the floor at north/east, along that heading) inside the view:
    its corners in view, its edges' crossings of the view's sides and the view's
    edges' crossings of its faces. Perspective keeps convexity, so the silhouette of
    what the frame shows of the box is the convex hull of these vertices' images."""
    floor = _floor_down(pose, params)
    height = params.body_height_m
    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    centre, r_ned_cam = camera.camera_pose_ned(_vehicle(pose), r_ned_body)
    h = np.asarray(headings)
    zeros, ones = np.zeros_like(h), np.ones_like(h)
    along = np.stack([np.cos(h), np.sin(h), zeros], axis=1)  # (H, 3) in NED
    across = np.stack([-np.sin(h), np.cos(h), zeros], axis=1)
    down = np.stack([zeros, zeros, ones], axis=1)
    box_centre = np.array([north_m, east_m, floor - height / 2])
    half = (params.body_length_m / 2, params.body_width_m / 2, height / 2)
    signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], float)
    ne = (
        signs[None, :, :1] * half[0] * along[:, None, :]
        + signs[None, :, 1:] * half[1] * across[:, None, :]
    )  # (H, 4, 3)
    corners_ned = np.concatenate([ne + half[2] * down[:, None], ne - half[2] * down[:, None]], 1)
    corners = (corners_ned + box_centre - centre) @ r_ned_cam  # (H, 8, 3) in the camera frame
    # The box's six faces as outward half-spaces n . p <= offset in the camera frame.
    axes = np.stack([along, -along, across, -across, down, -down], axis=1)  # (H, 6, 3)
    box_n = axes @ r_ned_cam
    box_off = np.repeat(np.array(half), 2)[None, :] + axes @ (box_centre - centre)
    view_n, view_off = _view_planes(bounds)

    def in_view(points: FloatArray) -> NDArray[np.bool_]:
        return np.asarray((points @ view_n.T - view_off >= -_EPS_M).all(axis=-1))

    def in_box(points: FloatArray) -> NDArray[np.bool_]:  # points (H, M, 3)
        return (np.einsum("hmk,hfk->hmf", points, box_n) <= box_off[:, None, :] + _EPS_M).all(-1)

    # the box's edges crossing the view's planes
    a, b = corners[:, _BOX_EDGES[:, 0]], corners[:, _BOX_EDGES[:, 1]]  # (H, 12, 3)
    fa, fb = a @ view_n.T - view_off, b @ view_n.T - view_off  # (H, 12, P)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = fa / (fa - fb)
    crossing = (fa >= 0.0) != (fb >= 0.0)
    s = np.where(crossing, s, np.nan)
    cuts = (a[:, :, None] + s[..., None] * (b - a)[:, :, None]).reshape(len(h), -1, 3)
    found = [corners, cuts]
    # the view's edges crossing the box's faces
    for seg in _view_edges(bounds):
        p0, d = seg[0], seg[1] - seg[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (box_off - box_n @ p0) / (box_n @ d)  # (H, 6)
        t = np.where((t >= 0.0) & (t <= 1.0), t, np.nan)
        found.append(p0 + t[..., None] * d)
    points = np.concatenate(found, axis=1)  # (H, M, 3), nan rows where nothing crosses
    ok = np.isfinite(points).all(-1)
    safe = np.where(ok[..., None], points, 0.0)
    ok &= in_view(safe) & in_box(safe)
    return [points[i][ok[i]] for i in range(len(h))]


def _hull_area(points: FloatArray) -> float:
    """Area of the convex hull (Andrew's monotone chain) of (N, 2) points."""
    pts = sorted(set(map(tuple, np.round(points, 12).tolist())))
    if len(pts) < 3:
        return 0.0

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for p in seq:
            while (
                len(out) >= 2
                and (
                    (out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                    - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])
                )
                <= 0
            ):
                out.pop()
            out.append(p)
        return out

    hull = half(pts)[:-1] + half(pts[::-1])[:-1]
    twice = sum(
        x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(hull, hull[1:] + hull[:1], strict=True)
    )
    return 0.5 * abs(twice)


def _distortion_area_scale(camera: CameraModel, xy: FloatArray) -> float:
    """|det d(distorted)/d(undistorted)| at normalized point xy: local area scale."""
    h = 1e-6
    steps = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    pts = xy[None, :] + steps
    d = camera.distort_normalized(pts)
    jac = np.column_stack([d[0] - d[1], d[2] - d[3]]) / (2.0 * h)
    return abs(float(np.linalg.det(jac)))


def expected_body_area_px(
    camera: CameraModel,
    pose: PoseSample,
    north_m: float,
    east_m: float,
    params: GeolocationParams,
    clip_to_image: bool = True,
    heading_rad: float | None = None,
) -> float:
    """Image area (px^2) a whole, unburied lying adult centred on this floor point covers.

    The body is a body_length_m x body_width_m x body_height_m box on the floor (from
    a low camera a lying body shows its side, not only its footprint): the area is
    its silhouette, the convex hull of its faces. Lying along ``heading_rad`` when
    given; otherwise the heading is unknown and the area is the mean over headings
    spread across 180 degrees. With
    ``clip_to_image`` (the default) the outline is clipped to the image, so the area
    is what the frame could show of that body: near the camera a body is larger than
    the frame, and a visibility of mask area / this value then measures burial, not
    framing. Without it, only the part behind the camera is clipped away. The pinhole
    area is scaled by the lens distortion's local area factor at the centre.
    Raises GeolocationRejected when the point is not in front of the camera.
    """
    floor = _floor_down(pose, params)
    centre_cam = _camera_frame(camera, pose, np.array([[north_m, east_m, floor]]))[0]
    if centre_cam[2] <= _Z_NEAR_M:
        raise GeolocationRejected(
            f"floor point ({north_m:.2f}, {east_m:.2f}) is not in front of the camera"
        )
    k = camera.intrinsics
    bounds = _image_bounds(camera) if clip_to_image else None
    areas = []
    headings = (
        [math.pi * i / _BODY_HEADINGS for i in range(_BODY_HEADINGS)]
        if heading_rad is None
        else [heading_rad]
    )
    for vertices in _box_vertices(camera, pose, north_m, east_m, params, headings, bounds):
        if len(vertices) < 3:
            areas.append(0.0)
            continue
        xy = vertices[:, :2] / vertices[:, 2:3]
        areas.append(_hull_area(xy) * k.fx_px * k.fy_px)
    scale = _distortion_area_scale(camera, centre_cam[:2] / centre_cam[2])
    return float(np.mean(areas)) * scale


def in_view(
    camera: CameraModel,
    pose: PoseSample,
    north_m: float,
    east_m: float,
    params: GeolocationParams,
    margin_px: float = 10.0,
) -> bool:
    """Whether a floor point shows in the image at least ``margin_px`` from its edges,
    in front of the camera, within [min_range_m, max_range_m]."""
    floor = _floor_down(pose, params)
    point = np.array([[north_m, east_m, floor]])
    cam = _camera_frame(camera, pose, point)[0]
    if cam[2] <= _Z_NEAR_M:
        return False
    range_m = float(np.linalg.norm(cam))
    if not params.min_range_m <= range_m <= params.max_range_m:
        return False
    u, v = camera.project_camera(cam[None, :])[0]
    k = camera.intrinsics
    return bool(
        margin_px - 0.5 <= u <= k.width_px - 0.5 - margin_px
        and margin_px - 0.5 <= v <= k.height_px - 0.5 - margin_px
    )
