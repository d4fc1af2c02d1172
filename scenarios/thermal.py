"""Thermal frames of a simulated world: what a FLIR Lepton 3.5 beside the colour camera sees.

For a pose and a mission time, ``ThermalRenderer.render`` gives the temperatures
(degrees Celsius, float32 160 x 120 for the default camera) that the thermal
camera model (scenarios.camera.default_thermal_camera) sees. It casts the same rays
against the same solids as the colour renderer (``scenarios.solids.Solids.trace``:
bodies, debris prisms, warm objects, one z-buffer) and maps what each pixel hits to
a temperature:

- the floor: the world's ambient (``Floor.temperature_c``) with gentle spatial
  variation (``temperature_variation_c``, features of a metre or two), plus heated
  patches of floor and fading imprints where a person lay (``WarmObject``), from a
  top-down raster at 2 cm sampled where each ray meets the floor;
- debris: ambient (each piece a few tenths of a kelvin off it), except thin cover
  lying on a body (``Debris.heat_through`` > 0: cloth, dust), which shows that
  share of the body's warmth beneath it; slabs and piles stay ambient;
- a body: skin at the victim's ``skin_c`` (about 34 degrees; hands and feet up to
  1.5 K cooler), hair and clothing between skin and ambient (clothing at 70 % of
  the skin's excess: 29 degrees at 18 ambient), shoes at 30 %; dust on a body and
  grazing views lower the excess a little;
- warm objects: a radiator panel (hotter at its top), a pipe, machinery (its top at
  the set temperature, its sides cooler), a dog (fur at 75 % of its core's excess
  over ambient, 33 degrees at 18 ambient, its head warmer);
- above the horizon: walls and ceiling 1.5 K below ambient.

Then the Lepton: slight optical blur, noise of about 0.05 K (seeded by the frame
key), and flat-field correction: every ``ffc_period_s`` (3 minutes; the first at a
seeded phase) the camera closes its shutter for ``ffc_duration_s`` and repeats its
last frame, as a real one does (``ThermalResult.frozen``). Deterministic for the
world's seed, the renderer's seed and the sequence of calls.

``encode_centikelvin_png`` / ``decode_centikelvin_png`` are the recorded frames
folder's format: 16-bit single-channel PNG, centi-kelvin.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from fusion.camera import CameraModel
from scenarios import body3d
from scenarios.errors import SimError
from scenarios.raster import smooth_noise
from scenarios.render import PoseLike, camera_rays, floor_rays
from scenarios.solids import PROP_BASE, Solids
from scenarios.world import World

F32 = NDArray[np.float32]

LEPTON_FPS = 8.7
KELVIN_OFFSET = 273.15
TEMP_RES_M = 0.02  # the top-down temperature rasters (coarser on floors over 40 m)
_MAX_RASTER_CELLS = 2000
MIN_WARM_VIEW_PX = 10  # a victim's warmth counts as in view from this many pixels
_CLOTHING_SHARE = 0.70  # clothing's excess over ambient, as a share of the skin's
_TROUSERS_SHARE = 0.65
_HAIR_SHARE = 0.60
_SHOES_SHARE = 0.30
_FUR_SHARE = {"dog_body": 0.75, "dog_head": 0.85, "dog_snout": 0.8, "dog_tail": 0.6}
_MACHINE_SIDE_SHARE = 0.85
_WALL_OFFSET_C = -1.5
_DRAPE_M = 0.25


@dataclass(frozen=True)
class ThermalOptions:
    noise_k: float = 0.05  # std of the temporal noise (NETD of a Lepton 3.5: < 50 mK)
    blur_sigma_px: float = 0.5  # the optics
    supersample: int = 1  # rays per pixel along each axis (2: smoother small parts)
    ffc: bool = True
    ffc_period_s: float = 180.0
    ffc_duration_s: float = 0.5

    def __post_init__(self) -> None:
        if not (self.noise_k >= 0 and self.blur_sigma_px >= 0 and 1 <= self.supersample <= 4):
            raise SimError(
                "ThermalOptions: noise_k and blur_sigma_px must be >= 0, supersample 1..4"
            )
        if not (self.ffc_period_s > 0 and 0 <= self.ffc_duration_s < self.ffc_period_s):
            raise SimError("ThermalOptions: ffc_duration_s must be in [0, ffc_period_s)")


@dataclass(frozen=True)
class ThermalResult:
    temps_c: F32  # (H, W) degrees Celsius
    frozen: bool  # a flat-field correction frame: the previous frame repeated
    warm_px: dict[int, int]  # victim id -> pixels of its warmth (its body, thin cover on it)


def encode_centikelvin_png(temps_c: np.ndarray) -> bytes:
    """Temperatures (degrees C) as a 16-bit single-channel PNG in centi-kelvin."""
    ck = np.clip(np.round((temps_c.astype(np.float64) + KELVIN_OFFSET) * 100.0), 0, 65535)
    ok, buf = cv2.imencode(".png", ck.astype(np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - OpenCV contract for a valid uint16 image
        raise SimError("PNG encoding of a thermal frame failed")
    return buf.tobytes()


def decode_centikelvin_png(data: bytes) -> F32:
    """A centi-kelvin PNG back to degrees C (the inverse of encode_centikelvin_png)."""
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise SimError("not a 16-bit single-channel PNG")
    return (img.astype(np.float32) / np.float32(100.0)) - np.float32(KELVIN_OFFSET)


def _fill(mask: np.ndarray, poly_ne: np.ndarray, value: float, res_m: float) -> None:
    pts = np.column_stack([poly_ne[:, 1] / res_m - 0.5, poly_ne[:, 0] / res_m - 0.5])
    cv2.fillPoly(mask, [np.round(pts * 16).astype(np.int32)], value, cv2.LINE_8, 4)


def _blur(img: np.ndarray, sigma_m: float, res_m: float) -> np.ndarray:
    return np.asarray(cv2.GaussianBlur(img, (0, 0), max(sigma_m / res_m, 0.5)), np.float32)


@dataclass(frozen=True)
class _Rasters:
    """Top-down (rows north, columns east) at res_m."""

    res_m: float
    floor_c: F32  # ambient with its variation and heated patches
    imprints: tuple[tuple[int, F32], ...]  # (warm object index, shape 0..1)
    body_heat_k: F32  # a body's warmth under thin cover: excess over ambient
    body_owner: NDArray[np.int32]  # victim index + 1 under each cell, else 0


def _rasters(world: World) -> _Rasters:
    res = max(TEMP_RES_M, max(world.size_m) / _MAX_RASTER_CELLS)
    rows = math.ceil(world.size_m[0] / res)
    cols = math.ceil(world.size_m[1] / res)
    rng = np.random.default_rng([world.seed, 0x7E47])
    fl = world.floor
    floor = np.full((rows, cols), fl.temperature_c, np.float32)
    if fl.temperature_variation_c > 0:
        floor += np.float32(fl.temperature_variation_c) * smooth_noise(
            rng, (rows, cols), max(2, int(1.5 / res))
        )
    imprints = []
    for q, w in enumerate(world.warm_objects):
        shape = np.zeros((rows, cols), np.float32)
        _fill(shape, w.polygon, 1.0, res)
        if w.kind == "heated_floor":
            # Pipes under the floor: warmer stripes across the patch, 0.15 m apart.
            n = (np.arange(rows, dtype=np.float32) + 0.5) * res
            e = (np.arange(cols, dtype=np.float32) + 0.5) * res
            along = np.cos(w.heading_rad) * n[:, None] + np.sin(w.heading_rad) * e[None, :]
            stripes = 1.0 + 0.06 * np.cos(along * (2 * math.pi / 0.15))
            floor += (
                _blur(shape, 0.12, res)
                * stripes.astype(np.float32)
                * np.float32(w.temperature_c - fl.temperature_c)
            )
        elif w.kind == "imprint":
            imprints.append((q, _blur(shape, 0.25 * w.width_m, res)))
    heat = np.zeros((rows, cols), np.float32)
    owner = np.zeros((rows, cols), np.int32)
    if any(d.heat_through > 0 for d in world.debris):
        for k, v in enumerate(world.victims, start=1):
            excess = v.skin_c - fl.temperature_c
            for part in v.parts():
                share = {"skin": 1.0, "top": _CLOTHING_SHARE, "trousers": _TROUSERS_SHARE}
                if part.role in share:
                    layer = np.zeros((rows, cols), np.float32)
                    _fill(layer, part.polygon_ne_m, excess * share[part.role], res)
                    np.maximum(heat, layer, out=heat)
                    _fill(owner, part.polygon_ne_m, k, res)
        # Cover lies over the body and drapes down to the floor beside it: its sides,
        # which a low camera sees, are warm too. The warmth reaches _DRAPE_M beyond the
        # body's outline, and the cover spreads it a little.
        grow = 2 * round(_DRAPE_M / res) + 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (grow, grow))
        heat = _blur(np.asarray(cv2.dilate(heat, kernel), np.float32), 0.04, res)
        owner = np.asarray(cv2.dilate(owner.astype(np.float32), kernel), np.int32)
    return _Rasters(res, floor, tuple(imprints), heat, owner)


class ThermalRenderer:
    """Renders thermal frames of one world through one camera. Not thread-safe: the
    flat-field frames repeat the last frame rendered."""

    def __init__(
        self,
        world: World,
        camera: CameraModel | None = None,
        *,
        options: ThermalOptions | None = None,
        seed: int = 0,
    ) -> None:
        if camera is None:
            from scenarios.camera import default_thermal_camera

            camera = default_thermal_camera()
        self.world = world
        self.camera = camera
        self.options = options or ThermalOptions()
        k = camera.intrinsics
        self.size = (k.width_px, k.height_px)
        ss = self.options.supersample
        self._trace_camera = camera
        if ss > 1:
            fine = k.scaled(k.width_px * ss, k.height_px * ss)
            self._trace_camera = dataclasses.replace(camera, intrinsics=fine)
        self._rays_cam = camera_rays(self._trace_camera)
        self.solids = Solids(world, None, self._trace_camera)
        self._rasters = _rasters(world)
        self._ambient = np.float32(world.floor.temperature_c)
        self._seed = seed
        self._count = 0
        self._last: ThermalResult | None = None
        rng = np.random.default_rng([world.seed, seed, 0xFFC])
        period = self.options.ffc_period_s
        self._ffc_phase_s = float(rng.uniform(0.1 * period, 0.9 * period))
        # Each debris piece a little off ambient (its mass lags the air's changes).
        self._prism_offset = rng.normal(0.0, 0.3, len(self.solids.prisms)).astype(np.float32)
        self._prism_through = np.array(
            [d.heat_through for d in self.solids.prism_debris], np.float32
        )
        self._prop_share, self._prop_temp, self._prop_kind = self._prop_tables()

    def _prop_tables(self) -> tuple[F32, F32, list[str]]:
        share, temp, kinds = [], [], []
        for part, q in zip(self.solids.props, self.solids.prop_object, strict=True):
            w = self.world.warm_objects[q]
            share.append(_FUR_SHARE.get(getattr(part, "name", ""), 1.0))
            temp.append(w.temperature_c)
            kinds.append(w.kind)
        return np.array(share, np.float32), np.array(temp, np.float32), kinds

    def ffc_active(self, t_s: float) -> bool:
        """Whether the shutter is closed (a flat-field correction) at mission time t_s."""
        opt = self.options
        if not opt.ffc or t_s < self._ffc_phase_s:
            return False
        return (t_s - self._ffc_phase_s) % opt.ffc_period_s < opt.ffc_duration_s

    def _sample(self, layer: F32, north: F32, east: F32, border: float) -> F32:
        inv = np.float32(1.0 / self._rasters.res_m)
        out = cv2.remap(
            layer,
            east * inv - np.float32(0.5),
            north * inv - np.float32(0.5),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=border,
        )
        return np.asarray(out, np.float32)

    def render(self, pose: PoseLike, t_s: float, *, frame_key: int | None = None) -> ThermalResult:
        """The frame at mission time ``t_s`` from the true pose; during a flat-field
        correction the previous frame again. ``frame_key`` seeds its noise (default: a
        counter)."""
        key = self._count if frame_key is None else frame_key
        self._count += 1
        if self.ffc_active(t_s) and self._last is not None:
            return dataclasses.replace(self._last, frozen=True)
        temps, warm = self._temperatures(pose, t_s)
        opt = self.options
        ss = opt.supersample
        if ss > 1:
            temps = np.asarray(cv2.resize(temps, self.size, interpolation=cv2.INTER_AREA))
            warm = {vid: round(px / (ss * ss)) for vid, px in warm.items()}
            warm = {vid: px for vid, px in warm.items() if px > 0}
        if opt.blur_sigma_px > 0:
            temps = np.asarray(cv2.GaussianBlur(temps, (0, 0), opt.blur_sigma_px), np.float32)
        if opt.noise_k > 0:
            rng = np.random.default_rng([self.world.seed, self._seed, key, 0x7E4])
            temps = temps + rng.standard_normal(temps.shape, np.float32) * np.float32(opt.noise_k)
        result = ThermalResult(np.ascontiguousarray(temps, np.float32), False, warm)
        self._last = result
        return result

    def _temperatures(self, pose: PoseLike, t_s: float) -> tuple[F32, dict[int, int]]:
        """Noise-free temperatures at the tracing resolution, and warm pixels per victim."""
        ras = self._rasters
        north, east, rng_m, _sin, rays, centre, r_nc = floor_rays(
            self._trace_camera, self._rays_cam, pose
        )
        ambient = float(self._ambient)
        temps = self._sample(ras.floor_c, north, east, ambient)
        for q, shape in ras.imprints:
            excess = self.world.warm_objects[q].excess_at(t_s, ambient)
            if excess != 0.0:
                temps += self._sample(shape, north, east, 0.0) * np.float32(excess)
        temps[~np.isfinite(rng_m)] = np.float32(ambient + _WALL_OFFSET_C)
        hits = self.solids.trace(rng_m, centre, r_nc, rays)
        flat = hits.owner.ravel()
        idx = np.nonzero(flat)[0]
        warm: dict[int, int] = {}
        if len(idx) == 0:
            return temps, warm
        who = flat[idx]
        t = hits.depth_m.ravel()[idx]
        d = rays.reshape(-1, 3)[idx]
        p = centre + d * t[:, None]
        n = hits.normal.reshape(-1, 3)[idx].astype(np.float64)
        facing = np.clip(-(n * d).sum(axis=1), 0.0, 1.0)
        out = np.empty(len(idx), np.float64)
        # The ambient where each hit stands (its floor cell).
        local = self._sample(
            ras.floor_c,
            p[:, 0].astype(np.float32)[None, :],
            p[:, 1].astype(np.float32)[None, :],
            ambient,
        )[0].astype(np.float64)
        bodies = (who > 0) & (who < PROP_BASE)
        if bodies.any():
            mat = hits.material.ravel()[idx][bodies]
            out[bodies] = self._body_temps(
                who[bodies], mat, p[bodies], facing[bodies], local[bodies]
            )
            counts = np.bincount(
                who[bodies][mat != body3d.SHOES], minlength=len(self.world.victims) + 1
            )
            for k, v in enumerate(self.world.victims, start=1):
                if counts[k] > 0:
                    warm[v.victim_id] = int(counts[k])
        debris = who < 0
        if debris.any():
            j = -who[debris] - 1
            temp = local[debris] + self._prism_offset[j]
            through = self._prism_through[j]
            covered = through > 0
            if covered.any():
                pn = p[debris][covered, 0].astype(np.float32)[None, :]
                pe = p[debris][covered, 1].astype(np.float32)[None, :]
                heat = self._sample(ras.body_heat_k, pn, pe, 0.0)[0]
                temp[covered] += through[covered] * heat
                cell_r = np.clip((pn[0] / ras.res_m).astype(int), 0, ras.body_owner.shape[0] - 1)
                cell_c = np.clip((pe[0] / ras.res_m).astype(int), 0, ras.body_owner.shape[1] - 1)
                under = ras.body_owner[cell_r, cell_c]
                shows = under[heat * through[covered] > 1.0]
                for k, v in enumerate(self.world.victims, start=1):
                    extra = int((shows == k).sum())
                    if extra:
                        warm[v.victim_id] = warm.get(v.victim_id, 0) + extra
            out[debris] = temp
        props = who >= PROP_BASE
        if props.any():
            out[props] = self._prop_temps(who[props] - PROP_BASE, p[props], n[props], local[props])
        temps.ravel()[idx] = out.astype(np.float32)
        return temps, warm

    def _body_temps(
        self, who: np.ndarray, mat: np.ndarray, p: np.ndarray, facing: np.ndarray, local: np.ndarray
    ) -> np.ndarray:
        out = np.empty(len(who))
        for k, v in enumerate(self.world.victims, start=1):
            m = who == k
            if not m.any():
                continue
            body = self.solids.bodies[k - 1]
            excess = np.full(int(m.sum()), v.skin_c) - local[m]
            share = np.ones(int(m.sum()))
            mk = mat[m]
            share[mk == body3d.TOP] = _CLOTHING_SHARE
            share[mk == body3d.TROUSERS] = _TROUSERS_SHARE
            share[mk == body3d.HAIR] = _HAIR_SHARE
            share[mk == body3d.SHOES] = _SHOES_SHARE
            # Hands and feet are cooler than the face and trunk.
            reach = np.linalg.norm(p[m, :2] - body.centre[:2], axis=1) / (0.85 * body.scale)
            skin = mk == body3d.SKIN
            head = np.linalg.norm(p[m] - body.head_centre, axis=1) < 0.17 * body.scale
            cool = np.where(skin & ~head, 1.5 * np.clip((reach - 0.4) / 0.6, 0.0, 1.0), 0.0)
            grazing = 0.8 + 0.2 * facing[m]
            dust = 1.0 - 0.2 * v.dust
            out[m] = local[m] + (excess * share - cool) * grazing * dust
        return out

    def _prop_temps(
        self, part: np.ndarray, p: np.ndarray, n: np.ndarray, local: np.ndarray
    ) -> np.ndarray:
        temp = self._prop_temp[part].astype(np.float64)
        share = self._prop_share[part].astype(np.float64)
        out: np.ndarray = local + (temp - local) * share
        for q, kind in enumerate(self._prop_kind):
            m = part == q
            if not m.any():
                continue
            w = self.world.warm_objects[self.solids.prop_object[q]]
            if kind == "radiator":  # hotter at the top: +-3 K over its height
                frac = np.clip((-p[m, 2] - w.elevation_m) / w.height_m, 0.0, 1.0)
                out[m] += 6.0 * (frac - 0.5)
            elif kind == "machinery":  # the top at the set temperature, the sides cooler
                side = n[m, 2] > -0.7
                out[m] = np.where(
                    side, local[m] + (temp[m] - local[m]) * _MACHINE_SIDE_SHARE, out[m]
                )
        return out
