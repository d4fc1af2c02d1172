"""The renderer against the camera model, its ground truth, and determinism."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from fusion.camera import CameraModel, Intrinsics, rotation_zyx
from scenarios.camera import default_camera
from scenarios.motion import TruePose
from scenarios.render import Renderer, RenderOptions
from scenarios.world import Debris, World, preset

MAGENTA = (255, 0, 255)
CLEAN = RenderOptions(noise=False, blur_sigma_px=0.0, headlight=0.0)


def _pose(
    n: float, e: float, yaw_deg: float, roll_deg: float = 0.0, pitch_deg: float = 0.0
) -> TruePose:
    return TruePose(
        0.0, n, e, -0.10, math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg)
    )


def _marker_world(points: list[tuple[float, float]]) -> World:
    markers = tuple(Debris.box("marker", MAGENTA, n, e, 0.05, 0.05, 0.0) for n, e in points)
    return World(debris=markers, seed=3)


def _centroids(image: np.ndarray) -> list[tuple[float, float]]:
    """Centroids of magenta blobs, weighted by how magenta each pixel is (edges count less)."""
    import cv2

    b, g, r = (image[:, :, i].astype(float) for i in range(3))
    weight = np.clip((r + b) / 2.0 - g - 40.0, 0.0, None)
    count, labels = cv2.connectedComponents((weight > 30.0).astype(np.uint8))
    out = []
    for k in range(1, count):
        ys, xs = np.nonzero(labels == k)
        if len(xs) < 3:
            continue
        # Grow the blob by 2 px so its soft edge is in the weighted mean on every side.
        y0, y1, x0, x1 = ys.min() - 2, ys.max() + 3, xs.min() - 2, xs.max() + 3
        w = weight[y0:y1, x0:x1]
        yy, xx = np.mgrid[y0:y1, x0:x1]
        out.append((float((xx * w).sum() / w.sum()), float((yy * w).sum() / w.sum())))
    return out


@pytest.mark.parametrize(
    ("camera", "pose"),
    [
        (default_camera(), _pose(4.0, 4.0, 0.0)),
        (default_camera(), _pose(4.2, 3.7, 20.0, roll_deg=2.0, pitch_deg=-1.5)),
        (
            dataclasses.replace(
                default_camera(),
                intrinsics=dataclasses.replace(
                    default_camera().intrinsics, distortion=(-0.25, 0.08, 0.001, -0.001, 0.0)
                ),
            ),
            _pose(4.0, 4.1, -10.0, roll_deg=-1.0),
        ),
    ],
    ids=["level", "rolled-yawed", "distorted"],
)
def test_floor_points_land_on_the_pixel_the_camera_model_predicts(
    camera: CameraModel, pose: TruePose
) -> None:
    yaw = pose.yaw_rad
    # Within ~2.5 m: farther, one pixel row spans several cm of floor and a marker of a
    # few cm is cut by a single row, whose crossing need not pass through its centre.
    ahead = [(1.0, 0.0), (1.6, -0.5), (2.2, 0.7), (1.3, 0.45), (2.0, -0.9)]
    points = [
        (
            pose.north_m + a * math.cos(yaw) - b * math.sin(yaw),
            pose.east_m + a * math.sin(yaw) + b * math.cos(yaw),
        )
        for a, b in ahead
    ]
    image = Renderer(_marker_world(points), camera, options=CLEAN).render(pose).image
    found = _centroids(image)
    px, inside = camera.project_ned(
        np.array([[n, e, 0.0] for n, e in points]),
        np.array([pose.north_m, pose.east_m, pose.down_m]),
        rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad),
    )
    assert inside.all()
    assert len(found) == len(points)
    for u, v in px:
        d = min(math.hypot(u - fu, v - fv) for fu, fv in found)
        # 1 px: the marker is 5 cm square, so the blob centroid differs from the projected
        # centre only by perspective (well under 0.3 px here) and the raster's 5 mm cells.
        assert d <= 1.0, (u, v, found)


def test_in_view_ground_truth_follows_the_pose() -> None:
    world = preset("light")
    (v,) = world.victims
    renderer = Renderer(world)
    facing = math.atan2(v.east_m - 3.2, v.north_m - 3.8)
    looking = renderer.render(_pose(3.8, 3.2, math.degrees(facing)))
    assert looking.in_view == (v.victim_id,)
    assert looking.visible_px[v.victim_id] > 500
    away = renderer.render(_pose(3.8, 3.2, math.degrees(facing) + 180.0))
    assert away.in_view == () and away.visible_px == {}


def test_buried_parts_do_not_count_as_in_view() -> None:
    world = preset("critical")
    (v,) = world.victims
    renderer = Renderer(world)
    # From 1.5 m beyond the exposed part (a hand), looking back at it over the pile.
    out = math.atan2(v.visible_east_m - v.east_m, v.visible_north_m - v.north_m)
    n = v.visible_north_m + 1.5 * math.cos(out)
    e = v.visible_east_m + 1.5 * math.sin(out)
    pose = _pose(n, e, math.degrees(out + math.pi))
    res = renderer.render(pose)
    # The same victim uncovered shows many more pixels from the same place.
    bare = Renderer(dataclasses.replace(world, debris=())).render(pose)
    assert 0 < res.visible_px.get(v.victim_id, 0) < 0.2 * bare.visible_px[v.victim_id]


def test_dark_zone_frames_are_darker_and_noisier() -> None:
    world = preset("dark")
    renderer = Renderer(world, options=RenderOptions(headlight=0.0))
    (v,) = world.victims
    dark = renderer.render(_pose(v.north_m - 1.5, v.east_m, 0.0), frame_key=1)
    lit = renderer.render(_pose(2.0, 1.0, 0.0), frame_key=1)
    assert dark.gain > 2.0 * lit.gain

    # Noise: differences between neighbouring pixels in the bottom rows (plain floor).
    def grain(img: np.ndarray) -> float:
        rows = img[-60:, :, 1].astype(float)
        return float(np.std(np.diff(rows, axis=1)))

    assert grain(dark.image) > 1.5 * grain(lit.image)


def test_same_seed_same_frame_and_jpeg_option() -> None:
    world = preset("mixed")
    pose = _pose(8.5, 1.5, 120.0)
    a = Renderer(world).render(pose, frame_key=5).image
    b = Renderer(world).render(pose, frame_key=5).image
    c = Renderer(world).render(pose, frame_key=6).image
    assert a.shape == (480, 640, 3) and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)  # noise differs per frame
    small = dataclasses.replace(default_camera(), intrinsics=Intrinsics.from_fov(320, 240, 70.0))
    jpeg = Renderer(world, small, options=RenderOptions(jpeg_quality=40)).render(pose).image
    assert jpeg.shape == (240, 320, 3)


def test_short_sleeves_show_the_forearms_skin() -> None:
    """A T-shirt bares the forearms: seen from the rover, the short-sleeved body shows
    skin where the long-sleeved one shows its top, and nothing else changes."""
    green_skin, blue_top = (40, 200, 40), (40, 40, 200)
    world = preset("light")
    (v,) = world.victims
    v = dataclasses.replace(v, skin_rgb=green_skin, top_rgb=blue_top, pattern="plain", dust=0.0)
    facing = math.atan2(v.east_m - 3.2, v.north_m - 3.8)
    frames = {}
    for sleeves in ("long", "short"):
        w = dataclasses.replace(world, victims=(dataclasses.replace(v, sleeves=sleeves),))
        frames[sleeves] = (
            Renderer(w, options=CLEAN)
            .render(_pose(3.8, 3.2, math.degrees(facing)))
            .image.astype(int)
        )
    changed = np.abs(frames["long"] - frames["short"]).sum(axis=2) > 30
    assert changed.sum() > 100  # the forearms are in view
    b, g, _r = (frames["short"][changed][:, i] for i in range(3))
    assert np.mean(g > b) > 0.9  # green skin where the long sleeves were blue
    b, g, _r = (frames["long"][changed][:, i] for i in range(3))
    assert np.mean(b > g) > 0.9
