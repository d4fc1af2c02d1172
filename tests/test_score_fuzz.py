"""Fuzz the scorer's inputs, `rescue-sim score --truth T --victims R`: any JSON value at
any key of a ground truth and of a report gives the figures (as text and JSON) or one
ScoreInputError line naming the file, never another exception."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from scenarios.score import ScoreInputError, format_score, report_from_dict, score, truth_from_dict
from tests.jsonfuzz import fuzz_settings, json_values

TRUTH = {
    "victims": [
        {
            "victim_id": 1,
            "north_m": 2.0,
            "east_m": 3.0,
            "urgency": "LIGHT",
            "visible_north_m": 2.1,
            "visible_east_m": 3.0,
            "first_in_view_unix_s": 10.0,
        },
        {
            "victim_id": 2,
            "north_m": 6.0,
            "east_m": 1.0,
            "urgency": "CRITICAL",
            "visible_north_m": None,
            "visible_east_m": None,
            "first_in_view_unix_s": None,
        },
    ]
}
REPORT = {
    "victims": [
        {
            "victim_id": 4,
            "urgency": "LIGHT",
            "north_m": 2.2,
            "east_m": 3.1,
            "first_seen_unix_s": 12.0,
            "first_reported_unix_s": 14.0,
            "cov_ne_m2": [[0.04, 0.0], [0.0, 0.04]],
        },
        {
            "victim_id": 5,
            "urgency": "MEDIUM",
            "north_m": 9.0,
            "east_m": 9.0,
            "first_seen_unix_s": 20.0,
        },
    ]
}
EDGES: list[Any] = [0, -1, 2**63, 1e308, -1e308, math.nan, math.inf, "", "light", None]
COVS: list[Any] = [[[0, 0], [0, 0]], [[-1, 0], [0, -1]], [[1, 2], [2, 1]], [[1e308, 0], [0, 1e308]]]
values = json_values | st.sampled_from([*EDGES, *COVS])


def _keys(doc: dict[str, Any]) -> list[tuple[int, str]]:
    return [(i, k) for i, v in enumerate(doc["victims"]) for k in v]


def _apply(doc: dict[str, Any], edits: list[tuple[tuple[int, str], Any]]) -> dict[str, Any]:
    out = copy.deepcopy(doc)
    for (i, key), value in edits:
        if value is KeyError:
            out["victims"][i].pop(key, None)
        else:
            out["victims"][i][key] = value
    return out


def _edits(doc: dict[str, Any]) -> st.SearchStrategy[list[tuple[tuple[int, str], Any]]]:
    return st.lists(st.tuples(st.sampled_from(_keys(doc)), values | st.just(KeyError)), max_size=3)


@fuzz_settings(400)
@given(truth_edits=_edits(TRUTH), report_edits=_edits(REPORT), duplicate=st.booleans())
def test_any_value_in_truth_or_report_is_scored_or_one_line(
    truth_edits: list[Any], report_edits: list[Any], duplicate: bool
) -> None:
    report_doc = _apply(REPORT, report_edits)
    if duplicate:  # two reports with one ID
        report_doc["victims"].append(copy.deepcopy(report_doc["victims"][0]))
    try:
        truth = truth_from_dict(json.loads(json.dumps(_apply(TRUTH, truth_edits))), Path("t.json"))
        report = report_from_dict(json.loads(json.dumps(report_doc)), Path("r.json"))
    except ScoreInputError as exc:
        assert str(exc).startswith(("t.json", "r.json")) and "\n" not in str(exc), str(exc)
        return
    result = score(truth, report, gate_m=1.0)
    assert format_score(result)
    json.dumps(result.as_dict(), allow_nan=False)
