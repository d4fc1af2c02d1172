"""Camera frames of a simulated world, rendered from the vehicle's true pose.

The floor is flat (down = 0) and everything on it is painted into a top-down raster
(scenarios.raster). For a pose, every image pixel's ray (through the camera model of
``fusion.camera``, distortion included) is intersected with the floor; the raster is
sampled there with ``cv2.remap``. This is the ground-plane homography, evaluated per
pixel, so the camera's plumb-bob distortion comes out exactly as the model has it.
A raster pyramid level is chosen per pixel from its floor footprint, so the far
floor does not alias.

Then: light (the zones' static light and a headlight that falls off with range),
slight optical blur, auto-exposure with a gain capped at ``max_gain``, sensor noise
(read noise and shot noise, amplified by the gain, so dark frames are noisy), and
optionally JPEG compression.

``render(pose)`` also returns the ground truth of the frame: which victims have
uncovered body parts in the image and how many pixels each.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from fusion.camera import CameraModel, rotation_zyx
from scenarios.raster import FloorRaster, build_raster
from scenarios.solids import Solids
from scenarios.world import World

MIN_VIEW_PX = 150  # a victim counts as "seen" in a frame from this many body pixels
_NOISE_BANK = 3
_NOISE_MARGIN = 64
_VOID_BGR = (18.0, 18.0, 20.0)  # above the horizon: the dark warehouse
_WALL_BGRL = (62, 60, 58, 25)  # off the floor: dim walls and rubble


class PoseLike(Protocol):
    @property
    def north_m(self) -> float: ...
    @property
    def east_m(self) -> float: ...
    @property
    def down_m(self) -> float: ...
    @property
    def roll_rad(self) -> float: ...
    @property
    def pitch_rad(self) -> float: ...
    @property
    def yaw_rad(self) -> float: ...


@dataclass(frozen=True)
class RenderOptions:
    noise: bool = True
    read_noise: float = 0.006  # std of read noise, fraction of full scale, before gain
    shot_noise: float = 0.012  # std of shot noise at full signal (scales with sqrt)
    blur_sigma_px: float = 0.6  # optics; 0 = none
    headlight: float = 0.10  # extra light at 1 m from the camera, fraction of full light
    target_mean: float = 0.42  # auto-exposure aims for this mean brightness
    max_gain: float = 4.0  # auto-exposure gain cap (dark frames stay dark and noisy)
    jpeg_quality: int = 0  # 0: no compression artefacts in RenderResult.image


@dataclass(frozen=True)
class RenderResult:
    image: np.ndarray  # BGR uint8 (height, width, 3)
    in_view: tuple[int, ...]  # victim ids with uncovered body pixels in the image
    visible_px: dict[int, int]  # victim id -> uncovered body pixels in the image
    gain: float  # auto-exposure gain used


def encode_jpeg(image: np.ndarray, quality: int = 85) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV contract for a valid uint8 image
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


def camera_rays(camera: CameraModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit rays of every pixel in the camera frame, distortion removed: three (H, W)."""
    k = camera.intrinsics
    u, v = np.meshgrid(np.arange(k.width_px, dtype=float), np.arange(k.height_px, dtype=float))
    rays = camera.rays_camera(np.column_stack([u.ravel(), v.ravel()]))
    return (
        np.ascontiguousarray(rays[:, 0].reshape(k.height_px, k.width_px), np.float32),
        np.ascontiguousarray(rays[:, 1].reshape(k.height_px, k.width_px), np.float32),
        np.ascontiguousarray(rays[:, 2].reshape(k.height_px, k.width_px), np.float32),
    )


def floor_rays(
    camera: CameraModel, rays_cam: tuple[np.ndarray, np.ndarray, np.ndarray], pose: PoseLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel: floor north, east and range (m; inf off the floor), sin(grazing), the
    unit NED rays (H, W, 3), the camera centre (NED) and R_ned_cam, for a pose."""
    r_nb = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    centre, r_nc = camera.camera_pose_ned(np.array([pose.north_m, pose.east_m, pose.down_m]), r_nb)
    # Rays in NED, component by component (cheaper than a BLAS call for 3x3).
    r = r_nc.astype(np.float32)
    cx, cy, cz = rays_cam
    dn = cx * r[0, 0] + cy * r[0, 1] + cz * r[0, 2]
    de = cx * r[1, 0] + cy * r[1, 1] + cz * r[1, 2]
    dz = cx * r[2, 0] + cy * r[2, 1] + cz * r[2, 2]  # sine of the angle below the horizon
    height = -float(centre[2])  # camera height above the floor (down = 0)
    hits = dz > 1e-4
    if height <= 0:
        hits[:] = False
    t = np.full(dz.shape, np.inf, np.float32)
    np.divide(np.float32(height), dz, out=t, where=hits)
    with np.errstate(invalid="ignore"):  # 0 * inf off the floor; set below
        north = dn * t
        east = de * t
    north += np.float32(centre[0])
    east += np.float32(centre[1])
    north[~hits] = -1e6
    east[~hits] = -1e6
    rays = np.stack([dn, de, dz], axis=-1).astype(np.float64)  # (H, W, 3)
    return north, east, t, np.clip(dz, 1e-4, 1.0), rays, centre, r_nc


class Renderer:
    """Renders frames of one world through one camera. Not thread-safe."""

    def __init__(
        self,
        world: World,
        camera: CameraModel | None = None,
        *,
        raster: FloorRaster | None = None,
        options: RenderOptions | None = None,
        seed: int = 0,
    ) -> None:
        if camera is None:
            from scenarios.camera import default_camera

            camera = default_camera()
        self.world = world
        self.camera = camera
        self.options = options or RenderOptions()
        self.raster = raster or build_raster(world)
        self.solids = Solids(world, self.raster, camera)
        k = camera.intrinsics
        self.size = (k.width_px, k.height_px)
        self._rays_cam = camera_rays(camera)
        self._focal_px = 0.5 * (k.fx_px + k.fy_px)
        self._seed = seed
        self._count = 0
        rng = np.random.default_rng([world.seed, seed, 0xCA3])
        # Noise frames with a margin: each frame takes a randomly offset window.
        self._noise = rng.standard_normal(
            (_NOISE_BANK, k.height_px + _NOISE_MARGIN, k.width_px + _NOISE_MARGIN, 3), np.float32
        )

    # -- geometry ------------------------------------------------------------------

    def floor_maps(self, pose: PoseLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per pixel: floor north, east and range (m; inf off the floor), and sin(grazing)."""
        north, east, t, sin_graze, _rays, _centre, _r = self._floor_rays(pose)
        return north, east, t, sin_graze

    def _floor_rays(
        self, pose: PoseLike
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """floor_maps, and the unit NED rays (H, W, 3), camera centre and R_ned_cam."""
        return floor_rays(self.camera, self._rays_cam, pose)

    # -- rendering -----------------------------------------------------------------

    def _row_levels(self, rng_m: np.ndarray, sin_graze: np.ndarray) -> np.ndarray:
        """Pyramid level per image row, from the floor footprint at the row's middle.

        A pixel's footprint is range/f across the ray and range/(f sin) along it; the
        level matches their geometric mean. Per row (not per pixel) keeps it cheap;
        the footprint changes little along a row for the small roll of a rover.
        """
        mid = self.size[0] // 2
        r, s = rng_m[:, mid].astype(np.float64), sin_graze[:, mid].astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            footprint = r / (self._focal_px * np.sqrt(s))
            level = np.floor(np.log2(footprint / self.raster.res_m) + 0.5)
        top = len(self.raster.pyramid) - 1
        return np.where(np.isfinite(level), np.clip(level, 0, top), top).astype(int)

    def _sample(
        self, north: np.ndarray, east: np.ndarray, rng_m: np.ndarray, sin_graze: np.ndarray
    ) -> np.ndarray:
        res = self.raster.res_m
        levels = self._row_levels(rng_m, sin_graze)
        out = np.empty((*north.shape, 4), np.uint8)
        start = 0
        rows = len(levels)
        while start < rows:
            stop = start + 1
            while stop < rows and levels[stop] == levels[start]:
                stop += 1
            lv = int(levels[start])
            inv = np.float32(1.0 / (res * 2.0**lv))
            cv2.remap(
                self.raster.pyramid[lv],
                east[start:stop] * inv - np.float32(0.5),
                north[start:stop] * inv - np.float32(0.5),
                cv2.INTER_LINEAR,
                dst=out[start:stop],
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=_WALL_BGRL,
            )
            start = stop
        return out

    def render(self, pose: PoseLike, *, frame_key: int | None = None) -> RenderResult:
        """A frame from the true pose. ``frame_key`` seeds its noise (default: a counter)."""
        opt = self.options
        north, east, rng_m, sin_graze, rays, centre, r_nc = self._floor_rays(pose)
        on_floor = np.isfinite(rng_m)
        bgrl = self._sample(north, east, rng_m, sin_graze).astype(np.float32)
        # light in 0..1: the zones' static light plus the headlight's inverse square.
        light = bgrl[:, :, 3] * np.float32(1.0 / 255.0)
        light += np.float32(opt.headlight) * np.minimum(np.float32(1.0), 1.0 / np.square(rng_m))
        signal = bgrl[:, :, :3] * (light * np.float32(1.0 / 255.0))[:, :, None]
        signal[~on_floor] = np.array(_VOID_BGR, np.float32) / 255.0
        visible = self.solids.draw(signal, rng_m, centre, r_nc, rays, opt.headlight)
        if opt.blur_sigma_px > 0:
            signal = cv2.GaussianBlur(signal, (0, 0), opt.blur_sigma_px)
        means = cv2.mean(signal)
        mean = (means[0] + means[1] + means[2]) / 3.0
        gain = float(np.clip(opt.target_mean / max(mean, 1e-6), 0.7, opt.max_gain))
        key = self._count if frame_key is None else frame_key
        self._count += 1
        if opt.noise:
            rng = np.random.default_rng([self.world.seed, self._seed, key])
            bank = self._noise[int(rng.integers(_NOISE_BANK))]
            h, w = self.size[1], self.size[0]
            dy = int(rng.integers(bank.shape[0] - h + 1))
            dx = int(rng.integers(bank.shape[1] - w + 1))
            noise = bank[dy : dy + h, dx : dx + w]
            # std = read + shot * signal: noise grows with signal, and the gain amplifies
            # both, so a dark frame brought up by the auto-exposure is grainy.
            signal += noise * (np.float32(opt.read_noise) + np.float32(opt.shot_noise) * signal)
        image = cv2.convertScaleAbs(signal, alpha=gain * 255.0)
        if opt.jpeg_quality > 0:
            buf = np.frombuffer(encode_jpeg(image, opt.jpeg_quality), np.uint8)
            image = np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR))
        return RenderResult(image, tuple(sorted(visible)), visible, gain)
