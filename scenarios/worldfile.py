"""World files: TOML, one table per kind of thing, angles in degrees for people.

    format = "rescue-sim-world/1"
    name = "medium"
    seed = 0
    size_m = [12.0, 8.0]            # north extent, east extent
    start_ne_m = [0.6, 0.6]
    start_heading_deg = 0.0
    route_ne_m = [[0.6, 0.6], [11.4, 0.6]]   # optional; default a lawnmower

    [origin]   lat_deg, lon_deg, alt_m
    [floor]    colour = "#7d7870", texture_contrast, ambient_light,
               temperature_c (ambient, 18), temperature_variation_c (0.5)
    [[debris]] kind, colour, polygon_ne_m = [[n, e], ...], heat_through (0..1;
               default by kind: cloth 0.55, dust 0.7, others 0)
    [[warm_objects]] kind (radiator | pipe | machinery | dog | heated_floor |
               imprint), north_m, east_m, heading_deg, length_m, width_m,
               temperature_c, height_m, elevation_m, colour, fade_s, age_s
               (every key but kind, north_m and east_m defaults by kind)
    [[light_zones]] north_m, east_m, radius_m, light, edge_m
    [[victims]] victim_id, north_m, east_m, heading_deg, height_m, skin, top,
                trousers, shoes, hair, posture, pattern, sleeves ("long" or
                "short"), dust, left_arm_deg, right_arm_deg, leg_spread_deg,
                skin_c (34)

``visibility_pct`` and ``urgency`` are written into [[victims]] for people to read
and are recomputed (not trusted) on load. Unknown keys are errors.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fusion.types import GlobalOrigin
from scenarios.world import (
    WARM_DEFAULTS,
    Debris,
    Floor,
    LightZone,
    Victim,
    WarmObject,
    World,
    WorldError,
    hex_from_rgb,
    rgb_from_hex,
    warm_object,
)

FORMAT = "rescue-sim-world/1"
_TOP_KEYS = {
    "format",
    "name",
    "seed",
    "size_m",
    "start_ne_m",
    "start_heading_deg",
    "route_ne_m",
    "origin",
    "floor",
    "debris",
    "light_zones",
    "victims",
    "warm_objects",
}
_VICTIM_KEYS = {
    "victim_id",
    "north_m",
    "east_m",
    "heading_deg",
    "height_m",
    "skin",
    "top",
    "trousers",
    "shoes",
    "hair",
    "posture",
    "pattern",
    "sleeves",
    "dust",
    "left_arm_deg",
    "right_arm_deg",
    "leg_spread_deg",
    "skin_c",
    "visibility_pct",
    "warm_visibility_pct",
    "urgency",
}
_WARM_KEYS = {
    "kind",
    "north_m",
    "east_m",
    "heading_deg",
    "length_m",
    "width_m",
    "temperature_c",
    "height_m",
    "elevation_m",
    "colour",
    "fade_s",
    "age_s",
}


class _Table:
    """Typed access to one TOML table that names the key in every error."""

    def __init__(self, data: Any, where: str, allowed: set[str]) -> None:
        if not isinstance(data, dict):
            raise WorldError(f"{where}: expected a table")
        unknown = sorted(set(data) - allowed)
        if unknown:
            name = unknown[0] if unknown[0].isprintable() else repr(unknown[0])  # one line
            raise WorldError(f"{where}.{name}: unknown key; allowed: {', '.join(sorted(allowed))}")
        self.data, self.where = data, where

    def _get(self, key: str, default: Any, check: Callable[[Any], bool], what: str) -> Any:
        if key not in self.data:
            if default is _REQUIRED:
                raise WorldError(f"{self.where}.{key}: missing (expected {what})")
            return default
        value = self.data[key]
        if not check(value):
            raise WorldError(f"{self.where}.{key} = {value!r}: expected {what}")
        return value

    def num(self, key: str, default: Any = None) -> float:
        value = self._get(
            key,
            _REQUIRED if default is None else default,
            lambda v: isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v),
            "a number",
        )
        return float(value)

    def integer(self, key: str, default: Any = None) -> int:
        ok = lambda v: isinstance(v, int) and not isinstance(v, bool)  # noqa: E731
        return int(self._get(key, _REQUIRED if default is None else default, ok, "an integer"))

    def text(self, key: str, default: Any = None) -> str:
        ok = lambda v: isinstance(v, str)  # noqa: E731
        return str(self._get(key, _REQUIRED if default is None else default, ok, "a string"))

    def colour(self, key: str, default: Any = None) -> tuple[int, int, int]:
        text = self.text(key, default)
        return rgb_from_hex(text, f"{self.where}.{key}")

    def points(
        self, key: str, default: Any = None, at_least: int = 1
    ) -> tuple[tuple[float, float], ...]:
        def ok(v: Any) -> bool:
            return (
                isinstance(v, list)
                and len(v) >= at_least
                and all(
                    isinstance(p, list)
                    and len(p) == 2
                    and all(isinstance(x, int | float) and not isinstance(x, bool) for x in p)
                    for p in v
                )
            )

        value = self._get(
            key,
            _REQUIRED if default is None else default,
            ok,
            f"a list of at least {at_least} [north_m, east_m] pairs",
        )
        return tuple((float(p[0]), float(p[1])) for p in value)


_REQUIRED = object()


def _pair(table: _Table, key: str, default: tuple[float, float]) -> tuple[float, float]:
    value = table.data.get(key, list(default))
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in value)
    )
    if not ok:
        raise WorldError(f"{table.where}.{key} = {value!r}: expected [number, number]")
    return (float(value[0]), float(value[1]))


def _list_of_tables(data: dict[str, Any], key: str) -> list[Any]:
    value = data.get(key, [])
    if not isinstance(value, list):
        raise WorldError(f"{key}: expected an array of tables [[{key}]]")
    return value


def _victim(t: _Table) -> Victim:
    """The victim a [[victims]] table describes; a value no victim can have (a height,
    posture, pattern or sleeves out of range) is named with the file and table."""
    fields: dict[str, Any] = dict(
        victim_id=t.integer("victim_id"),
        north_m=t.num("north_m"),
        east_m=t.num("east_m"),
        heading_rad=math.radians(t.num("heading_deg")),
        height_m=t.num("height_m"),
        skin_rgb=t.colour("skin"),
        top_rgb=t.colour("top"),
        trousers_rgb=t.colour("trousers"),
        shoes_rgb=t.colour("shoes", "#282422"),
        hair_rgb=t.colour("hair", "#261e18"),
        posture=t.text("posture", "back"),
        pattern=t.text("pattern", "plain"),
        sleeves=t.text("sleeves", "long"),
        dust=t.num("dust", 0.0),
        left_arm_rad=math.radians(t.num("left_arm_deg", 9.0)),
        right_arm_rad=math.radians(t.num("right_arm_deg", 9.0)),
        leg_spread_rad=math.radians(t.num("leg_spread_deg", 3.0)),
        skin_c=t.num("skin_c", 34.0),
    )
    try:
        return Victim(**fields)
    except WorldError as exc:
        raise WorldError(f"{t.where}: {exc}") from None


def _warm(t: _Table) -> WarmObject:
    """The warm object a [[warm_objects]] table describes, its kind's defaults filling
    in every key left out."""
    kind = t.text("kind")
    if kind not in WARM_DEFAULTS:
        raise WorldError(f"{t.where}.kind = {kind!r}: one of {', '.join(WARM_DEFAULTS)}")
    temp, length, width, height, elevation, colour = WARM_DEFAULTS[kind]
    try:
        return warm_object(
            kind,
            t.num("north_m"),
            t.num("east_m"),
            heading_rad=math.radians(t.num("heading_deg", 0.0)),
            length_m=t.num("length_m", length),
            width_m=t.num("width_m", width),
            temperature_c=t.num("temperature_c", temp),
            height_m=t.num("height_m", height),
            elevation_m=t.num("elevation_m", elevation),
            colour_rgb=t.colour("colour", hex_from_rgb(colour)),
            fade_s=t.num("fade_s", 90.0),
            age_s=t.num("age_s", 0.0),
        )
    except WorldError as exc:
        raise WorldError(f"{t.where}: {exc}") from None


def world_from_dict(data: dict[str, Any], where: str = "world") -> World:
    """The World a parsed world file describes; WorldError naming ``where`` (the file)
    and the key or table at fault."""
    try:
        return _world(data, where)
    except WorldError as exc:
        if str(exc).startswith(where):
            raise
        raise WorldError(f"{where}: {exc}") from None


def _world(data: dict[str, Any], where: str) -> World:
    top = _Table(data, where, _TOP_KEYS)
    fmt = top.text("format", FORMAT)
    if fmt != FORMAT:
        raise WorldError(f"{where}.format = {fmt!r}: this program reads {FORMAT!r}")
    o = _Table(data.get("origin", {}), f"{where}.origin", {"lat_deg", "lon_deg", "alt_m"})
    f = _Table(
        data.get("floor", {}),
        f"{where}.floor",
        {
            "colour",
            "texture_contrast",
            "ambient_light",
            "temperature_c",
            "temperature_variation_c",
        },
    )
    try:
        origin = GlobalOrigin(
            o.num("lat_deg", 40.071), o.num("lon_deg", -105.2296), o.num("alt_m", 1580.0)
        )
    except ValueError as exc:
        raise WorldError(f"{where}.origin: {exc}") from None
    floor = Floor(
        f.colour("colour", "#7d7870"),
        f.num("texture_contrast", 0.18),
        f.num("ambient_light", 1.0),
        f.num("temperature_c", 18.0),
        f.num("temperature_variation_c", 0.5),
    )
    debris = []
    for i, d in enumerate(_list_of_tables(data, "debris")):
        t = _Table(d, f"{where}.debris[{i}]", {"kind", "colour", "polygon_ne_m", "heat_through"})
        try:
            debris.append(
                Debris(
                    t.text("kind"),
                    t.colour("colour"),
                    t.points("polygon_ne_m", None, 3),
                    t.num("heat_through", math.nan) if "heat_through" in t.data else math.nan,
                )
            )
        except WorldError as exc:
            if str(exc).startswith(t.where):
                raise
            raise WorldError(f"{t.where}: {exc}") from None
    zones = []
    for i, z in enumerate(_list_of_tables(data, "light_zones")):
        t = _Table(
            z, f"{where}.light_zones[{i}]", {"north_m", "east_m", "radius_m", "light", "edge_m"}
        )
        zones.append(
            LightZone(
                t.num("north_m"),
                t.num("east_m"),
                t.num("radius_m"),
                t.num("light"),
                t.num("edge_m", 0.5),
            )
        )
    victims = [
        _victim(_Table(v, f"{where}.victims[{i}]", _VICTIM_KEYS))
        for i, v in enumerate(_list_of_tables(data, "victims"))
    ]
    warm = [
        _warm(_Table(w, f"{where}.warm_objects[{i}]", _WARM_KEYS))
        for i, w in enumerate(_list_of_tables(data, "warm_objects"))
    ]
    route = top.points("route_ne_m", [], 0)
    return World(
        size_m=_pair(top, "size_m", (12.0, 8.0)),
        floor=floor,
        debris=tuple(debris),
        light_zones=tuple(zones),
        victims=tuple(victims),
        origin=origin,
        seed=top.integer("seed", 0),
        name=top.text("name", ""),
        route_ne_m=route,
        start_ne_m=_pair(top, "start_ne_m", (0.6, 0.6)),
        start_heading_rad=math.radians(top.num("start_heading_deg", 0.0)),
        warm_objects=tuple(warm),
    )


def load_world_text(text: str, where: str) -> World:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise WorldError(f"{where}: not valid TOML: {exc}") from None
    return world_from_dict(data, where)


def load_world(path: Path) -> World:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise WorldError(f"{path}: cannot read world file: {exc}") from None
    return load_world_text(text, str(path))


# -- writing ------------------------------------------------------------------------


def _f(x: float) -> str:
    text = repr(round(float(x), 4))
    return text if ("." in text or "e" in text) else text + ".0"


def _deg(x_rad: float) -> str:
    """Degrees at full precision, so a saved world loads back to the same radians."""
    return repr(math.degrees(x_rad))


def _pts(points: tuple[tuple[float, float], ...]) -> str:
    return "[" + ", ".join(f"[{_f(n)}, {_f(e)}]" for n, e in points) + "]"


def world_to_toml(world: World) -> str:
    lines = [
        f'format = "{FORMAT}"',
        f"name = {_quote(world.name)}",
        f"seed = {world.seed}",
        f"size_m = [{_f(world.size_m[0])}, {_f(world.size_m[1])}]",
        f"start_ne_m = [{_f(world.start_ne_m[0])}, {_f(world.start_ne_m[1])}]",
        f"start_heading_deg = {_deg(world.start_heading_rad)}",
    ]
    if world.route_ne_m:
        lines.append(f"route_ne_m = {_pts(world.route_ne_m)}")
    o = world.origin
    lines += [
        "",
        "[origin]",
        f"lat_deg = {o.lat_deg!r}",
        f"lon_deg = {o.lon_deg!r}",
        f"alt_m = {_f(o.alt_m)}",
    ]
    fl = world.floor
    lines += [
        "",
        "[floor]",
        f'colour = "{hex_from_rgb(fl.colour_rgb)}"',
        f"texture_contrast = {_f(fl.texture_contrast)}",
        f"ambient_light = {_f(fl.ambient_light)}",
        f"temperature_c = {_f(fl.temperature_c)}",
        f"temperature_variation_c = {_f(fl.temperature_variation_c)}",
    ]
    for z in world.light_zones:
        lines += [
            "",
            "[[light_zones]]",
            f"north_m = {_f(z.north_m)}",
            f"east_m = {_f(z.east_m)}",
            f"radius_m = {_f(z.radius_m)}",
            f"light = {_f(z.light)}",
            f"edge_m = {_f(z.edge_m)}",
        ]
    for v in world.victims:
        lines += [
            "",
            "[[victims]]",
            f"victim_id = {v.victim_id}",
            f"north_m = {_f(v.north_m)}",
            f"east_m = {_f(v.east_m)}",
            f"heading_deg = {_deg(v.heading_rad)}",
            f"height_m = {_f(v.height_m)}",
            f'skin = "{hex_from_rgb(v.skin_rgb)}"',
            f'top = "{hex_from_rgb(v.top_rgb)}"',
            f'trousers = "{hex_from_rgb(v.trousers_rgb)}"',
            f'shoes = "{hex_from_rgb(v.shoes_rgb)}"',
            f'hair = "{hex_from_rgb(v.hair_rgb)}"',
            f'posture = "{v.posture}"',
            f'pattern = "{v.pattern}"',
            f'sleeves = "{v.sleeves}"',
            f"dust = {_f(v.dust)}",
            f"left_arm_deg = {_deg(v.left_arm_rad)}",
            f"right_arm_deg = {_deg(v.right_arm_rad)}",
            f"leg_spread_deg = {_deg(v.leg_spread_rad)}",
            f"skin_c = {_f(v.skin_c)}",
            f"visibility_pct = {_f(v.visibility_pct)}  # computed, not read",
            f"warm_visibility_pct = {_f(v.warm_visibility_pct)}  # computed, not read",
            f'urgency = "{v.urgency.name}"  # computed, not read',
        ]
    for d in world.debris:
        lines += [
            "",
            "[[debris]]",
            f'kind = "{d.kind}"',
            f'colour = "{hex_from_rgb(d.colour_rgb)}"',
            f"polygon_ne_m = {_pts(d.polygon_ne_m)}",
        ]
        if d.heat_through > 0 or d.kind in ("cloth", "dust"):
            lines.append(f"heat_through = {_f(d.heat_through)}")
    for w in world.warm_objects:
        lines += [
            "",
            "[[warm_objects]]",
            f'kind = "{w.kind}"',
            f"north_m = {_f(w.north_m)}",
            f"east_m = {_f(w.east_m)}",
            f"heading_deg = {_deg(w.heading_rad)}",
            f"length_m = {_f(w.length_m)}",
            f"width_m = {_f(w.width_m)}",
            f"temperature_c = {_f(w.temperature_c)}",
            f"height_m = {_f(w.height_m)}",
            f"elevation_m = {_f(w.elevation_m)}",
            f'colour = "{hex_from_rgb(w.colour_rgb)}"',
            f"fade_s = {_f(w.fade_s)}",
            f"age_s = {_f(w.age_s)}",
        ]
    return "\n".join(lines) + "\n"


def _quote(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def save_world(world: World, path: Path) -> None:
    Path(path).write_text(world_to_toml(world), encoding="utf-8")
