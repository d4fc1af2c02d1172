"""Fuzz world files, rescue-sim's entry point (`rescue-sim record/demo --world FILE`):
any value at any key of a saved preset, keys left out and unknown keys give a World
the simulator can use, or one WorldError line, never another exception. A second
base holds the thermal keys: thin cover on victims, skin temperatures, every kind
of warm object."""

from __future__ import annotations

import copy
import dataclasses
import math
import tomllib
from typing import Any

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fusion.types import PoseSample
from scenarios.camera import VEHICLE_HEIGHT_M, default_camera
from scenarios.render import Renderer
from scenarios.thermal import ThermalRenderer
from scenarios.world import WorldError, preset
from scenarios.worldfile import world_from_dict, world_to_toml
from tests.jsonfuzz import NewKey, fuzz_settings, json_values

BASE = tomllib.loads(world_to_toml(preset("mixed")))
Place = tuple[str | int, ...]


def _places(data: Any, prefix: Place = ()) -> list[Place]:
    """Every key path of the document, into its tables and arrays of tables."""
    out: list[Place] = []
    items = data.items() if isinstance(data, dict) else enumerate(data)
    for key, value in items:
        out.append((*prefix, key))
        if isinstance(value, dict) or (
            isinstance(value, list) and value and isinstance(value[0], (dict, list))
        ):
            out += _places(value, (*prefix, key))
    return out


PLACES = _places(BASE)
THERMAL_BASE = tomllib.loads(
    world_to_toml(
        dataclasses.replace(
            preset("thermal_covered"),
            warm_objects=preset("thermal_warm_things").warm_objects,
        )
    )
)
THERMAL_PLACES = _places(THERMAL_BASE)
# What a TOML file can hold (no None), and values near the edges of what keys take.
EDGES: list[Any] = [0, -1, 2**63 - 1, -(2**63), 1e308, -1e308, 1e-308, math.nan, math.inf, ""]
POINTS: list[Any] = [[1e308, 1e308], [0.0, 0.0], [[0, 0], [0, 0], [0, 0]], [[0, 0], [1e308, 0]]]
toml_values = json_values.filter(lambda v: v is not None) | st.sampled_from([*EDGES, *POINTS])


def _edit(data: Any, place: Place, value: Any) -> None:
    parent = data
    for key in place[:-1]:
        try:
            parent = parent[key]
        except (KeyError, IndexError, TypeError):
            return
    if not isinstance(parent, (dict, list)):
        return
    last = place[-1]
    if isinstance(parent, list):
        if isinstance(last, int) and last < len(parent):
            if value is KeyError:
                del parent[last]
            elif not isinstance(value, NewKey):
                parent[last] = value
        return
    if value is KeyError:
        parent.pop(last, None)  # a key left out
    elif isinstance(value, NewKey):
        parent[str(value) or "k"] = 1  # an unknown name
    else:
        parent[last] = value


def _edits(places: list[Place]) -> st.SearchStrategy[list[tuple[Place, Any]]]:
    return st.lists(
        st.tuples(
            st.sampled_from(places),
            st.one_of(toml_values, st.just(KeyError), st.text(max_size=8).map(NewKey)),
        ),
        min_size=1,
        max_size=4,
    )


@fuzz_settings(100)
@given(edits=_edits(THERMAL_PLACES))
def test_any_value_at_any_thermal_key_is_a_usable_world_or_one_line(
    edits: list[tuple[Place, Any]],
) -> None:
    data = copy.deepcopy(THERMAL_BASE)
    for place, value in edits:
        _edit(data, place, value)
    try:
        world = world_from_dict(data, "fuzz.toml")
    except WorldError as exc:
        assert str(exc).startswith("fuzz.toml") and "\n" not in str(exc), str(exc)
        return
    for v in world.victims:
        assert 0.0 <= v.warm_visibility_pct <= 100.0
    n, e = world.start_ne_m
    pose = PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, world.start_heading_rad)
    frame = ThermalRenderer(world, seed=1).render(pose, 0.0, frame_key=0)
    assert frame.temps_c.shape == (120, 160) and np.isfinite(frame.temps_c).all()


@fuzz_settings(300)
@given(
    edits=st.lists(
        st.tuples(
            st.sampled_from(PLACES),
            st.one_of(toml_values, st.just(KeyError), st.text(max_size=8).map(NewKey)),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_any_value_at_any_key_is_a_usable_world_or_one_line(edits: list[tuple[Place, Any]]) -> None:
    data = copy.deepcopy(BASE)
    for place, value in edits:
        _edit(data, place, value)
    try:
        world = world_from_dict(data, "fuzz.toml")
    except WorldError as exc:
        assert str(exc).startswith("fuzz.toml") and "\n" not in str(exc), str(exc)
        return
    # What the simulator does with a world it loaded: the truth, a rover's view.
    for v in world.victims:
        assert 0.0 <= v.visibility_pct <= 100.0
        assert math.isfinite(v.visible_north_m) and math.isfinite(v.visible_east_m)
    n, e = world.start_ne_m
    pose = PoseSample(0.0, 0.0, n, e, -VEHICLE_HEIGHT_M, 0.0, 0.0, world.start_heading_rad)
    frame = Renderer(world, default_camera(), seed=1).render(pose, frame_key=0)
    assert frame.image.shape == (480, 640, 3)
