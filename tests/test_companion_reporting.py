"""Reporting policy: report on news, never once per frame; survive a restart."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.reporting.policy import (
    FLAG_MOVED,
    FLAG_NEW,
    FLAG_REQUESTED,
    FLAG_URGENCY_CHANGED,
    ReportPolicy,
)
from fusion.registry import EventKind, TrackEvent, Victim
from fusion.types import TrackState, Urgency
from tests.jsonfuzz import json_values


def _victim(**kw: object) -> Victim:
    base: dict[str, object] = dict(
        victim_id=1,
        state=TrackState.CONFIRMED,
        urgency=Urgency.MEDIUM,
        visibility_pct=30.0,
        north_m=5.0,
        east_m=2.0,
        cov_ne_m2=((0.04, 0.0), (0.0, 0.04)),
        observations=5,
        first_seen_unix_s=100.0,
        last_seen_unix_s=101.0,
        log_odds=3.0,
        merged_into=None,
    )
    base.update(kw)
    return Victim(**base)  # type: ignore[arg-type]


def _policy() -> ReportPolicy:
    return ReportPolicy(move_threshold_sigma=1.0, move_min_m=0.3, update_min_interval_s=5.0)


def test_confirmation_is_announced_once() -> None:
    p = _policy()
    v = _victim()
    (d,) = p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    assert d.flags == FLAG_NEW and d.announce
    # The same victim in later frames, unchanged: nothing to say.
    for t in range(101, 160):
        assert p.decide([], [v], float(t)) == []


def test_urgency_change_is_announced() -> None:
    p = _policy()
    v = _victim()
    p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    worse = dataclasses.replace(v, urgency=Urgency.CRITICAL, visibility_pct=5.0)
    (d,) = p.decide([TrackEvent(EventKind.URGENCY_CHANGED, worse)], [worse], 101.0)
    assert d.flags == FLAG_URGENCY_CHANGED and d.announce


def test_small_moves_and_frequent_moves_are_not_news() -> None:
    p = _policy()
    v = _victim()
    p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    # 0.25 m is over 1 sigma (0.2 m) but under move_min_m: no report.
    assert p.decide([], [dataclasses.replace(v, north_m=5.25)], 110.0) == []
    # 1 m, but only 2 s after the last report: wait.
    far = dataclasses.replace(v, north_m=6.0)
    assert p.decide([], [far], 102.0) == []
    (d,) = p.decide([], [far], 106.0)
    assert d.flags == FLAG_MOVED and not d.announce
    # Reported where it now is: no repeat.
    assert p.decide([], [far], 120.0) == []


def test_tentative_and_unreported_victims_are_silent() -> None:
    p = _policy()
    v = _victim(state=TrackState.TENTATIVE)
    assert p.decide([TrackEvent(EventKind.SEEN_AGAIN, v)], [v], 100.0) == []
    assert p.requested([v], 100.0) == []


def test_operator_mark_and_request() -> None:
    p = _policy()
    v = _victim()
    p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    rescued = dataclasses.replace(v, state=TrackState.RESCUED)
    (d,) = p.decide([TrackEvent(EventKind.OPERATOR, rescued)], [rescued], 101.0)
    assert d.victim.state is TrackState.RESCUED and d.announce
    (again,) = p.requested([rescued], 102.0)
    assert again.flags == FLAG_REQUESTED and not again.announce


def test_restart_reannounces_nothing() -> None:
    p = _policy()
    v = _victim()
    p.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 100.0)
    saved = json.loads(json.dumps(p.snapshot()))
    q = _policy()
    q.restore(saved)
    # A restored tracker may re-emit CONFIRMED for a known victim: not news.
    assert q.decide([TrackEvent(EventKind.CONFIRMED, v)], [v], 200.0) == []


@pytest.mark.parametrize(
    "bad",
    [
        [],
        {"1": ["CONFIRMED"]},
        {"x": ["CONFIRMED", "LIGHT", 1, 2, 3]},
        {"1": ["CONFIRMED", "LIGHT", float("nan"), 2, 3]},
        {"0": ["CONFIRMED", "LIGHT", 1, 2, 3]},
    ],
)
def test_malformed_saved_state_is_named(bad: object) -> None:
    with pytest.raises(ValueError, match="reported-state"):
        _policy().restore(bad)


@settings(max_examples=500, deadline=None)
@given(
    json_values
    | st.dictionaries(
        st.text(max_size=4),
        st.lists(
            st.sampled_from(["CONFIRMED", "LIGHT", "MEDIUM", "RESCUED"])
            | st.floats()
            | st.integers(),
            min_size=5,
            max_size=6,
        ),
        max_size=3,
    )
)
def test_any_saved_state_restores_or_is_named(saved: object) -> None:
    """What was reported, read back from disk, fuzzed: it restores with finite
    positions or raises ValueError; never anything else."""
    p = _policy()
    try:
        p.restore(saved)
    except ValueError as exc:
        assert "reported-state" in str(exc)
        return
    for vid, r in p.reported.items():
        assert vid >= 1 and math.isfinite(r.north_m + r.east_m + r.t_unix_s)


def test_every_reported_victim_again_when_the_origin_becomes_known() -> None:
    p = _policy()
    seen, unreported = _victim(), _victim(victim_id=2)
    p.decide([TrackEvent(EventKind.CONFIRMED, seen)], [seen], 100.0)
    (d,) = p.requested([seen, unreported], 101.0, flags=0)
    assert d.victim.victim_id == 1 and d.flags == 0 and not d.announce
