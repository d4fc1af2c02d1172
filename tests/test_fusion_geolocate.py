"""Geolocation: exact round trip, honest covariance, rejections, size priors."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from fusion.camera import CameraModel, Intrinsics, Mount, rotation_zyx
from fusion.errors import GeolocationRejected
from fusion.geolocate import (
    expected_body_area_px,
    geolocate,
    ground_sample_distance_m,
    ground_sample_distances_m,
    in_view,
)
from fusion.params import GeolocationParams
from fusion.types import PoseSample

PARAMS = GeolocationParams()


def _camera(pitch_deg: float = -20.0, distortion: tuple[float, ...] = (0.0,) * 5) -> CameraModel:
    k = Intrinsics.from_fov(640, 480, 70.0)
    k = Intrinsics(640, 480, k.fx_px, k.fy_px, k.cx_px, k.cy_px, distortion)  # type: ignore[arg-type]
    return CameraModel(k, Mount(x_m=0.12, y_m=0.02, z_m=-0.25, pitch_rad=math.radians(pitch_deg)))


def _pose(
    north_m: float = 1.0,
    east_m: float = 2.0,
    down_m: float = -0.3,
    roll_rad: float = 0.0,
    pitch_rad: float = 0.0,
    yaw_rad: float = 0.5,
) -> PoseSample:
    return PoseSample(10.0, 100.0, north_m, east_m, down_m, roll_rad, pitch_rad, yaw_rad)


def _project(camera: CameraModel, pose: PoseSample, point: np.ndarray) -> tuple[float, float, bool]:
    r = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    vehicle = np.array([pose.north_m, pose.east_m, pose.down_m])
    px, inside = camera.project_ned(point[None, :], vehicle, r)
    return float(px[0, 0]), float(px[0, 1]), bool(inside[0])


angles = st.floats(min_value=-math.radians(8), max_value=math.radians(8))


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    roll=angles,
    pitch=angles,
    yaw=st.floats(min_value=-math.pi, max_value=math.pi),
    mount_pitch_deg=st.floats(min_value=-45.0, max_value=-5.0),
    mount_yaw_deg=st.floats(min_value=-30.0, max_value=30.0),
    mount_roll_deg=st.floats(min_value=-5.0, max_value=5.0),
    mount_xyz=st.tuples(st.floats(-0.2, 0.3), st.floats(-0.15, 0.15), st.floats(-0.4, -0.05)),
    k1=st.floats(-0.2, 0.1),
    bearing_frac=st.floats(-0.8, 0.8),
    dist_m=st.floats(0.5, 6.0),
)
def test_round_trip_world_pixel_world(
    roll: float,
    pitch: float,
    yaw: float,
    mount_pitch_deg: float,
    mount_yaw_deg: float,
    mount_roll_deg: float,
    mount_xyz: tuple[float, float, float],
    k1: float,
    bearing_frac: float,
    dist_m: float,
) -> None:
    # Tolerance 1e-6 m: the pipeline is exact but for the fixed-point undistortion
    # (20 iterations, converging far below 1e-9 rad for these mild lenses) and
    # float rounding; 1e-6 m at 8 m range is 1.2e-7 rad.
    k = Intrinsics.from_fov(640, 480, 75.0)
    k = Intrinsics(640, 480, k.fx_px, k.fy_px, k.cx_px, k.cy_px, (k1, 0.02, 0.001, -0.001, 0.0))
    mount = Mount(
        *mount_xyz,
        roll_rad=math.radians(mount_roll_deg),
        pitch_rad=math.radians(mount_pitch_deg),
        yaw_rad=math.radians(mount_yaw_deg),
    )
    camera = CameraModel(k, mount)
    pose = _pose(roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw)
    floor = pose.down_m + PARAMS.floor_down_m
    heading = yaw + math.radians(mount_yaw_deg) + bearing_frac * math.radians(30.0)
    point = np.array(
        [
            pose.north_m + dist_m * math.cos(heading),
            pose.east_m + dist_m * math.sin(heading),
            floor,
        ]
    )
    u, v, inside = _project(camera, pose, point)
    if not inside:
        return  # the generated point is outside this camera's view: nothing to invert
    try:
        fix = geolocate(camera, pose, u, v, PARAMS)
    except GeolocationRejected as exc:
        assert "range" in exc.reason  # only the range limits may refuse a visible point
        return
    assert abs(fix.north_m - point[0]) < 1e-6
    assert abs(fix.east_m - point[1]) < 1e-6
    assert abs(fix.down_m - point[2]) < 1e-9


def test_round_trip_known_geometry() -> None:
    # Camera 0.35 m above the floor looking north, tilted down 45 degrees: the
    # principal point hits the floor 0.35 m ahead of the camera, range 0.35*sqrt(2).
    camera = CameraModel(Intrinsics.from_fov(641, 481, 60.0), Mount(pitch_rad=-math.pi / 4))
    pose = _pose(north_m=0.0, east_m=0.0, down_m=0.0, yaw_rad=0.0)
    fix = geolocate(camera, pose, 320.0, 240.0, GeolocationParams(floor_down_m=0.35))
    assert fix.north_m == pytest.approx(0.35, abs=1e-9)
    assert fix.east_m == pytest.approx(0.0, abs=1e-9)
    assert fix.range_m == pytest.approx(0.35 * math.sqrt(2.0), abs=1e-9)


def _nees_mean(camera: CameraModel, pose: PoseSample, u: float, v: float, runs: int) -> float:
    rng = np.random.default_rng(20240605)
    truth = geolocate(camera, pose, u, v, PARAMS)
    s_att = math.radians(PARAMS.attitude_sigma_deg)
    total = 0.0
    for _ in range(runs):
        du, dv = rng.normal(0.0, PARAMS.pixel_sigma_px, 2)
        dr, dp, dy = rng.normal(0.0, s_att, 3)
        dn, de = rng.normal(0.0, PARAMS.position_sigma_m, 2)
        noisy = PoseSample(
            pose.t_boot_s,
            pose.t_mono_s,
            pose.north_m + dn,
            pose.east_m + de,
            pose.down_m,
            pose.roll_rad + dr,
            pose.pitch_rad + dp,
            pose.yaw_rad + dy,
        )
        est = geolocate(camera, noisy, u + du, v + dv, PARAMS)
        err = np.array([est.north_m - truth.north_m, est.east_m - truth.east_m])
        # The estimator's own covariance, as the tracker would receive it.
        total += float(err @ np.linalg.solve(np.array(est.cov_ne_m2), err))
    return total / runs


@pytest.mark.parametrize(
    ("pitch_deg", "v_px"),
    [(-20.0, 300.0), (-30.0, 240.0), (-10.0, 330.0)],
)
def test_covariance_is_honest_monte_carlo(pitch_deg: float, v_px: float) -> None:
    # Noise drawn exactly as modelled: pixel, roll/pitch/yaw and horizontal position.
    # The mean NEES of 400 independent 2-dof errors lies in the two-sided 99 % chi-square
    # interval chi2(800)/400 = [0.88, 1.13] when the covariance is honest; first-order
    # propagation is accurate here because the ray is >= 10 deg below the horizon.
    camera = _camera(pitch_deg)
    pose = _pose(roll_rad=0.02, pitch_rad=-0.03)
    runs = 400
    mean = _nees_mean(camera, pose, 250.0, v_px, runs)
    lo, hi = chi2.ppf([0.005, 0.995], 2 * runs) / runs
    assert lo < mean < hi, f"mean NEES {mean:.3f} outside [{lo:.3f}, {hi:.3f}]"


def test_covariance_grows_with_range_and_grazing() -> None:
    camera = _camera(-10.0)  # camera 0.35 m above the floor
    pose = _pose()
    sigmas, ranges = [], []
    for v in (470.0, 400.0, 330.0, 280.0, 230.0, 200.0):
        fix = geolocate(camera, pose, 320.0, v, PARAMS)
        sigmas.append(math.sqrt(max(np.linalg.eigvalsh(np.array(fix.cov_ne_m2)))))
        ranges.append(fix.range_m)
    assert ranges == sorted(ranges)
    assert sigmas == sorted(sigmas)
    assert sigmas[-1] > 5 * sigmas[0]  # grazing rays are far less certain
    # Never better than the vehicle's own position uncertainty.
    assert sigmas[0] >= PARAMS.position_sigma_m


def test_a_body_cut_by_the_frame_edge_is_doubted_across_the_ray_only() -> None:
    """The part of a body beyond the frame's side edge is unknown: its centre may lie
    beyond the edge's plane, which holds the ray. Along the ray nothing changes."""
    camera, pose = _camera(-12.0), _pose()
    for u in (5.0, 634.0):  # at the left and the right edge
        plain = geolocate(camera, pose, u, 330.0, PARAMS)
        cut = geolocate(camera, pose, u, 330.0, PARAMS, cut_by_frame=True)
        assert (cut.north_m, cut.east_m) == (plain.north_m, plain.east_m)
        centre, _r = camera.camera_pose_ned(
            np.array([pose.north_m, pose.east_m, pose.down_m]),
            rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad),
        )
        ray = np.array([cut.north_m - centre[0], cut.east_m - centre[1]])
        ray /= np.linalg.norm(ray)
        across = np.array([-ray[1], ray[0]])
        grown = np.array(cut.cov_ne_m2) - np.array(plain.cov_ne_m2)
        assert across @ grown @ across == pytest.approx(PARAMS.frame_cut_sigma_m**2)
        assert ray @ grown @ ray == pytest.approx(0.0, abs=1e-12)


def test_rejects_rays_above_horizon_and_out_of_range() -> None:
    camera = _camera(-10.0)
    pose = _pose()
    with pytest.raises(GeolocationRejected, match="does not hit the floor in front"):
        geolocate(camera, pose, 320.0, 10.0, PARAMS)
    with pytest.raises(GeolocationRejected, match=r"beyond max_range_m 8.0: \d+\.\d m"):
        geolocate(camera, pose, 320.0, 170.0, PARAMS)
    near = GeolocationParams(min_range_m=1.0)
    with pytest.raises(GeolocationRejected, match=r"nearer than min_range_m 1\.0"):
        geolocate(camera, pose, 320.0, 470.0, near)
    with pytest.raises(GeolocationRejected, match="not finite"):
        geolocate(camera, pose, float("nan"), 400.0, PARAMS)


def test_camera_below_floor_is_rejected() -> None:
    camera = _camera(-20.0)
    sunk = GeolocationParams(floor_down_m=-0.5)  # floor above the camera
    with pytest.raises(GeolocationRejected, match="below the floor"):
        geolocate(camera, _pose(), 320.0, 400.0, sunk)


def test_ground_sample_distance_matches_finite_steps() -> None:
    camera = _camera(-20.0)
    pose = _pose()
    u, v = 300.0, 320.0
    gsd = ground_sample_distance_m(camera, pose, u, v, PARAMS)
    a = geolocate(camera, pose, u, v, PARAMS)
    bu = geolocate(camera, pose, u + 1.0, v, PARAMS)
    bv = geolocate(camera, pose, u, v + 1.0, PARAMS)
    du = math.hypot(bu.north_m - a.north_m, bu.east_m - a.east_m)
    dv = math.hypot(bv.north_m - a.north_m, bv.east_m - a.east_m)
    # One-pixel secants differ from the tangent by the curvature: under 1 %.
    assert gsd == pytest.approx(math.sqrt(du * dv), rel=0.01)
    far = ground_sample_distance_m(camera, pose, u, 250.0, PARAMS)
    assert far > gsd
    with pytest.raises(GeolocationRejected):
        ground_sample_distance_m(camera, pose, 320.0, 10.0, PARAMS)


@settings(max_examples=40, deadline=None)
@given(
    roll_deg=st.floats(-10.0, 10.0),
    pitch_deg=st.floats(-40.0, 5.0),
    yaw_deg=st.floats(-180.0, 180.0),
    k1=st.floats(-0.3, 0.1),
)
def test_many_ground_sample_distances_at_once_are_the_one_pixel_answers(
    roll_deg: float, pitch_deg: float, yaw_deg: float, k1: float
) -> None:
    # The far-band search of every colour frame asks for a column of them at once; it
    # must be the same numbers, and NaN exactly where one pixel's call is rejected
    # (above the horizon, beyond max_range_m, nearer than min_range_m).
    camera = _camera(pitch_deg, (k1, 0.0, 0.0, 0.0, 0.0))
    pose = dataclasses.replace(
        _pose(), roll_rad=math.radians(roll_deg), yaw_rad=math.radians(yaw_deg)
    )
    pixels = np.array([(u, v) for u in (3.0, 320.0, 637.0) for v in range(2, 480, 6)], float)
    many = ground_sample_distances_m(camera, pose, pixels, PARAMS)
    for (u, v), got in zip(pixels, many, strict=True):
        try:
            want = ground_sample_distance_m(camera, pose, u, v, PARAMS)
        except GeolocationRejected:
            assert math.isnan(got), (u, v, got)
        else:
            assert got == pytest.approx(want, rel=1e-12), (u, v)
    assert ground_sample_distances_m(camera, pose, np.zeros((0, 2)), PARAMS).shape == (0,)


def test_expected_body_area_top_down_is_exact() -> None:
    # Looking straight down from h = 2 m, a 1.7 x 0.45 m body covers
    # fx * fy * 1.7 * 0.45 / h^2 pixels at any heading (clipping never bites: the
    # floor's view is 2.8 m x 2.1 m).
    camera = CameraModel(Intrinsics.from_fov(640, 480, 70.0), Mount(pitch_rad=-math.pi / 2))
    pose = _pose(north_m=0.0, east_m=0.0, down_m=0.0, yaw_rad=0.3)
    k = camera.intrinsics
    flat = GeolocationParams(floor_down_m=2.0, body_height_m=0.0)
    area = expected_body_area_px(camera, pose, 0.0, 0.0, flat)
    assert area == pytest.approx(k.fx_px * k.fy_px * 1.7 * 0.45 / 4.0, rel=1e-9)
    # A body 0.22 m thick: its top is 1.78 m from the camera, seen larger by (2/1.78)^2.
    thick = GeolocationParams(floor_down_m=2.0, body_height_m=0.22)
    area = expected_body_area_px(camera, pose, 0.0, 0.0, thick)
    assert area == pytest.approx(k.fx_px * k.fy_px * 1.7 * 0.45 / 1.78**2, rel=1e-9)


def test_from_a_low_camera_a_lying_body_shows_its_side() -> None:
    # 0.3 m up, looking level: the footprint is a thin sliver, the 0.22 m side is not.
    camera = _camera(0.0)
    pose = _pose(north_m=0.0, east_m=0.0, down_m=0.0)
    low = GeolocationParams(floor_down_m=0.3)
    flat = expected_body_area_px(camera, pose, 3.0, 0.0, dataclasses.replace(low, body_height_m=0))
    thick = expected_body_area_px(camera, pose, 3.0, 0.0, low)
    assert thick > 2.0 * flat


def test_expected_body_area_shrinks_with_range_and_is_clipped_near() -> None:
    camera = _camera(-20.0)
    pose = _pose()
    fixes = [geolocate(camera, pose, 320.0, v, PARAMS) for v in (200.0, 150.0, 120.0)]
    areas = [expected_body_area_px(camera, pose, f.north_m, f.east_m, PARAMS) for f in fixes]
    assert areas[0] > areas[1] > areas[2] > 0.0
    near = geolocate(camera, pose, 320.0, 450.0, PARAMS)
    clipped = expected_body_area_px(camera, pose, near.north_m, near.east_m, PARAMS)
    whole = expected_body_area_px(
        camera, pose, near.north_m, near.east_m, PARAMS, clip_to_image=False
    )
    assert clipped <= 640 * 480 * 1.001
    assert whole > clipped
    behind = (pose.north_m - 3.0 * math.cos(pose.yaw_rad), pose.east_m - 3.0 * math.sin(0.5))
    with pytest.raises(GeolocationRejected, match="not in front"):
        expected_body_area_px(camera, pose, *behind, PARAMS)


def test_in_view() -> None:
    camera = _camera(-20.0)
    pose = _pose()
    fix = geolocate(camera, pose, 320.0, 300.0, PARAMS)
    assert in_view(camera, pose, fix.north_m, fix.east_m, PARAMS)
    edge = geolocate(camera, pose, 3.0, 300.0, PARAMS)
    assert not in_view(camera, pose, edge.north_m, edge.east_m, PARAMS, margin_px=10.0)
    assert in_view(camera, pose, edge.north_m, edge.east_m, PARAMS, margin_px=0.0)
    behind = (pose.north_m - 2.0 * math.cos(0.5), pose.east_m - 2.0 * math.sin(0.5))
    assert not in_view(camera, pose, *behind, PARAMS)
    ahead_far = (pose.north_m + 20.0 * math.cos(0.5), pose.east_m + 20.0 * math.sin(0.5))
    assert not in_view(camera, pose, *ahead_far, PARAMS)
