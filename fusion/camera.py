"""Pinhole camera with plumb-bob distortion, mounted on the vehicle.

Frames:
- camera (optical): x right, y down, z forward along the optical axis;
- body FRD: x forward, y right, z down, from the vehicle's reference point;
- local NED: north, east, down.

With a mount of roll = pitch = yaw = 0 the camera looks straight ahead along the
body's x axis. The mount angles rotate the camera in the body frame with the same
ZYX (yaw, pitch, roll) convention as the vehicle's attitude, so a camera tilted
down by 20 degrees has ``pitch_rad = -20 deg``.

Distortion is OpenCV's plumb-bob model (k1, k2, p1, p2, k3). Undistortion inverts it
by fixed-point iteration, as ``cv2.undistortPoints`` does, in numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

# Columns are the optical axes (x right, y down, z forward) expressed in body FRD.
_R_BODY_FROM_OPTICAL = np.array(
    [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
    ]
)

_UNDISTORT_ITERATIONS = 20


def rotation_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """R such that v_parent = R @ v_child for ZYX Euler angles (aerospace convention).

    For the vehicle's attitude this is R_ned_from_body.
    """
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics and plumb-bob distortion for one image size."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"image size must be positive, got {self.width_px}x{self.height_px}")
        if not (self.fx_px > 0 and self.fy_px > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx_px} fy={self.fy_px}")
        values = (self.fx_px, self.fy_px, self.cx_px, self.cy_px, *self.distortion)
        if not all(math.isfinite(v) for v in values):
            raise ValueError("intrinsics must be finite numbers")
        if len(self.distortion) != 5:
            raise ValueError(
                f"distortion needs 5 coefficients (k1 k2 p1 p2 k3), got {len(self.distortion)}"
            )

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float) -> Intrinsics:
        """An ideal camera with the given horizontal field of view and square pixels."""
        f = 0.5 * width_px / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width_px, height_px, f, f, (width_px - 1) / 2.0, (height_px - 1) / 2.0)

    def scaled(self, width_px: int, height_px: int) -> Intrinsics:
        """The same camera at another resolution of the same aspect (binned or resized)."""
        sx, sy = width_px / self.width_px, height_px / self.height_px
        return Intrinsics(
            width_px,
            height_px,
            self.fx_px * sx,
            self.fy_px * sy,
            (self.cx_px + 0.5) * sx - 0.5,
            (self.cy_px + 0.5) * sy - 0.5,
            self.distortion,
        )

    @property
    def matrix(self) -> FloatArray:
        """The 3x3 camera matrix K."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )

    @property
    def has_distortion(self) -> bool:
        return any(c != 0.0 for c in self.distortion)


@dataclass(frozen=True)
class Mount:
    """Where the camera sits on the vehicle: position in body FRD and its rotation."""

    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0

    @property
    def position_body_m(self) -> FloatArray:
        return np.array([self.x_m, self.y_m, self.z_m])

    @property
    def r_body_from_camera(self) -> FloatArray:
        return rotation_zyx(self.roll_rad, self.pitch_rad, self.yaw_rad) @ _R_BODY_FROM_OPTICAL


@dataclass(frozen=True)
class CameraModel:
    """A calibrated camera on its mount. Pure geometry: no image I/O."""

    intrinsics: Intrinsics
    mount: Mount = field(default_factory=Mount)

    # -- distortion ----------------------------------------------------------------

    def distort_normalized(self, xy: FloatArray) -> FloatArray:
        """Apply plumb-bob distortion to normalized coordinates, shape (N, 2)."""
        k1, k2, p1, p2, k3 = self.intrinsics.distortion
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return np.column_stack([xd, yd])

    def undistort_normalized(self, xy_distorted: FloatArray) -> FloatArray:
        """Invert the distortion by fixed-point iteration (as cv2.undistortPoints)."""
        if not self.intrinsics.has_distortion:
            return xy_distorted.copy()
        k1, k2, p1, p2, k3 = self.intrinsics.distortion
        xd, yd = xy_distorted[:, 0], xy_distorted[:, 1]
        x, y = xd.copy(), yd.copy()
        for _ in range(_UNDISTORT_ITERATIONS):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = (xd - dx) / radial
            y = (yd - dy) / radial
        return np.column_stack([x, y])

    # -- camera frame <-> pixels ---------------------------------------------------

    def project_camera(self, points_cam: FloatArray) -> FloatArray:
        """Pixels (N, 2) of points (N, 3) in the camera frame; z must be > 0."""
        pts = np.atleast_2d(np.asarray(points_cam, dtype=float))
        xy = pts[:, :2] / pts[:, 2:3]
        xy = self.distort_normalized(xy)
        k = self.intrinsics
        return np.column_stack([k.fx_px * xy[:, 0] + k.cx_px, k.fy_px * xy[:, 1] + k.cy_px])

    def rays_camera(self, pixels: FloatArray) -> FloatArray:
        """Unit rays (N, 3) in the camera frame through pixels (N, 2), distortion removed."""
        px = np.atleast_2d(np.asarray(pixels, dtype=float))
        k = self.intrinsics
        xy = np.column_stack([(px[:, 0] - k.cx_px) / k.fx_px, (px[:, 1] - k.cy_px) / k.fy_px])
        xy = self.undistort_normalized(xy)
        rays = np.column_stack([xy, np.ones(len(xy))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    # -- world frame ---------------------------------------------------------------

    def camera_pose_ned(
        self, vehicle_ned_m: FloatArray, r_ned_from_body: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """The camera's centre in NED and R_ned_from_camera for a vehicle pose."""
        centre = vehicle_ned_m + r_ned_from_body @ self.mount.position_body_m
        return centre, r_ned_from_body @ self.mount.r_body_from_camera

    def project_ned(
        self, points_ned: FloatArray, vehicle_ned_m: FloatArray, r_ned_from_body: FloatArray
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Pixels of NED points and a mask of those in front of the camera and in the image."""
        centre, r_ned_cam = self.camera_pose_ned(vehicle_ned_m, r_ned_from_body)
        pts_cam = (np.atleast_2d(points_ned) - centre) @ r_ned_cam  # = (R^T @ (p - c)^T)^T
        in_front = pts_cam[:, 2] > 1e-6
        safe = pts_cam.copy()
        safe[~in_front, 2] = 1.0
        px = self.project_camera(safe)
        k = self.intrinsics
        inside = (
            in_front
            & (px[:, 0] >= -0.5)
            & (px[:, 0] <= k.width_px - 0.5)
            & (px[:, 1] >= -0.5)
            & (px[:, 1] <= k.height_px - 0.5)
        )
        return px, inside
