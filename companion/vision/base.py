"""The detector interface, its errors, and the per-frame size prior (FrameGeometry).

Exceptions::

    VisionError                 the vision step cannot run as configured
    +-- DetectorUnavailable     the chosen backend cannot be built here (says why)

A detector turns a BGR frame into ``fusion.types.Detection`` objects, one per
victim: ``u_px, v_px`` is the centroid of the visible body mask (where a lying body
touches the floor), ``visible_area_px`` the mask's pixels at the frame's resolution.

``FrameGeometry`` is the camera geometry of one frame reduced to what vision needs:
how many metres of floor a pixel spans, and how many pixels a whole lying adult
would cover, at a pixel. Both are None where the pixel does not see the floor
within range (above the horizon, too near, too far): nothing can be a victim there.
``floor_ne_m`` maps many pixels at once to floor points (north, east in metres;
NaN off the usable floor), so shapes, sizes and gaps can be measured on the floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import numpy as np

from companion.errors import CompanionError
from fusion.types import Detection

if TYPE_CHECKING:
    from fusion.camera import CameraModel
    from fusion.params import GeolocationParams
    from fusion.types import PoseSample

# A lying adult's silhouette covers about this share of its body_length_m x
# body_width_m bounding rectangle (arms along the body; head, neck and feet narrower
# than the shoulders). 0.75 of 1.7 m x 0.45 m = 0.57 m^2, close to the 0.5-0.6 m^2
# projected frontal area of an adult. Visibility is measured against it.
DEFAULT_SILHOUETTE_FILL = 0.75

_CACHE_CELL_PX = 8  # FrameGeometry answers are cached per 8x8-pixel cell


def _cell(kind: str, u_px: float, v_px: float) -> tuple[str, int, int]:
    """The cache key of a FrameGeometry answer: its kind and the pixel's 8x8 cell."""
    return (kind, int(u_px) // _CACHE_CELL_PX, int(v_px) // _CACHE_CELL_PX)


FloorMap = Callable[[np.ndarray], np.ndarray]  # pixels (N, 2) -> floor (N, 2), NaN off it
PlaneMap = Callable[[np.ndarray, float], np.ndarray]  # (pixels, height_m) -> (N, 2) on that plane
PixelMap = Callable[[np.ndarray], np.ndarray]  # floor (N, 2) -> pixels (N, 2), NaN if not in front
# (pixels (N, 2), range_m) -> (N, 3): north, east and height above the floor of the
# point at that distance along each pixel's ray
RayMap = Callable[[np.ndarray, float], np.ndarray]


class VisionError(CompanionError):
    """The vision step cannot run as configured; the message says why."""


class DetectorUnavailable(VisionError):
    """The configured detector backend is not available in this installation."""


class Detector(Protocol):
    name: str
    min_score: float  # detections scoring below it are dropped; may change between frames

    def detect(
        self, image_bgr: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]: ...


class FrameGeometry:
    """Size prior of one frame: metres per pixel and a whole body's area in pixels."""

    def __init__(
        self,
        metres_per_px: Callable[[float, float], float | None],
        expected_body_area_px: Callable[[float, float], float | None],
        floor_ne_m: FloorMap | None = None,
        plane_ne_m: PlaneMap | None = None,
        pixels_of_floor: PixelMap | None = None,
        area_along: Callable[[float, float, float], float | None] | None = None,
        along_ray: RayMap | None = None,
        metres_per_px_many: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self._mpp = metres_per_px
        self._mpp_many = metres_per_px_many
        self._area = expected_body_area_px
        self._floor = floor_ne_m
        self._plane = plane_ne_m
        self._pixels_of = pixels_of_floor
        self._area_along = area_along
        self._along_ray = along_ray
        self._cache: dict[tuple[str, int, int], float | None] = {}

    def _cached(
        self, kind: str, fn: Callable[[float, float], float | None], u: float, v: float
    ) -> float | None:
        if not (math.isfinite(u) and math.isfinite(v)):
            return None
        key = _cell(kind, u, v)
        if key not in self._cache:
            value = fn(u, v)
            self._cache[key] = None if value is None else float(value)
        return self._cache[key]

    def metres_per_px(self, u_px: float, v_px: float) -> float | None:
        """Floor metres spanned by one pixel at (u, v); None off the usable floor."""
        return self._cached("mpp", self._mpp, u_px, v_px)

    def metres_per_px_column(self, u_px: float, vs_px: list[int]) -> list[float | None]:
        """``metres_per_px`` at (u, v) for each row v, in one pass where the geometry
        can (cached per cell alike: the same values as one call per row)."""
        if not math.isfinite(u_px):
            return [None] * len(vs_px)
        todo: dict[tuple[str, int, int], int] = {}  # uncached cells: their first row asked
        for v in vs_px:
            if (key := _cell("mpp", u_px, v)) not in self._cache:
                todo.setdefault(key, v)
        if todo and self._mpp_many is not None:
            values = self._mpp_many(np.array([(u_px, v) for v in todo.values()], np.float64))
            for key, value in zip(todo, values.tolist(), strict=True):
                self._cache[key] = value if math.isfinite(value) else None
        return [self.metres_per_px(u_px, v) for v in vs_px]

    def expected_body_area_px(
        self, u_px: float, v_px: float, heading_rad: float | None = None
    ) -> float | None:
        """Pixels a whole lying adult centred at (u, v) would cover; None off the floor.
        Lying along ``heading_rad`` (NED yaw) when given and this geometry knows the
        camera; else over all headings."""
        if heading_rad is not None and self._area_along is not None:
            if not (math.isfinite(u_px) and math.isfinite(v_px)):
                return None
            return self._area_along(u_px, v_px, heading_rad)
        return self._cached("area", self._area, u_px, v_px)

    def along_ray(self, pixels: np.ndarray, range_m: float) -> np.ndarray | None:
        """North, east and height above the floor (N, 3) of the points ``range_m``
        along the rays of pixels (N, 2): where a thing of known size seen at those
        pixels lies, off the floor too. None for a geometry without the camera."""
        if self._along_ray is None:
            return None
        return np.asarray(self._along_ray(np.asarray(pixels, np.float64).reshape(-1, 2), range_m))

    def floor_ne_m(self, pixels: np.ndarray) -> np.ndarray:
        """Floor points (N, 2) of pixels (N, 2) in metres; rows off the usable floor
        are NaN. Without a floor map: each pixel's own scale, placed locally (a
        geometry built from callables alone has no global floor frame)."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if self._floor is not None:
            return np.asarray(self._floor(px), dtype=np.float64).reshape(-1, 2)
        out = np.full(px.shape, np.nan)
        for i, (u, v) in enumerate(px):
            mpp = self.metres_per_px(float(u), float(v))
            if mpp is not None:
                out[i] = (v * mpp, u * mpp)
        return out

    def plane_ne_m(self, pixels: np.ndarray, height_m: float) -> np.ndarray:
        """Where the rays of ``pixels`` cross a plane ``height_m`` above the floor
        (a lying body's joints are about 0.1 m up): (N, 2) north, east; NaN where
        the ray does not reach it in range. Without a 3-D camera: the floor map."""
        if self._plane is None or height_m == 0.0:
            return self.floor_ne_m(pixels)
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        return np.asarray(self._plane(px, height_m), dtype=np.float64).reshape(-1, 2)

    def pixels_of_floor(self, floor_ne: np.ndarray) -> np.ndarray | None:
        """Pixels (N, 2) of floor points (N, 2); NaN rows behind the camera; None
        when this geometry cannot project (built from callables alone)."""
        if self._pixels_of is None:
            return None
        pts = np.asarray(floor_ne, dtype=np.float64).reshape(-1, 2)
        return np.asarray(self._pixels_of(pts), dtype=np.float64).reshape(-1, 2)

    @classmethod
    def constant(
        cls,
        metres_per_px: float,
        body_area_m2: float = 1.7 * 0.45 * DEFAULT_SILHOUETTE_FILL,
        floor_from_v_px: float = 0.0,
    ) -> FrameGeometry:
        """The same scale everywhere below image row ``floor_from_v_px`` (tests, tools)."""
        area_px = body_area_m2 / metres_per_px**2

        def mpp(_u: float, v: float) -> float | None:
            return metres_per_px if v >= floor_from_v_px else None

        def area(_u: float, v: float) -> float | None:
            return area_px if v >= floor_from_v_px else None

        def floor(px: np.ndarray) -> np.ndarray:
            out = np.column_stack([px[:, 1], px[:, 0]]) * metres_per_px
            out[px[:, 1] < floor_from_v_px] = np.nan
            return out

        def pixels(ne: np.ndarray) -> np.ndarray:
            return np.column_stack([ne[:, 1], ne[:, 0]]) / metres_per_px

        return cls(mpp, area, floor, None, pixels)

    @classmethod
    def from_pose(
        cls,
        camera: CameraModel,
        pose: PoseSample,
        params: GeolocationParams,
        silhouette_fill: float = DEFAULT_SILHOUETTE_FILL,
    ) -> FrameGeometry:
        """The size prior of a frame taken from ``pose`` (fusion.geolocate's geometry).

        The expected body area is fusion's body rectangle (clipped to the image)
        times ``silhouette_fill``: visibility compares mask pixels with the
        silhouette a whole body would show, not with its bounding rectangle.
        """
        from fusion.errors import GeolocationRejected
        from fusion.geolocate import (
            expected_body_area_px,
            geolocate,
            ground_sample_distance_m,
            ground_sample_distances_m,
        )

        def mpp(u: float, v: float) -> float | None:
            try:
                return float(ground_sample_distance_m(camera, pose, u, v, params))
            except GeolocationRejected:
                return None

        def area_along(u: float, v: float, heading_rad: float | None) -> float | None:
            try:
                fix = geolocate(camera, pose, u, v, params)
                rect_px = expected_body_area_px(
                    camera, pose, fix.north_m, fix.east_m, params, heading_rad=heading_rad
                )
            except GeolocationRejected:
                return None
            return float(rect_px) * silhouette_fill if rect_px > 0.0 else None

        def area(u: float, v: float) -> float | None:
            return area_along(u, v, None)

        plane = _plane_map(camera, pose, params)

        def floor(px: np.ndarray) -> np.ndarray:
            return plane(px, 0.0)

        return cls(
            mpp,
            area,
            floor,
            plane,
            _pixel_map(camera, pose, params),
            area_along,
            _ray_map(camera, pose, params),
            lambda px: ground_sample_distances_m(camera, pose, px, params),
        )


def _plane_map(camera: CameraModel, pose: PoseSample, params: GeolocationParams) -> PlaneMap:
    """fusion.geolocate's ray-floor intersection for many pixels at once (no covariance),
    to the floor or to a plane ``height_m`` above it: NaN where the ray misses it or
    lands outside [min_range_m, max_range_m] along the ray."""
    from fusion.camera import rotation_zyx

    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    centre, r_ned_cam = camera.camera_pose_ned(vehicle, r_ned_body)
    floor_down = pose.down_m + params.floor_down_m

    def plane(px: np.ndarray, height_m: float) -> np.ndarray:
        if len(px) == 0:
            return np.zeros((0, 2))
        above = floor_down - height_m - centre[2]
        dirs = camera.rays_camera(px) @ r_ned_cam.T
        down = dirs[:, 2]
        ok = (down > 1e-9) & (above > 0.0)
        t = np.where(ok, above / np.where(ok, down, 1.0), np.nan)
        ok &= (t >= params.min_range_m) & (t <= params.max_range_m)
        ne = centre[:2] + t[:, None] * dirs[:, :2]
        ne[~ok] = np.nan
        return ne

    return plane


def _ray_map(camera: CameraModel, pose: PoseSample, params: GeolocationParams) -> RayMap:
    from fusion.camera import rotation_zyx

    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    centre, r_ned_cam = camera.camera_pose_ned(vehicle, r_ned_body)
    floor_down = pose.down_m + params.floor_down_m

    def along(px: np.ndarray, range_m: float) -> np.ndarray:
        points = centre + range_m * (camera.rays_camera(px) @ r_ned_cam.T)
        return np.column_stack([points[:, :2], floor_down - points[:, 2]])

    return along


def _pixel_map(camera: CameraModel, pose: PoseSample, params: GeolocationParams) -> PixelMap:
    from fusion.camera import rotation_zyx

    r_ned_body = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    floor_down = pose.down_m + params.floor_down_m

    def pixels(ne: np.ndarray) -> np.ndarray:
        pts = np.column_stack([ne, np.full(len(ne), floor_down)])
        centre, r_ned_cam = camera.camera_pose_ned(vehicle, r_ned_body)
        in_front = ((pts - centre) @ r_ned_cam)[:, 2] > 1e-6
        px, _inside = camera.project_ned(pts, vehicle, r_ned_body)
        px = np.asarray(px, dtype=np.float64)
        px[~in_front] = np.nan
        return px

    return pixels
