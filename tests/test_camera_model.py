"""Camera model: projection, distortion and mount conventions."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.camera import CameraModel, Intrinsics, Mount, rotation_zyx

PI_CAM_V2 = Intrinsics(
    1280, 960, 999.46, 996.96, 642.26, 474.15, (0.1644, -0.2717, -0.00287, -0.000097, 0.0)
)


def test_level_camera_looks_along_body_x() -> None:
    cam = CameraModel(Intrinsics.from_fov(640, 480, 90.0))
    # A point 5 m straight ahead of a vehicle facing north lands on the principal point.
    px, inside = cam.project_ned(np.array([[5.0, 0.0, 0.0]]), np.zeros(3), np.eye(3))
    assert inside[0]
    assert px[0] == pytest.approx([319.5, 239.5])
    # East of it is to the right of the image, below it lower in the image.
    px, _ = cam.project_ned(np.array([[5.0, 1.0, 1.0]]), np.zeros(3), np.eye(3))
    assert px[0, 0] > 319.5 and px[0, 1] > 239.5


def test_downward_pitch_moves_the_horizon_up() -> None:
    level = CameraModel(Intrinsics.from_fov(640, 480, 60.0))
    tilted = CameraModel(level.intrinsics, Mount(pitch_rad=math.radians(-20)))
    far = np.array([[1000.0, 0.0, 0.0]])
    v0 = level.project_ned(far, np.zeros(3), np.eye(3))[0][0, 1]
    v_tilted = tilted.project_ned(far, np.zeros(3), np.eye(3))[0][0, 1]
    assert v_tilted < v0 - 100  # the horizon sits well above the centre


def test_points_behind_the_camera_are_not_inside() -> None:
    cam = CameraModel(Intrinsics.from_fov(640, 480, 90.0))
    _, inside = cam.project_ned(np.array([[-5.0, 0.0, 0.0]]), np.zeros(3), np.eye(3))
    assert not inside[0]


def test_rotation_zyx_matches_yaw_convention() -> None:
    # Yaw 90 deg: the body's forward axis points east.
    r = rotation_zyx(0.0, 0.0, math.pi / 2)
    assert r @ np.array([1.0, 0.0, 0.0]) == pytest.approx([0.0, 1.0, 0.0])


def test_distortion_matches_opencv() -> None:
    cam = CameraModel(PI_CAM_V2)
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, 50), rng.uniform(-0.45, 0.45, 50), np.ones(50)])
    ours = cam.project_camera(pts)
    theirs, _ = cv2.projectPoints(
        pts, np.zeros(3), np.zeros(3), PI_CAM_V2.matrix, np.array(PI_CAM_V2.distortion)
    )
    assert ours == pytest.approx(theirs.reshape(-1, 2), abs=1e-6)


@settings(max_examples=50, deadline=None)
@given(
    st.floats(-0.55, 0.55),
    st.floats(-0.4, 0.4),
)
def test_undistortion_inverts_distortion(x: float, y: float) -> None:
    # Within the Pi camera's field of view, iteration recovers the ray to 1e-3 px.
    cam = CameraModel(PI_CAM_V2)
    px = cam.project_camera(np.array([[x, y, 1.0]]))
    ray = cam.rays_camera(px)[0]
    assert ray[:2] / ray[2] == pytest.approx([x, y], abs=1e-3 / PI_CAM_V2.fx_px)


def test_scaled_intrinsics_keep_the_field_of_view() -> None:
    half = PI_CAM_V2.scaled(640, 480)
    assert half.fx_px == pytest.approx(PI_CAM_V2.fx_px / 2)
    # The same ray hits corresponding pixel centres at both resolutions.
    full_px = CameraModel(PI_CAM_V2).project_camera(np.array([[0.2, 0.1, 1.0]]))[0]
    half_px = CameraModel(half).project_camera(np.array([[0.2, 0.1, 1.0]]))[0]
    assert (half_px + 0.5) * 2 - 0.5 == pytest.approx(full_px)
