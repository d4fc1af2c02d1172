"""The tracker's snapshot, as read back from disk, fuzzed: any value anywhere, keys
dropped or added. Restoring either works, and the tracker then runs and reports
finite positions, or raises FusionError naming the field; never anything else."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fusion.errors import FusionError
from fusion.params import TrackerParams
from fusion.tracker import VictimTracker
from fusion.types import Observation
from tests.jsonfuzz import json_values

T0 = 1_700_000_000.0
PARAMS = TrackerParams()


def _snapshot() -> dict[str, Any]:
    """Victims seen many times (fixes stored), one merged into another, one not
    seen recently, and a tentative track."""
    tracker = VictimTracker(TrackerParams(same_victim_m=0.0))
    rng = np.random.default_rng(0)

    def see(t: float, points: list[tuple[float, float]], var_m2: float = 0.01) -> None:
        cov = ((var_m2, 0.0), (0.0, var_m2))
        obs = [Observation(t, n + rng.normal(0, 0.02), e, cov, 60.0, 1.0, 3.0) for n, e in points]
        tracker.update(obs, t, lambda n, e: True)

    for k in range(4):
        see(T0 + k, [(1.0, 1.0), (5.0, 1.0)])
    for k in range(4, 8):  # 0.6 m from the first: a second victim, for now
        see(T0 + k, [(1.6, 1.0)])
    for k in range(8, 40):  # then seen between them, twice a frame: one body
        see(T0 + k, [(1.3, 1.0), (1.3, 1.0)])
    see(T0 + 40, [(9.0, 2.0)])
    snapshot = tracker.snapshot()
    states = sorted(t["state"] for t in snapshot["tracks"])
    assert states == ["CONFIRMED", "MERGED", "NOT_SEEN_RECENTLY", "TENTATIVE"], states
    return snapshot


SNAPSHOT = _snapshot()


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every place in the snapshot a value sits."""
    out = [prefix]
    if isinstance(node, dict):
        for key, value in node.items():
            out += _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _paths(value, (*prefix, i))
    return out


PATHS = _paths(SNAPSHOT)[1:]


@settings(max_examples=1000, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from(PATHS), st.sampled_from(["set", "drop", "add"]), json_values),
        min_size=1,
        max_size=3,
    )
)
def test_a_damaged_snapshot_restores_or_is_named(
    mutations: list[tuple[tuple[Any, ...], str, Any]],
) -> None:
    snap = copy.deepcopy(SNAPSHOT)
    for path, how, value in mutations:
        parent: Any = snap
        try:
            for key in path[:-1]:
                parent = parent[key]
            if how == "set":
                parent[path[-1]] = value
            elif how == "drop" and isinstance(parent, dict):
                del parent[path[-1]]
            elif how == "add" and isinstance(parent, dict):
                parent[f"extra_{path[-1]}"] = value
        except (KeyError, IndexError, TypeError):
            continue  # an earlier mutation removed or replaced that place
    try:
        tracker = VictimTracker.restore(PARAMS, snap)
    except FusionError as exc:
        assert str(exc).startswith("snapshot")
        return
    t = T0 + 60.0
    obs = Observation(t, 1.0, 1.0, ((0.04, 0.0), (0.0, 0.04)), 60.0, 1.0, 3.0)
    tracker.update([obs], t, lambda n, e: True)
    for v in tracker.victims(include_tentative=True):
        assert math.isfinite(v.north_m) and math.isfinite(v.east_m)
