"""A simulated collapsed-warehouse floor: debris, light, and victims lying on it.

Coordinates are the local NED frame of the rover's EKF origin: the floor spans
``0 <= north_m <= size_m[0]`` and ``0 <= east_m <= size_m[1]`` at ``down_m = 0``;
north runs along the long side. Everything lies flat on the floor.

Each victim's ``visibility_pct`` is ground truth: the body silhouette
(scenarios.body) and every debris polygon are rasterised top-down at 2.5 mm and the
uncovered body pixels counted. It is computed when the World is built, so a World
always carries the truth for its own debris. The urgency class follows from it
(fusion.types.Urgency.from_visibility).

For the thermal camera (scenarios.thermal) a world also has temperatures: the
floor's ambient (``Floor.temperature_c``, with gentle spatial variation), each
victim's skin (``Victim.skin_c``), how much of a body's heat shows through a piece
of debris lying on it (``Debris.heat_through``: thin cover such as ``cloth`` and
``dust`` lets some through; slabs and piles none), and warm things that are not
people (``WarmObject``: a radiator, a pipe, machinery, a dog, a heated patch of
floor, the fading imprint where a person lay). ``warm_visibility_pct`` is the share
of a victim's skin and clothing not under opaque debris (thin cover counts as seen).

Worlds are stored as TOML (``load_world`` / ``save_world``); the seven scenarios of
the first prototype and four thermal ones ship as presets (``preset(name)``,
``PRESETS``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fusion.types import GlobalOrigin, Urgency
from scenarios import body3d
from scenarios.body3d import PATTERNS, POSTURES, SLEEVES, Pattern, Posture, Sleeves
from scenarios.errors import SimError

RGB = tuple[int, int, int]
PointNE = tuple[float, float]

VISIBILITY_RES_M = 0.0025  # raster cell of the ground-truth visibility
MAX_COORD_M = 1000.0  # no point of a world lies farther from its origin (the floor: 200)
PRESETS: tuple[str, ...] = (
    "empty",
    "light",
    "medium",
    "critical",
    "dark",
    "mixed",
    "skin_debris",
    "thermal_dark",
    "thermal_covered",
    "thermal_warm_things",
    "thermal_warm_things2",
)
DEFAULT_ORIGIN = GlobalOrigin(lat_deg=40.071, lon_deg=-105.2296, alt_m=1580.0)


class WorldError(SimError, ValueError):
    """A world file or world description cannot be used; the message names the key."""


def rgb_from_hex(text: str, where: str = "colour") -> RGB:
    """'#rrggbb' -> (r, g, b)."""
    t = text.strip()
    if len(t) != 7 or t[0] != "#":
        raise WorldError(f"{where} = {text!r}: expected a colour like '#a0b1c2'")
    try:
        return (int(t[1:3], 16), int(t[3:5], 16), int(t[5:7], 16))
    except ValueError:
        raise WorldError(f"{where} = {text!r}: expected a colour like '#a0b1c2'") from None


def hex_from_rgb(rgb: RGB) -> str:
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def _check_rgb(rgb: RGB, where: str) -> None:
    if len(rgb) != 3 or not all(isinstance(c, int) and 0 <= c <= 255 for c in rgb):
        raise WorldError(f"{where} = {rgb!r}: expected three integers 0..255")


@dataclass(frozen=True)
class Floor:
    colour_rgb: RGB = (125, 120, 112)  # dusty concrete
    texture_contrast: float = 0.18  # relative amplitude of stains and grain
    ambient_light: float = 1.0  # light outside every light zone, 0..1
    temperature_c: float = 18.0  # ambient: the floor and debris, for the thermal camera
    temperature_variation_c: float = 0.5  # std of its gentle spatial variation

    def __post_init__(self) -> None:
        _check_rgb(self.colour_rgb, "floor.colour")
        if not -30.0 <= self.temperature_c <= 50.0:
            raise WorldError(f"floor.temperature_c = {self.temperature_c}: must be in [-30, 50]")
        if not 0.0 <= self.temperature_variation_c <= 5.0:
            raise WorldError(
                f"floor.temperature_variation_c = {self.temperature_variation_c}: must be in [0, 5]"
            )
        if not 0.0 <= self.texture_contrast <= 1.0:
            raise WorldError(f"floor.texture_contrast = {self.texture_contrast}: must be in [0, 1]")
        if not 0.0 < self.ambient_light <= 1.0:
            raise WorldError(f"floor.ambient_light = {self.ambient_light}: must be in (0, 1]")


@dataclass(frozen=True)
class Debris:
    """A piece of rubble: the prism over the convex hull of its polygon, from the floor
    up to ``height_m`` (by kind). A piece that lies on a victim is a pile over it: the
    renderer raises it above the body, so what it covers is hidden from every view."""

    kind: str  # slab | piece | plank | beam | sheet | carton | pallet | plasterboard | tarp
    # | cable | racking | lookalike_skin | lookalike_cloth | cloth | dust
    colour_rgb: RGB
    polygon_ne_m: tuple[PointNE, ...]
    # Share of a covered body's heat (above ambient) that shows through the piece, 0..1;
    # NaN: by kind (cloth 0.55, dust 0.7, every other kind 0: slabs and piles hide it).
    heat_through: float = math.nan

    def __post_init__(self) -> None:
        _check_rgb(self.colour_rgb, f"debris ({self.kind}).colour")
        if math.isnan(self.heat_through):
            object.__setattr__(self, "heat_through", _HEAT_THROUGH.get(self.kind, 0.0))
        if not 0.0 <= self.heat_through <= 1.0:
            raise WorldError(
                f"debris ({self.kind}).heat_through = {self.heat_through}: must be in [0, 1]"
            )
        if len(self.polygon_ne_m) < 3:
            raise WorldError(f"debris ({self.kind}).polygon_ne_m needs at least 3 points")
        if not all(abs(v) <= MAX_COORD_M for p in self.polygon_ne_m for v in p):
            raise WorldError(
                f"debris ({self.kind}).polygon_ne_m must be numbers within +-{MAX_COORD_M:g} m"
            )

    @classmethod
    def box(
        cls,
        kind: str,
        colour_rgb: RGB,
        north_m: float,
        east_m: float,
        length_m: float,
        width_m: float,
        heading_rad: float,
        heat_through: float = math.nan,
    ) -> Debris:
        """A rectangle centred at (north, east), its length along heading_rad."""
        box = _box(north_m, east_m, length_m, width_m, heading_rad)
        return cls(kind, colour_rgb, box, heat_through)

    @property
    def polygon(self) -> np.ndarray:
        """The convex hull of the outline (north, east), the piece's footprint."""
        pts = np.asarray(self.polygon_ne_m, dtype=np.float32)
        return cv2.convexHull(pts).reshape(-1, 2).astype(float)

    @property
    def height_m(self) -> float:
        return _DEBRIS_HEIGHT_M.get(self.kind, 0.0)  # other kinds: paint on the floor


_DEBRIS_HEIGHT_M = {
    "slab": 0.10,
    "piece": 0.14,
    "plank": 0.04,
    "beam": 0.12,
    "sheet": 0.01,
    "lookalike_skin": 0.03,
    "lookalike_cloth": 0.02,
    "carton": 0.35,
    "pallet": 0.14,
    "plasterboard": 0.015,
    "tarp": 0.01,
    "cable": 0.02,
    "racking": 2.2,
    "cloth": 0.01,
    "dust": 0.01,
}
_HEAT_THROUGH = {"cloth": 0.55, "dust": 0.7}


def _box(
    north_m: float, east_m: float, length_m: float, width_m: float, heading_rad: float
) -> tuple[PointNE, ...]:
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    pts = []
    for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1)):
        x, y = a * length_m / 2, b * width_m / 2
        pts.append((round(north_m + c * x - s * y, 4), round(east_m + s * x + c * y, 4)))
    return tuple(pts)


WARM_KINDS = ("radiator", "pipe", "machinery", "dog", "heated_floor", "imprint")
# Per kind: temperature_c, length_m, width_m, height_m, elevation_m, colour.
WARM_DEFAULTS: dict[str, tuple[float, float, float, float, float, RGB]] = {
    "radiator": (55.0, 1.0, 0.08, 0.6, 0.12, (225, 225, 218)),  # a panel on a wall
    "pipe": (45.0, 3.0, 0.1, 0.0, 0.5, (150, 150, 155)),  # width: its diameter
    "machinery": (75.0, 1.0, 0.7, 0.9, 0.0, (70, 95, 80)),
    "dog": (38.0, 0.8, 0.3, 0.0, 0.0, (110, 75, 45)),  # its core; the fur is cooler
    "heated_floor": (30.0, 2.5, 2.0, 0.0, 0.0, (0, 0, 0)),  # no colour: the floor's
    "imprint": (28.0, 1.6, 0.5, 0.0, 0.0, (0, 0, 0)),  # at the mission's start
}


@dataclass(frozen=True)
class WarmObject:
    """A warm thing that is not a person. Solid ones (radiator, pipe, machinery, dog)
    are drawn by both cameras and block the rover; a heated patch of floor and the
    imprint where a person lay are warmth on the floor only, seen by the thermal
    camera alone. An imprint's excess over ambient fades as exp(-(age_s + t) / fade_s)
    with mission time t."""

    kind: str
    north_m: float
    east_m: float
    heading_rad: float
    length_m: float
    width_m: float
    temperature_c: float
    height_m: float = 0.0  # radiator, machinery: vertical size
    elevation_m: float = 0.0  # radiator, pipe: bottom (axis for a pipe) above the floor
    colour_rgb: RGB = (128, 128, 128)
    fade_s: float = 90.0  # imprint only
    age_s: float = 0.0  # imprint only: seconds since the person left at mission start

    def __post_init__(self) -> None:
        where = f"warm_objects ({self.kind})"
        if self.kind not in WARM_KINDS:
            raise WorldError(f"{where}.kind: one of {', '.join(WARM_KINDS)}")
        if not (abs(self.north_m) <= MAX_COORD_M and abs(self.east_m) <= MAX_COORD_M):
            raise WorldError(f"{where}: centre must lie within +-{MAX_COORD_M:g} m")
        if not math.isfinite(self.heading_rad):
            raise WorldError(f"{where}.heading = {self.heading_rad}: must be a finite angle")
        for name in ("length_m", "width_m"):
            if not 0.01 <= getattr(self, name) <= 20.0:
                raise WorldError(f"{where}.{name} = {getattr(self, name)}: must be in [0.01, 20]")
        if not 0.0 <= self.height_m <= 5.0 or not 0.0 <= self.elevation_m <= 5.0:
            raise WorldError(f"{where}: height_m and elevation_m must be in [0, 5]")
        if self.kind in ("radiator", "machinery") and self.height_m < 0.05:
            raise WorldError(f"{where}.height_m = {self.height_m}: must be at least 0.05")
        if not -30.0 <= self.temperature_c <= 150.0:
            raise WorldError(f"{where}.temperature_c = {self.temperature_c}: must be in [-30, 150]")
        if not (0.0 < self.fade_s <= 1e6 and 0.0 <= self.age_s <= 1e6):
            raise WorldError(f"{where}: fade_s must be in (0, 1e6] and age_s in [0, 1e6]")
        _check_rgb(self.colour_rgb, f"{where}.colour")

    @property
    def solid(self) -> bool:
        return self.kind in ("radiator", "pipe", "machinery", "dog")

    @property
    def polygon(self) -> np.ndarray:
        """The footprint (north, east): a rectangle length x width along the heading."""
        pts = _box(self.north_m, self.east_m, self.length_m, self.width_m, self.heading_rad)
        return np.asarray(pts, float)

    def excess_at(self, t_s: float, ambient_c: float) -> float:
        """Degrees above ambient at mission time t_s (an imprint fades)."""
        excess = self.temperature_c - ambient_c
        if self.kind == "imprint":
            excess *= math.exp(-(self.age_s + max(t_s, 0.0)) / self.fade_s)
        return excess


def warm_object(kind: str, north_m: float, east_m: float, **fields: float | RGB) -> WarmObject:
    """A warm object with its kind's defaults for every field not given."""
    if kind not in WARM_DEFAULTS:
        raise WorldError(f"warm_objects.kind = {kind!r}: one of {', '.join(WARM_KINDS)}")
    temp, length, width, height, elevation, colour = WARM_DEFAULTS[kind]
    values: dict[str, Any] = dict(
        heading_rad=0.0,
        length_m=length,
        width_m=width,
        temperature_c=temp,
        height_m=height,
        elevation_m=elevation,
        colour_rgb=colour,
    )
    values.update(fields)
    return WarmObject(kind, north_m, east_m, **values)


@dataclass(frozen=True)
class LightZone:
    """A darker (or lit) disc: light is the fraction of full light at its centre."""

    north_m: float
    east_m: float
    radius_m: float
    light: float  # 0.05 .. 1
    edge_m: float = 0.5  # width of the smooth transition at the rim

    def __post_init__(self) -> None:
        if not 0.0 < self.light <= 1.0:
            raise WorldError(f"light_zones.light = {self.light}: must be in (0, 1]")
        if not (0 < self.radius_m <= MAX_COORD_M and 0 <= self.edge_m <= MAX_COORD_M):
            raise WorldError(
                f"light_zones: radius_m must be in (0, {MAX_COORD_M:g}] and edge_m in "
                f"[0, {MAX_COORD_M:g}]"
            )
        if not (abs(self.north_m) <= MAX_COORD_M and abs(self.east_m) <= MAX_COORD_M):
            raise WorldError(
                f"light_zones: centre ({self.north_m}, {self.east_m}) must lie within "
                f"+-{MAX_COORD_M:g} m"
            )


@dataclass(frozen=True)
class Victim:
    """A person lying on the floor. ``visibility_pct`` is filled in by World."""

    victim_id: int
    north_m: float
    east_m: float
    heading_rad: float
    height_m: float
    skin_rgb: RGB
    top_rgb: RGB
    trousers_rgb: RGB
    shoes_rgb: RGB = (40, 36, 34)
    hair_rgb: RGB = (38, 30, 24)
    posture: Posture = "back"
    pattern: Pattern = "plain"
    dust: float = 0.0  # 0..1: how much of the clothes and skin is grey with dust
    left_arm_rad: float = 0.15
    right_arm_rad: float = 0.15
    leg_spread_rad: float = 0.05
    sleeves: Sleeves = "long"
    skin_c: float = 34.0  # skin temperature; clothing lies between it and ambient
    visibility_pct: float = math.nan  # ground truth, computed by World
    visible_north_m: float = math.nan  # centroid of the uncovered body
    visible_east_m: float = math.nan
    warm_visibility_pct: float = math.nan  # skin and clothing not under opaque debris

    def __post_init__(self) -> None:
        where = f"victims[{self.victim_id}]"
        if self.victim_id < 1:
            raise WorldError(f"{where}.victim_id must be >= 1")
        if not 1.0 <= self.height_m <= 2.2:
            raise WorldError(f"{where}.height_m = {self.height_m}: must be in [1.0, 2.2]")
        for name in ("skin_rgb", "top_rgb", "trousers_rgb", "shoes_rgb", "hair_rgb"):
            _check_rgb(getattr(self, name), f"{where}.{name.removesuffix('_rgb')}")
        if self.posture not in POSTURES:
            raise WorldError(f"{where}.posture = {self.posture!r}: one of {', '.join(POSTURES)}")
        if self.pattern not in PATTERNS:
            raise WorldError(f"{where}.pattern = {self.pattern!r}: one of {', '.join(PATTERNS)}")
        if self.sleeves not in SLEEVES:
            raise WorldError(f"{where}.sleeves = {self.sleeves!r}: one of {', '.join(SLEEVES)}")
        if not 0.0 <= self.dust <= 1.0:
            raise WorldError(f"{where}.dust = {self.dust}: must be in [0, 1]")
        if not 20.0 <= self.skin_c <= 42.0:
            raise WorldError(f"{where}.skin_c = {self.skin_c}: must be in [20, 42]")

    @property
    def urgency(self) -> Urgency:
        if math.isnan(self.visibility_pct):
            raise WorldError(f"victim {self.victim_id}: visibility not computed (not in a World)")
        return Urgency.from_visibility(self.visibility_pct)

    def body(self) -> body3d.Body3D:
        """The solid body the renderer draws."""
        return body3d.build_body(
            self.north_m,
            self.east_m,
            self.heading_rad,
            self.height_m,
            self.posture,
            self.left_arm_rad,
            self.right_arm_rad,
            self.leg_spread_rad,
            self.sleeves,
        )

    def look(self) -> body3d.Look:
        return body3d.Look(
            self.skin_rgb,
            self.top_rgb,
            self.trousers_rgb,
            self.shoes_rgb,
            self.hair_rgb,
            self.pattern,
            self.dust,
        )

    def parts(self) -> list[Part]:
        """The body's floor footprint: each solid's outline seen from straight above."""
        return [
            Part(name, _ROLE[material], polygon)
            for name, material, polygon in body3d.footprint(self.body())
        ]

    def colour_of(self, role: str) -> RGB:
        colours: dict[str, RGB] = {
            "skin": self.skin_rgb,
            "top": self.top_rgb,
            "trousers": self.trousers_rgb,
            "shoes": self.shoes_rgb,
        }
        return colours[role]


@dataclass(frozen=True)
class Part:
    name: str
    role: str  # skin | top | trousers | shoes: which of the victim's colours
    polygon_ne_m: np.ndarray  # (N, 2) north, east in metres


_ROLE = {
    body3d.SKIN: "skin",
    body3d.TOP: "top",
    body3d.TROUSERS: "trousers",
    body3d.SHOES: "shoes",
    body3d.HAIR: "skin",
}


def _fill(mask: np.ndarray, poly_ne: np.ndarray, n0: float, e0: float, res: float) -> None:
    """Fill a polygon into a mask whose rows are north and columns east (cell centres)."""
    pts = np.column_stack([(poly_ne[:, 1] - e0) / res - 0.5, (poly_ne[:, 0] - n0) / res - 0.5])
    shift = 4  # sub-pixel vertices: 1/16 cell
    cv2.fillPoly(mask, [np.round(pts * (1 << shift)).astype(np.int32)], 1, cv2.LINE_8, shift)


def compute_visibility(
    victim: Victim,
    debris: tuple[Debris, ...],
    res_m: float = VISIBILITY_RES_M,
    *,
    warm: bool = False,
) -> tuple[float, float, float]:
    """(visibility_pct, visible centroid north, east) from a top-down raster.

    ``warm``: of the skin and clothing (not the shoes) under no opaque debris (debris
    that lets heat through, ``heat_through`` > 0, does not hide it)."""
    parts = victim.parts()
    if warm:
        parts = [p for p in parts if p.role != "shoes"]
        debris = tuple(d for d in debris if d.heat_through == 0.0)
    allpts = np.vstack([p.polygon_ne_m for p in parts])
    n0, e0 = allpts.min(axis=0) - 0.05
    n1, e1 = allpts.max(axis=0) + 0.05
    rows, cols = math.ceil((n1 - n0) / res_m), math.ceil((e1 - e0) / res_m)
    body = np.zeros((rows, cols), np.uint8)
    for p in parts:
        _fill(body, p.polygon_ne_m, n0, e0, res_m)
    cover = np.zeros_like(body)
    for d in debris:
        poly = d.polygon
        if (poly[:, 0].max() < n0 or poly[:, 0].min() > n1) or (
            poly[:, 1].max() < e0 or poly[:, 1].min() > e1
        ):
            continue
        _fill(cover, poly, n0, e0, res_m)
    visible = (body == 1) & (cover == 0)
    total = int(body.sum())
    seen = int(visible.sum())
    pct = 100.0 * seen / total
    if seen == 0:
        return 0.0, victim.north_m, victim.east_m
    r, c = np.nonzero(visible)
    return pct, float(n0 + (r.mean() + 0.5) * res_m), float(e0 + (c.mean() + 0.5) * res_m)


@dataclass(frozen=True)
class World:
    size_m: tuple[float, float] = (12.0, 8.0)  # (north extent, east extent)
    floor: Floor = field(default_factory=Floor)
    debris: tuple[Debris, ...] = ()
    light_zones: tuple[LightZone, ...] = ()
    victims: tuple[Victim, ...] = ()
    origin: GlobalOrigin = DEFAULT_ORIGIN
    seed: int = 0
    name: str = ""
    route_ne_m: tuple[PointNE, ...] = ()  # empty: the default lawnmower
    start_ne_m: PointNE = (0.6, 0.6)
    start_heading_rad: float = 0.0
    warm_objects: tuple[WarmObject, ...] = ()

    def __post_init__(self) -> None:
        n, e = self.size_m
        if not (0 < n <= 200 and 0 < e <= 200):
            raise WorldError(f"size_m = {list(self.size_m)}: both extents must be in (0, 200]")
        if self.seed < 0:
            raise WorldError(f"seed = {self.seed}: must be >= 0")
        for what, points in (("start_ne_m", (self.start_ne_m,)), ("route_ne_m", self.route_ne_m)):
            for pn, pe in points:
                if not (0 <= pn <= n and 0 <= pe <= e):
                    raise WorldError(f"{what}: ({pn}, {pe}) is off the floor")
        if not math.isfinite(self.start_heading_rad):
            raise WorldError(f"start_heading = {self.start_heading_rad}: must be a finite angle")
        ids = [v.victim_id for v in self.victims]
        if len(set(ids)) != len(ids):
            raise WorldError(f"victims: duplicate victim_id in {ids}")
        for v in self.victims:
            if not (0 <= v.north_m <= n and 0 <= v.east_m <= e):
                raise WorldError(
                    f"victims[{v.victim_id}] at ({v.north_m}, {v.east_m}) is off the floor"
                )
        for w in self.warm_objects:
            if not (0 <= w.north_m <= n and 0 <= w.east_m <= e):
                raise WorldError(
                    f"warm_objects ({w.kind}) at ({w.north_m}, {w.east_m}) is off the floor"
                )
        done = []
        for v in self.victims:
            pct, vn, ve = compute_visibility(v, self.debris)
            warm_pct = compute_visibility(v, self.debris, warm=True)[0]
            done.append(
                dataclasses.replace(
                    v,
                    visibility_pct=pct,
                    visible_north_m=vn,
                    visible_east_m=ve,
                    warm_visibility_pct=warm_pct,
                )
            )
        object.__setattr__(self, "victims", tuple(done))

    def light_at(self, north_m: np.ndarray, east_m: np.ndarray) -> np.ndarray:
        """Fraction of full light at floor points (the darkest zone wins)."""
        light = np.full(np.broadcast(north_m, east_m).shape, self.floor.ambient_light, float)
        for z in self.light_zones:
            d = np.hypot(north_m - z.north_m, east_m - z.east_m)
            if z.edge_m > 0:
                w = np.clip((z.radius_m + z.edge_m / 2 - d) / z.edge_m, 0.0, 1.0)
            else:
                w = (d <= z.radius_m).astype(float)
            w = w * w * (3 - 2 * w)  # smoothstep
            zone = self.floor.ambient_light + (z.light - self.floor.ambient_light) * w
            light = np.minimum(light, zone)
        return light

    def victim(self, victim_id: int) -> Victim:
        for v in self.victims:
            if v.victim_id == victim_id:
                return v
        raise KeyError(victim_id)


def preset(name: str) -> World:
    """One of the preset scenarios (see PRESETS)."""
    if name not in PRESETS:
        raise WorldError(f"unknown preset {name!r}; presets: {', '.join(PRESETS)}")
    from scenarios.worldfile import load_world_text

    # Package data sits beside this module in both normal and editable installs.
    path = Path(__file__).resolve().parent / "presets" / f"{name}.toml"
    return load_world_text(path.read_text(encoding="utf-8"), f"preset {name}")


def load_world(path: Path) -> World:
    """Load a world file; WorldError names the file and the bad key."""
    from scenarios.worldfile import load_world as _load

    return _load(path)


def save_world(world: World, path: Path) -> None:
    from scenarios.worldfile import save_world as _save

    _save(world, path)


def generate_world(seed: int) -> World:
    """A random mixed world: 3-6 victims of all classes, look-alike debris, dark zones."""
    from scenarios.generate import generate

    world: World = generate(seed)
    return world
