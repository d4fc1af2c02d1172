"""The tracker on a simulated drive: geolocated detections from a moving rover,
with modelled noise, missed detections and clutter."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.stats import chi2

from fusion.camera import CameraModel, Intrinsics, Mount, rotation_zyx
from fusion.errors import GeolocationRejected
from fusion.geolocate import geolocate, in_view
from fusion.params import GeolocationParams, TrackerParams
from fusion.registry import EventKind, TrackEvent, Victim
from fusion.tracker import VictimTracker
from fusion.types import Observation, PoseSample, TrackState

GEO = GeolocationParams()
CAMERA = CameraModel(
    Intrinsics.from_fov(640, 480, 70.0), Mount(x_m=0.15, z_m=-0.25, pitch_rad=math.radians(-15))
)
VICTIMS_NE = np.array([[3.5, 0.5], [-1.0, 4.0], [-4.0, -1.5], [1.0, -4.5]])
VISIBILITY_PCT = (80.0, 30.0, 5.0, 60.0)
T0_UNIX_S = 1_700_000_000.0
FRAME_S = 0.1
CLUTTER_RATE = 0.1  # false detections per frame: 1 per second at 10 FPS


@dataclass(frozen=True)
class Frame:
    t_unix_s: float
    observations: list[Observation]
    truth: list[int | None]  # index of the true victim per observation, None for clutter
    in_view: Callable[[float, float], bool]


def _pose(t_s: float) -> PoseSample:
    """A slow loop of radius 2.2 m around the victims' centre, facing outwards a bit
    so the forward camera sweeps across them."""
    angle = 0.25 * t_s
    yaw = angle + math.pi / 2 - 0.9  # tangent, turned 50 deg towards the outside
    return PoseSample(t_s, t_s, 2.2 * math.cos(angle), 2.2 * math.sin(angle), -0.3, 0.0, 0.0, yaw)


def frames(seed: int, n_frames: int = 700) -> Iterator[Frame]:
    rng = np.random.default_rng(seed)
    s_att = math.radians(GEO.attitude_sigma_deg)
    for k in range(n_frames):
        truth_pose = _pose(k * FRAME_S)
        # The pose the companion believes: the modelled attitude and position noise.
        dn, de = rng.normal(0.0, GEO.position_sigma_m, 2)
        dr, dp, dy = rng.normal(0.0, s_att, 3)
        est = PoseSample(
            truth_pose.t_boot_s,
            truth_pose.t_mono_s,
            truth_pose.north_m + dn,
            truth_pose.east_m + de,
            truth_pose.down_m,
            truth_pose.roll_rad + dr,
            truth_pose.pitch_rad + dp,
            truth_pose.yaw_rad + dy,
        )
        t_unix = T0_UNIX_S + k * FRAME_S
        pixels: list[tuple[float, float, int | None]] = []
        r = rotation_zyx(truth_pose.roll_rad, truth_pose.pitch_rad, truth_pose.yaw_rad)
        vehicle = np.array([truth_pose.north_m, truth_pose.east_m, truth_pose.down_m])
        for i, (n, e) in enumerate(VICTIMS_NE):
            if not in_view(CAMERA, truth_pose, n, e, GEO) or rng.random() > 0.8:
                continue  # out of view, or missed (20 %)
            floor = np.array([[n, e, truth_pose.down_m + GEO.floor_down_m]])
            px, _inside = CAMERA.project_ned(floor, vehicle, r)
            u, v = float(px[0, 0]), float(px[0, 1])
            du, dv = rng.normal(0.0, GEO.pixel_sigma_px, 2)
            pixels.append((u + du, v + dv, i))
        if rng.random() < CLUTTER_RATE:  # a false detection anywhere in the image
            pixels.append((rng.uniform(0, 639), rng.uniform(0, 479), None))
        observations, truth = [], []
        for u, v, i in pixels:
            try:
                fix = geolocate(CAMERA, est, u, v, GEO)
            except GeolocationRejected:
                continue
            vis = VISIBILITY_PCT[i] if i is not None else rng.uniform(0, 100)
            vis = float(np.clip(vis + rng.normal(0.0, 4.0), 0.0, 100.0))
            observations.append(
                Observation(t_unix, fix.north_m, fix.east_m, fix.cov_ne_m2, vis, 1.0, fix.range_m)
            )
            truth.append(i)

        def view(n: float, e: float, pose: PoseSample = est) -> bool:
            return in_view(CAMERA, pose, n, e, GEO)

        yield Frame(t_unix, observations, truth, view)


def _confirmed(tracker: VictimTracker) -> list[int]:
    return [
        v.victim_id
        for v in tracker.victims()
        if v.state in (TrackState.CONFIRMED, TrackState.NOT_SEEN_RECENTLY)
    ]


def _nearest_truth(north_m: float, east_m: float) -> int:
    return int(np.argmin(np.hypot(VICTIMS_NE[:, 0] - north_m, VICTIMS_NE[:, 1] - east_m)))


def _near_truth(v: Victim) -> bool:
    return bool(
        np.hypot(*(VICTIMS_NE[_nearest_truth(v.north_m, v.east_m)] - (v.north_m, v.east_m))) < 1.0
    )


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_static_victims_from_moving_rover(seed: int) -> None:
    """Every person gets exactly one ID that never switches or merges, placed within
    its reported uncertainty. The clutter here is harsh: one false detection a second
    anywhere in the image, and the image's bottom rows all land on a small patch of
    floor in front of the bumper, so three of them fall together on some runs.
    Confirming on three detections with at most two misses between them (the person
    detector sees a real body on only some frames) lets such a patch become a victim
    on 5 of 40 seeded runs (with no miss allowed: 1 of 40; 2026-11-27); the real
    detector's phantoms are objects, not random pixels, and the scenario suite's
    empty and skin-debris warehouses give none. At most one such ghost per run."""
    tracker = VictimTracker(TrackerParams())
    identity: dict[int, int] = {}  # victim_id -> true victim, must never change
    clutter_frames = 0
    for frame in frames(seed):
        clutter_frames += any(i is None for i in frame.truth)
        for ev in tracker.update(frame.observations, frame.t_unix_s, frame.in_view):
            assert ev.kind != EventKind.MERGED  # one track per victim from the start
        for v in tracker.victims():
            truth = _nearest_truth(v.north_m, v.east_m)
            assert identity.setdefault(v.victim_id, truth) == truth, "ID switch"
    assert clutter_frames > 30  # the clutter really was there
    ids = _confirmed(tracker)
    people = [v for v in tracker.victims() if _near_truth(v)]
    assert sorted(identity[v.victim_id] for v in people) == [0, 1, 2, 3]  # one ID each
    assert len(ids) - len(people) <= 1  # at most one ghost of clutter
    assert sorted(ids) == list(range(1, len(ids) + 1))  # consecutive IDs
    # Final error within the reported uncertainty: d^2 below the 99.9 % chi-square
    # quantile of 2 dof (13.8) for every victim.
    gate = chi2.ppf(0.999, 2)
    for v in people:
        err = np.array([v.north_m, v.east_m]) - VICTIMS_NE[identity[v.victim_id]]
        d2 = float(err @ np.linalg.solve(np.array(v.cov_ne_m2), err))
        assert d2 < gate, f"victim {v.victim_id}: error {err} d^2 {d2:.1f}"
        assert np.linalg.norm(err) < 0.5  # and usefully small in metres
        assert v.urgency.name == ("LIGHT", "MEDIUM", "CRITICAL", "LIGHT")[identity[v.victim_id]]


def _events_key(events: list[TrackEvent]) -> list[tuple[str, object]]:
    return [(e.kind.value, e.victim) for e in events]


def test_snapshot_restore_continues_identically() -> None:
    all_frames = list(frames(seed=7, n_frames=500))
    params = TrackerParams()
    straight = VictimTracker(params)
    restarted = VictimTracker(params)
    events_a: list[tuple[str, object]] = []
    events_b: list[tuple[str, object]] = []
    for k, frame in enumerate(all_frames):
        if k == 250:  # the service restarts mid-mission, through JSON as in SQLite
            saved = json.loads(json.dumps(restarted.snapshot()))
            restarted = VictimTracker.restore(params, saved)
            assert restarted.victims(include_tentative=True) == straight.victims(
                include_tentative=True
            )
        events_a += _events_key(straight.update(frame.observations, frame.t_unix_s, frame.in_view))
        events_b += _events_key(restarted.update(frame.observations, frame.t_unix_s, frame.in_view))
    assert len(_confirmed(straight)) >= 3  # the restart happened with victims known
    assert events_a == events_b
    assert straight.victims(include_tentative=True) == restarted.victims(include_tentative=True)
    assert straight.snapshot() == restarted.snapshot()
