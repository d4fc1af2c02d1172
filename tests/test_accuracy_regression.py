"""Accuracy cannot silently drop: short recorded missions are replayed through the
whole companion pipeline and scored, and must do no worse than the figures stored in
bench/accuracy_baseline.json (its "guard" entries, measured with exactly these
settings by ``python -m bench.accuracy --update-baseline``).

Tolerances (bench.accuracy.TOLERANCE, with the reasons there): found victims, right
urgency classes: none fewer; false victims, duplicate IDs: none more; localisation
error: median +0.10 m, p95/max +0.15 m; slowest first report: +2 s.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest

from bench.accuracy import (
    BASELINE,
    GUARD,
    TOLERANCE,
    Scenario,
    load_baseline,
    measure,
    regressions,
)

_UPDATE = "re-measure it on purpose with: python -m bench.accuracy --update-baseline"


@pytest.fixture(scope="module")
def baseline() -> dict[str, Any]:
    if not BASELINE.exists():
        pytest.fail(f"{BASELINE} is missing; {_UPDATE}")
    guard: dict[str, Any] = load_baseline()["guard"]
    return guard


def test_baseline_was_measured_with_the_settings_this_test_uses(baseline: dict[str, Any]) -> None:
    assert baseline["settings"] == {s.key: s.settings() for s in GUARD}, (
        f"the guard's settings changed since {BASELINE.name} was written; {_UPDATE}"
    )
    # A guard that finds nobody could not notice a drop in recall or precision.
    assert sum(f["matched"] for f in baseline["scenarios"].values()) >= 2


# One test per mission: the test run's workers measure them side by side.
@pytest.mark.timeout(240)
@pytest.mark.parametrize("scenario", GUARD, ids=[s.key for s in GUARD])
def test_guard_missions_score_no_worse_than_the_baseline(
    baseline: dict[str, Any], scenario: Scenario
) -> None:
    measured = measure([scenario])
    worse = regressions(measured["scenarios"], {scenario.key: baseline["scenarios"][scenario.key]})
    assert not worse, (
        "accuracy dropped below bench/accuracy_baseline.json:\n  "
        + "\n  ".join(worse)
        + f"\n(if the change is intended, {_UPDATE})"
    )


# -- the comparison itself, on hand-made figures ----------------------------------------

_BASE = {
    "s": {
        "matched": 3,
        "urgency_correct": 2,
        "false_victims": 1,
        "duplicates": 0,
        "error_median_m": 0.20,
        "error_p95_m": 0.40,
        "error_max_m": 0.42,
        "time_to_report_max_s": 10.0,
    }
}


def _with(**changes: Any) -> dict[str, Any]:
    out = copy.deepcopy(_BASE)
    out["s"].update(changes)
    return out


@pytest.mark.parametrize(
    "changes",
    [
        {"matched": 2},
        {"urgency_correct": 1},
        {"false_victims": 2},
        {"duplicates": 1},
        {"error_median_m": 0.20 + TOLERANCE["error_median_m"] + 0.01},
        {"error_p95_m": 0.40 + TOLERANCE["error_max_m"] + 0.01},
        {"error_max_m": 0.42 + TOLERANCE["error_max_m"] + 0.01},
        {"error_median_m": None},
        {"time_to_report_max_s": 10.0 + TOLERANCE["time_to_report_max_s"] + 0.1},
    ],
)
def test_each_kind_of_drop_is_flagged(changes: dict[str, Any]) -> None:
    worse = regressions(_with(**changes), _BASE)
    assert len(worse) == 1 and worse[0].startswith("s: " + next(iter(changes)))


def test_equal_better_and_within_tolerance_pass() -> None:
    assert regressions(_BASE, _BASE) == []
    better = _with(matched=4, urgency_correct=4, false_victims=0, error_max_m=0.1)
    assert regressions(better, _BASE) == []
    slightly = _with(error_median_m=0.20 + TOLERANCE["error_median_m"] - 0.01)
    assert regressions(slightly, _BASE) == []


def test_a_scenario_that_was_not_measured_is_flagged() -> None:
    assert regressions({}, _BASE) == ["s: not measured"]
