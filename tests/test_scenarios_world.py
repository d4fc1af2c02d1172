"""The simulated world: presets, exact visibility, files, generation, determinism."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from fusion.types import Urgency
from scenarios.world import (
    PRESETS,
    Debris,
    Victim,
    World,
    WorldError,
    generate_world,
    load_world,
    preset,
    save_world,
)


def _victim(**kw: float) -> Victim:
    base = dict(
        victim_id=1,
        north_m=5.0,
        east_m=4.0,
        heading_rad=math.radians(30.0),
        height_m=1.75,
        skin_rgb=(198, 134, 66),
        top_rgb=(40, 110, 60),
        trousers_rgb=(50, 60, 90),
        left_arm_rad=math.radians(40.0),
        right_arm_rad=math.radians(10.0),
    )
    base.update(kw)
    return Victim(**base)  # type: ignore[arg-type]


def _monte_carlo_visibility(victim: Victim, debris: tuple[Debris, ...], n: int = 400_000) -> float:
    """Independent of the rasteriser: random points tested with matplotlib's point-in-polygon."""
    parts = [MplPath(p.polygon_ne_m) for p in victim.parts()]
    allpts = np.vstack([p.polygon_ne_m for p in victim.parts()])
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pts = np.random.default_rng(7).uniform(lo, hi, (n, 2))
    body = np.zeros(n, bool)
    for p in parts:
        body |= p.contains_points(pts)
    covered = np.zeros(n, bool)
    for d in debris:
        covered |= MplPath(d.polygon).contains_points(pts)
    return 100.0 * (body & ~covered).sum() / body.sum()


def test_visibility_of_a_partly_covered_victim_matches_an_independent_count() -> None:
    v = _victim()
    # A slab over the legs and hips, along the body axis, from the feet up.
    axis = v.heading_rad
    slab = Debris.box(
        "slab",
        (150, 150, 150),
        v.north_m - 0.45 * math.cos(axis),
        v.east_m - 0.45 * math.sin(axis),
        1.0,
        0.7,
        axis,
    )
    world = World(victims=(v,), debris=(slab,))
    got = world.victims[0].visibility_pct
    expected = _monte_carlo_visibility(v, (slab,))
    # 400k samples: the Monte Carlo standard error is ~0.1 percentage point; the
    # 2.5 mm raster's edge error is of the same order.
    assert got == pytest.approx(expected, abs=0.6)
    assert 20.0 < got < 80.0  # really partly covered
    # The uncovered part is towards the head: its centroid moved up the body axis.
    vis = world.victims[0]
    along = (vis.visible_north_m - v.north_m) * math.cos(axis) + (
        vis.visible_east_m - v.east_m
    ) * math.sin(axis)
    assert along > 0.1


def test_uncovered_and_fully_covered_victims() -> None:
    v = _victim()
    assert World(victims=(v,)).victims[0].visibility_pct == 100.0
    lid = Debris.box("slab", (150, 150, 150), v.north_m, v.east_m, 3.0, 3.0, 0.0)
    buried = World(victims=(v,), debris=(lid,)).victims[0]
    assert buried.visibility_pct == 0.0
    assert buried.urgency is Urgency.CRITICAL


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("light", [Urgency.LIGHT]),
        ("medium", [Urgency.MEDIUM]),
        ("critical", [Urgency.CRITICAL]),
        ("mixed", [Urgency.LIGHT, Urgency.MEDIUM, Urgency.CRITICAL]),
        ("empty", []),
        ("skin_debris", []),
    ],
)
def test_presets_give_the_classes_their_names_say(name: str, expected: list[Urgency]) -> None:
    world = preset(name)
    assert sorted(v.urgency for v in world.victims) == expected
    assert world.size_m == (12.0, 8.0)


def test_dark_preset_puts_its_victim_in_a_dark_zone() -> None:
    world = preset("dark")
    (v,) = world.victims
    light = float(world.light_at(np.array(v.north_m), np.array(v.east_m)))
    assert 0.05 <= light <= 0.10


def test_skin_debris_preset_has_skin_coloured_debris_and_no_victim() -> None:
    world = preset("skin_debris")
    assert world.victims == ()
    assert sum(d.kind == "lookalike_skin" for d in world.debris) >= 3


def test_presets_list_is_the_seven_scenarios_and_four_thermal_ones() -> None:
    assert len(PRESETS) == 11
    assert sum(name.startswith("thermal_") for name in PRESETS) == 4
    for name in PRESETS:
        preset(name)
    with pytest.raises(WorldError, match="unknown preset 'nope'"):
        preset("nope")


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    world = generate_world(11)
    path = tmp_path / "w.toml"
    save_world(world, path)
    back = load_world(path)
    assert back.name == world.name and back.seed == world.seed
    assert len(back.victims) == len(world.victims) and back.debris == world.debris
    assert {v.sleeves for v in world.victims} == {"long", "short"}  # both kinds saved
    for a, b in zip(world.victims, back.victims, strict=True):
        assert (a.victim_id, a.north_m, a.east_m, a.top_rgb, a.sleeves) == (
            b.victim_id,
            b.north_m,
            b.east_m,
            b.top_rgb,
            b.sleeves,
        )
        assert a.heading_rad == pytest.approx(b.heading_rad, abs=1e-9)
        # Visibility is recomputed on load, from the same geometry.
        assert a.visibility_pct == pytest.approx(b.visibility_pct, abs=0.05)


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("size_m = [12.0]", "size_m"),
        (
            '[[victims]]\nvictim_id = 1\nnorth_m = 3.0\neast_m = 2.0\nheading_deg = 0.0\nheight_m = 1.7\nskin = "#aabbcc"\ntop = "blue"\ntrousers = "#000000"',
            "victims[0].top",
        ),
        (
            '[[victims]]\nvictim_id = 1\nnorth_m = 3.0\neast_m = 2.0\nheading_deg = 0.0\nskin = "#aabbcc"\ntop = "#000000"\ntrousers = "#000000"',
            "victims[0].height_m: missing",
        ),
        (
            '[[debris]]\nkind = "slab"\ncolour = "#808080"\npolygon_ne_m = [[0, 0], [1, 1]]',
            "debris[0].polygon_ne_m",
        ),
        ("[floor]\ncolor = '#808080'", "floor.color: unknown key"),
        (
            '[[victims]]\nvictim_id = 1\nnorth_m = 3.0\neast_m = 2.0\nheading_deg = 0.0\nheight_m = 1.7\nskin = "#aabbcc"\ntop = "#000000"\ntrousers = "#000000"\nsleeves = "none"',
            "victims[1].sleeves = 'none': one of long, short",
        ),
        ("size_m = [12.0, 8.0", "not valid TOML"),
        # Values the dataclasses refuse are named with the file too (they were not).
        ("[floor]\ntexture_contrast = 2.0", "floor.texture_contrast = 2.0: must be in [0, 1]"),
        ("seed = -1", "seed = -1: must be >= 0"),
        ("start_ne_m = [50.0, 1.0]", "start_ne_m: (50.0, 1.0) is off the floor"),
        ("route_ne_m = [[1.0, 1.0], [nan, 2.0]]", "route_ne_m: (nan, 2.0) is off the floor"),
        (
            "[[light_zones]]\nnorth_m = 1e308\neast_m = 1.0\nradius_m = 1.0\nlight = 0.5",
            "must lie within +-1000 m",
        ),
    ],
)
def test_bad_world_file_names_the_key(tmp_path: Path, text: str, needle: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text + "\n")
    with pytest.raises(WorldError) as err:
        load_world(path)
    assert needle in str(err.value)
    assert str(path) in str(err.value)


def test_missing_world_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(WorldError, match="cannot read world file"):
        load_world(tmp_path / "none.toml")


def test_generated_worlds_are_deterministic_and_varied() -> None:
    a, b, c = generate_world(4), generate_world(4), generate_world(5)
    assert a == b
    assert a != c
    for w in (a, c, generate_world(6)):
        assert 3 <= len(w.victims) <= 6
        assert any(d.kind == "lookalike_skin" for d in w.debris)
        assert any(d.kind == "lookalike_cloth" for d in w.debris)
        assert any(z.light <= 0.10 for z in w.light_zones)
    classes = {v.urgency for s in range(6) for v in generate_world(s).victims}
    assert classes == set(Urgency)
    colours = {v.top_rgb for s in range(6) for v in generate_world(s).victims}
    assert len(colours) >= 6  # a wide palette, not only blue and red
