"""Core types: validation on construction and the urgency classes of the mission."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fusion.types import (
    Detection,
    GlobalOrigin,
    Observation,
    PoseSample,
    TrackState,
    Urgency,
    VictimReport,
)


@pytest.mark.parametrize(
    ("visibility_pct", "urgency"),
    [
        (100.0, Urgency.LIGHT),
        (50.1, Urgency.LIGHT),
        (50.0, Urgency.MEDIUM),
        (10.0, Urgency.MEDIUM),
        (9.99, Urgency.CRITICAL),
        (0.0, Urgency.CRITICAL),
    ],
)
def test_urgency_thresholds_of_the_mission(visibility_pct: float, urgency: Urgency) -> None:
    assert Urgency.from_visibility(visibility_pct) is urgency


@given(st.floats(min_value=0.0, max_value=100.0))
def test_urgency_is_monotonic_in_visibility(v: float) -> None:
    # Less visible never means less urgent.
    assert Urgency.from_visibility(v) >= Urgency.from_visibility(min(100.0, v + 5.0))


@pytest.mark.parametrize("bad", [-1.0, 100.5, math.nan])
def test_urgency_rejects_impossible_visibility(bad: float) -> None:
    with pytest.raises(ValueError, match="visibility_pct"):
        Urgency.from_visibility(bad)


def _pose(**kw: float) -> PoseSample:
    base = dict(
        t_boot_s=1.0,
        t_mono_s=2.0,
        north_m=0.0,
        east_m=0.0,
        down_m=0.0,
        roll_rad=0.0,
        pitch_rad=0.0,
        yaw_rad=0.0,
    )
    base.update(kw)
    return PoseSample(**base)


def test_pose_rejects_non_finite_and_negative_boot_time() -> None:
    with pytest.raises(ValueError, match="north_m"):
        _pose(north_m=math.inf)
    with pytest.raises(ValueError, match="t_boot_s"):
        _pose(t_boot_s=-0.1)


def test_origin_of_zero_zero_is_not_an_origin() -> None:
    with pytest.raises(ValueError, match="no origin"):
        GlobalOrigin(0.0, 0.0, 0.0)
    assert GlobalOrigin(-35.36, 149.16, 584.0).lat_deg == -35.36


def test_detection_needs_a_box_and_a_score_in_range() -> None:
    with pytest.raises(ValueError, match="positive size"):
        Detection(0.0, 10, 10, (5, 5, 0, 4), 10.0, 0.5)
    with pytest.raises(ValueError, match="score"):
        Detection(0.0, 10, 10, (5, 5, 3, 4), 10.0, 1.5)
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="seen_share_max"):
            Detection(0.0, 10, 10, (5, 5, 3, 4), 10.0, 0.5, seen_share_max=bad)
    with pytest.raises(ValueError, match="whole_uv_px"):
        Detection(0.0, 10, 10, (5, 5, 3, 4), 10.0, 0.5, whole_uv_px=(1.0, float("inf")))


def test_observation_covariance_must_be_positive_definite() -> None:
    with pytest.raises(ValueError, match="positive definite"):
        Observation(0.0, 1.0, 2.0, ((1.0, 2.0), (2.0, 1.0)), 50.0, 1.0, 3.0)
    with pytest.raises(ValueError, match="symmetric"):
        Observation(0.0, 1.0, 2.0, ((1.0, 0.1), (0.0, 1.0)), 50.0, 1.0, 3.0)


def _report(**kw: object) -> VictimReport:
    base: dict[str, object] = dict(
        victim_id=1,
        robot_sysid=1,
        state=TrackState.CONFIRMED,
        urgency=Urgency.MEDIUM,
        visibility_pct=30.0,
        north_m=1.0,
        east_m=2.0,
        down_m=0.1,
        cov_ne_m2=((0.09, 0.0), (0.0, 0.04)),
        observations=4,
        first_seen_unix_s=100.0,
        last_seen_unix_s=110.0,
    )
    base.update(kw)
    return VictimReport(**base)  # type: ignore[arg-type]


def test_report_sigma_is_the_larger_axis() -> None:
    assert _report().sigma_m == pytest.approx(0.3)
    assert not _report().has_global


def test_report_global_position_comes_whole() -> None:
    with pytest.raises(ValueError, match="together"):
        _report(lat_deg=1.0)
    assert _report(lat_deg=1.0, lon_deg=2.0, alt_m=3.0).has_global


def test_report_ids_and_times_are_checked() -> None:
    with pytest.raises(ValueError, match="victim_id"):
        _report(victim_id=0)
    with pytest.raises(ValueError, match="before"):
        _report(first_seen_unix_s=120.0)
