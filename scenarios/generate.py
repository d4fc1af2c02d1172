"""Random mixed worlds: seed -> World, deterministic.

3-6 victims of every urgency class (each partly buried by a slab whose reach along
the body is searched until the exact visibility lands in the class wanted): adults
and children, on the back, the side, face down or curled, skin from very dark to
very pale, clothing plain, patterned or hi-vis, grey, brown, black or dusty, long
or short sleeves, with dust on skin and clothes; ordinary rubble (concrete, wood,
metal, cartons, pallets, plasterboard, tarps, cables), racking uprights along the
walls, look-alike debris in skin and clothing colours, and one or two dark zones.
"""

from __future__ import annotations

import math

import numpy as np

from fusion.types import Urgency
from scenarios.body3d import PATTERNS, POSTURES, SLEEVES, Sleeves
from scenarios.world import RGB, Debris, LightZone, Victim, World, compute_visibility

SKIN: tuple[RGB, ...] = (
    (255, 219, 172),
    (241, 194, 125),
    (224, 172, 105),
    (198, 134, 66),
    (168, 110, 75),
    (141, 85, 36),
    (112, 70, 40),
    (92, 58, 30),
    (59, 34, 25),
)
CLOTHING: tuple[RGB, ...] = (
    (240, 150, 30),  # hi-vis orange
    (220, 200, 40),  # hi-vis yellow
    (30, 40, 110),  # navy
    (60, 90, 150),  # denim
    (40, 110, 60),  # green
    (90, 100, 60),  # olive
    (200, 40, 40),  # red
    (120, 40, 120),  # purple
    (210, 210, 205),  # white, dusty
    (35, 35, 38),  # black
    (120, 120, 125),  # grey
    (110, 80, 50),  # brown
    (220, 120, 150),  # pink
    (30, 130, 130),  # teal
    (180, 160, 120),  # khaki
    (150, 145, 135),  # dusty grey
    (95, 80, 65),  # dusty brown
)
HAIR: tuple[RGB, ...] = (
    (20, 16, 14),
    (60, 40, 25),
    (110, 80, 45),
    (200, 170, 110),
    (150, 150, 150),
)
TROUSERS: tuple[RGB, ...] = (
    (50, 60, 90),
    (30, 30, 30),
    (80, 80, 80),
    (110, 100, 70),
    (60, 50, 40),
    (60, 90, 150),
)
CONCRETE: tuple[RGB, ...] = ((142, 139, 133), (169, 165, 157), (111, 108, 104), (128, 122, 112))
WOOD: tuple[RGB, ...] = ((139, 107, 74), (160, 120, 79), (94, 69, 48))
CARDBOARD: tuple[RGB, ...] = ((176, 137, 92), (160, 124, 80), (190, 160, 120))
PLASTERBOARD: tuple[RGB, ...] = ((215, 212, 204), (190, 188, 180))
TARP: tuple[RGB, ...] = ((40, 80, 150), (60, 110, 70), (150, 150, 150))
METAL: tuple[RGB, ...] = ((90, 101, 112), (123, 133, 145), (138, 75, 42))
LOOKALIKE_SKIN: tuple[RGB, ...] = (
    (217, 163, 122),
    (232, 184, 150),
    (201, 140, 107),
    (180, 120, 80),
    (150, 95, 60),
)
LOOKALIKE_CLOTH: tuple[RGB, ...] = ((42, 92, 170), (178, 42, 42), (240, 192, 32), (40, 120, 60))

RUBBLE_KINDS = (
    "slab",
    "piece",
    "plank",
    "beam",
    "carton",
    "pallet",
    "plasterboard",
    "tarp",
    "cable",
)
_PALETTE = {
    "slab": CONCRETE,
    "plank": WOOD,
    "beam": METAL,
    "carton": CARDBOARD,
    "pallet": WOOD,
    "plasterboard": PLASTERBOARD,
    "tarp": TARP,
}

_TARGET_PCT = {
    Urgency.LIGHT: (60.0, 92.0),
    Urgency.MEDIUM: (18.0, 42.0),
    Urgency.CRITICAL: (2.5, 8.0),
}


def _pick(rng: np.random.Generator, palette: tuple[RGB, ...]) -> RGB:
    return palette[int(rng.integers(len(palette)))]


def _r(x: float) -> float:
    return round(float(x), 4)


def _irregular(
    rng: np.random.Generator, n: float, e: float, size_m: float
) -> tuple[tuple[float, float], ...]:
    k = int(rng.integers(5, 9))
    angles = np.sort(rng.uniform(0, 2 * math.pi, k))
    radii = size_m / 2 * rng.uniform(0.55, 1.0, k)
    return tuple(
        (_r(n + r * math.cos(a)), _r(e + r * math.sin(a)))
        for a, r in zip(angles, radii, strict=True)
    )


def _bury(rng: np.random.Generator, v: Victim, urgency: Urgency) -> list[Debris]:
    """Slab(s) over the body from the feet (or the head) so visibility falls in the class."""
    if urgency is Urgency.LIGHT and rng.random() < 0.3:
        return []
    lo_pct, hi_pct = _TARGET_PCT[urgency]
    return bury(rng, v, rng.uniform(lo_pct, hi_pct), (lo_pct, hi_pct))


def bury(
    rng: np.random.Generator,
    v: Victim,
    target_pct: float,
    accept_pct: tuple[float, float] | None = None,
) -> list[Debris]:
    """One slab over the body so that about ``target_pct`` of it stays visible.

    The slab covers the body axis from beyond one end (the feet, or the head for a
    victim more than 10 % visible, three times in ten) up to a reach found by
    bisection; widths are tried from body-wide to wider than spread arms until the
    visibility lands in ``accept_pct`` (default: target +- 20 % of it).
    """
    lo_pct, hi_pct = accept_pct or (0.8 * target_pct, 1.2 * target_pct)
    critical = target_pct < 10.0
    from_head = not critical and rng.random() < 0.3
    skew = rng.normal(0.0, math.radians(8.0))
    # A critical victim's slab is wide enough to reach over spread arms (a hand or the
    # face stays out); others are body-wide.
    first = rng.uniform(0.75, 1.1) if critical else rng.uniform(0.42, 0.6)
    colour = _pick(rng, CONCRETE + WOOD)
    axis = v.heading_rad + (math.pi if from_head else 0.0)

    def slab(reach: float, width: float) -> Debris:
        # Covers the body axis from beyond the far end up to `reach` (metres, body frame).
        start = -0.6 * v.height_m
        length = reach - start
        mid = start + length / 2
        n = v.north_m + math.cos(axis) * mid
        e = v.east_m + math.sin(axis) * mid
        return Debris.box("slab", colour, _r(n), _r(e), _r(length), _r(width), axis + skew)

    best = slab(0.58 * v.height_m, first * v.height_m)
    for width in (first * v.height_m, 1.2 * v.height_m, 1.4 * v.height_m):
        lo, hi = -0.5 * v.height_m, 0.58 * v.height_m
        for _ in range(18):  # bisection on the reach: visibility falls as the slab grows
            mid = (lo + hi) / 2
            pct, _, _ = compute_visibility(v, (slab(mid, width),))
            if pct > target_pct:
                lo = mid
            else:
                hi = mid
        best = slab(hi, width)
        if lo_pct <= compute_visibility(v, (best,))[0] <= hi_pct:
            break
    return [best]


def _sleeves(seed: int, victim_id: int) -> Sleeves:
    """Long or short sleeves, even odds, from a random stream of their own (the
    world's other draws do not depend on it)."""
    return SLEEVES[int(np.random.default_rng([seed, 0x51E, victim_id]).integers(2))]


def generate(seed: int, size_m: tuple[float, float] = (12.0, 8.0)) -> World:
    """A random mixed world for the seed (see the module docstring)."""
    rng = np.random.default_rng([seed, 0x6E4])
    n_victims = int(rng.integers(3, 7))
    classes = [Urgency.LIGHT, Urgency.MEDIUM, Urgency.CRITICAL]
    wanted = [classes[i % 3] for i in range(n_victims)]
    rng.shuffle(wanted)
    victims: list[Victim] = []
    debris: list[Debris] = []
    for i, urgency in enumerate(wanted, start=1):
        for _ in range(200):
            n = rng.uniform(1.2, size_m[0] - 1.2)
            e = rng.uniform(1.2, size_m[1] - 1.2)
            if all(math.hypot(n - o.north_m, e - o.east_m) > 2.2 for o in victims):
                break
        child = rng.random() < 0.2
        v = Victim(
            victim_id=i,
            north_m=_r(n),
            east_m=_r(e),
            heading_rad=_r(rng.uniform(-math.pi, math.pi)),
            height_m=_r(rng.uniform(1.1, 1.45) if child else rng.uniform(1.5, 1.9)),
            skin_rgb=_pick(rng, SKIN),
            top_rgb=_pick(rng, CLOTHING),
            trousers_rgb=_pick(rng, TROUSERS),
            hair_rgb=_pick(rng, HAIR),
            posture=POSTURES[int(rng.integers(len(POSTURES)))],
            pattern=PATTERNS[int(rng.choice(len(PATTERNS), p=[0.5, 0.15, 0.1, 0.15, 0.1]))],
            dust=_r(rng.uniform(0.0, 0.6)),
            left_arm_rad=_r(math.radians(rng.uniform(0, 80))),
            right_arm_rad=_r(math.radians(rng.uniform(0, 80))),
            leg_spread_rad=_r(math.radians(rng.uniform(0, 10))),
            sleeves=_sleeves(seed, i),
        )
        victims.append(v)
        debris += _bury(rng, v, urgency)

    def clear_of_victims(n: float, e: float, r: float) -> bool:
        return all(math.hypot(n - v.north_m, e - v.east_m) > r + 1.1 for v in victims)

    def spot(r: float) -> tuple[float, float]:
        for _ in range(200):
            n, e = rng.uniform(0.4, size_m[0] - 0.4), rng.uniform(0.4, size_m[1] - 0.4)
            if clear_of_victims(n, e, r):
                break
        return float(n), float(e)

    rubble: list[Debris] = []
    for _ in range(int(rng.integers(10, 18))):
        kind = RUBBLE_KINDS[int(rng.integers(len(RUBBLE_KINDS)))]
        size = rng.uniform(0.3, 1.2)
        n, e = spot(size / 2)
        if kind == "piece":
            rubble.append(Debris("piece", _pick(rng, CONCRETE), _irregular(rng, n, e, size)))
        elif kind == "cable":
            rubble.append(
                Debris.box(
                    "cable", (25, 25, 28), _r(n), _r(e), _r(size * 2), 0.02, rng.uniform(0, math.pi)
                )
            )
        else:
            palette = _PALETTE[kind]
            narrow = kind in ("plank", "beam")
            w = rng.uniform(0.1, 0.22) if narrow else size * rng.uniform(0.5, 0.9)
            rubble.append(
                Debris.box(
                    kind,
                    _pick(rng, palette),
                    _r(n),
                    _r(e),
                    _r(size * 1.4),
                    _r(w),
                    rng.uniform(0, math.pi),
                )
            )
    for _ in range(int(rng.integers(2, 6))):
        size = rng.uniform(0.12, 0.4)
        n, e = spot(size / 2)
        rubble.append(
            Debris("lookalike_skin", _pick(rng, LOOKALIKE_SKIN), _irregular(rng, n, e, size))
        )
    for _ in range(int(rng.integers(2, 5))):
        size = rng.uniform(0.3, 0.8)
        n, e = spot(size / 2)
        rubble.append(
            Debris.box(
                "lookalike_cloth",
                _pick(rng, LOOKALIKE_CLOTH),
                _r(n),
                _r(e),
                _r(size),
                _r(size * 0.7),
                rng.uniform(0, math.pi),
            )
        )
    for k in range(int(rng.integers(2, 5))):  # racking uprights along the long walls
        e = 0.15 if k % 2 == 0 else size_m[1] - 0.15
        n = rng.uniform(0.5, size_m[0] - 0.5)
        rubble.append(Debris.box("racking", _pick(rng, METAL), _r(n), _r(e), 0.09, 0.09, 0.0))
    zones = []
    for _ in range(int(rng.integers(1, 3))):
        anchor = victims[int(rng.integers(len(victims)))]
        zones.append(
            LightZone(
                _r(anchor.north_m + rng.normal(0, 0.5)),
                _r(anchor.east_m + rng.normal(0, 0.5)),
                _r(rng.uniform(1.5, 2.5)),
                _r(rng.uniform(0.05, 0.10)),
                0.8,
            )
        )
    return World(
        size_m=size_m,
        debris=tuple(rubble + debris),
        light_zones=tuple(zones),
        victims=tuple(victims),
        seed=seed,
        name=f"generated-{seed}",
    )
