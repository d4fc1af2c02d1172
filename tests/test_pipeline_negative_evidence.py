"""What the pipeline makes of detections before the tracker.

Where it lets a miss count against a tentative track: only within
``tracker.miss_max_range_m``. Farther, the person detector often misses a body in
plain view, so three detections spread over a few seconds confirm a far body, while
a near spot that the detector stops seeing dies.

A body cut by the frame's side edge is placed where it shows, with its doubt across
the view widened (the rest of it is beyond the edge)."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import Config
from companion.pipeline import Pipeline, ThermalEye
from companion.reporting.policy import ReportPolicy
from companion.sources.base import Frame
from companion.sources.thermal import ThermalFrame
from companion.vision.base import FrameGeometry
from fusion.geolocate import geolocate
from fusion.pose import PoseHistory
from fusion.registry import EventKind
from fusion.tracker import VictimTracker
from fusion.types import Detection, PoseSample
from scenarios.camera import default_camera, default_thermal_camera


class _Scripted:
    """Detections given by the test frame by frame: the pipeline's input."""

    name = "scripted"
    min_score = 0.5

    def __init__(self, plan: list[list[Detection]]) -> None:
        self.plan = plan
        self.frame = 0

    def detect(self, image_bgr, geometry, t_mono_s):  # type: ignore[no-untyped-def]
        out = self.plan[self.frame]
        self.frame += 1
        return out


def _confirmed(range_m: float) -> bool:
    config = Config()
    camera = default_camera()
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    geometry = FrameGeometry.from_pose(camera, pose, config.geolocation)
    pixels = geometry.pixels_of_floor(np.array([[range_m, 0.0]]))
    assert pixels is not None
    u, v = (float(x) for x in pixels[0])
    det = Detection(0.0, u, v, (int(u) - 40, int(v) - 20, 80, 20), 600.0, 0.9, "scripted")
    plan = [[det]] + [[] for _ in range(15)] + [[det], [det]]  # a hit, 3 s unseen, 2 hits
    pipeline = Pipeline(
        config, camera, _Scripted(plan), VictimTracker(config.tracker), ReportPolicy(1.0, 0.5, 1.0)
    )
    poses = PoseHistory(60.0)
    for i in range(len(plan) + 2):
        poses.add(PoseSample(i * 0.2, 10.0 + i * 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    events = []
    for i in range(len(plan)):
        t_s = 10.2 + i * 0.2
        frame = Frame(np.zeros((480, 640, 3), np.uint8), t_s, 1_700_000_000.0 + t_s, i)
        out = pipeline.process(frame, poses)
        assert len(out.observations) == len(plan[i])
        events += out.events
    return any(e.kind is EventKind.CONFIRMED for e in events)


def test_misses_count_only_where_the_detector_would_see_a_body() -> None:
    assert not _confirmed(2.0)  # 15 misses at -0.2 end a track of one hit (0.85)
    assert _confirmed(5.0)  # no evidence against it: 3 hits (2.55) confirm it


def test_a_body_cut_by_the_side_of_the_frame_is_doubted_where_the_rest_may_be() -> None:
    config = Config()
    camera = default_camera()
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    geometry = FrameGeometry.from_pose(camera, pose, config.geolocation)
    pixels = geometry.pixels_of_floor(np.array([[2.5, -0.9], [2.5, 0.0], [2.5, 0.9]]))
    assert pixels is not None
    (ul, vl), (uc, vc), (ur, vr) = ((float(u), float(v)) for u, v in pixels)

    def det(u: float, v: float, box: tuple[int, int, int, int], cues: tuple[str, ...]) -> Detection:
        return Detection(0.0, u, v, box, 900.0, 0.9, "scripted", cues=cues)

    dets = [
        det(ul, vl, (0, int(vl) - 30, int(ul) + 40, 30), ("landmarks", "person")),  # left edge
        det(uc, vc, (int(uc) - 60, int(vc) - 30, 120, 30), ("landmarks", "person")),
        det(ur, vr, (int(ur) - 40, int(vr) - 30, 640 - int(ur) + 40, 30), ("person",)),  # right
        det(ul, vl, (0, int(vl) - 10, 20, 10), ("hand",)),  # a lone hand: no body beyond it
    ]
    pipeline = Pipeline(
        config,
        camera,
        _Scripted([dets]),
        VictimTracker(config.tracker),
        ReportPolicy(1.0, 0.5, 1.0),
    )
    poses = PoseHistory(60.0)
    poses.add(pose)
    poses.add(PoseSample(0.1, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    frame = Frame(np.zeros((480, 640, 3), np.uint8), 0.05, 1_700_000_000.05, 0)
    located = pipeline.process(frame, poses).located
    assert len(located) == 4
    for (d, o), cut in zip(located, (True, False, True, False), strict=True):
        want = geolocate(camera, pose, d.u_px, d.v_px, config.geolocation, cut_by_frame=cut)
        assert np.allclose(o.cov_ne_m2, want.cov_ne_m2)
        assert (o.north_m, o.east_m) == pytest.approx((want.north_m, want.east_m))
    cut_cov = np.array(located[0][1].cov_ne_m2)
    plain = geolocate(camera, pose, ul, vl, config.geolocation)
    assert np.linalg.det(cut_cov) > 2 * np.linalg.det(np.array(plain.cov_ne_m2))


class _Warm:
    """A thermal detector that finds the same warm body, 40 % of it bare, every frame."""

    def __init__(self, range_m: float) -> None:
        self.range_m = range_m

    def detect(self, temps_c, geometry, t_mono_s):  # type: ignore[no-untyped-def]
        pixels = geometry.pixels_of_floor(np.array([[self.range_m, 0.0]]))
        u, v = (float(x) for x in pixels[0])
        whole = geometry.expected_body_area_px(u, v)
        box = (int(u) - 10, int(v) - 5, 20, 10)
        return [Detection(t_mono_s, u, v, box, 0.4 * whole, 0.9, "thermal", cues=("warm",))]


def _urgency_of_a_warm_body(grey: int) -> str:
    """A body only the thermal camera finds, 2 m ahead, while the colour camera's
    frames (all ``grey``) find nothing there."""
    config = Config()
    eye = ThermalEye(default_thermal_camera(), _Warm(2.0))
    colour = _Scripted([[] for _ in range(12)])
    pipeline = Pipeline(
        config,
        default_camera(),
        colour,
        VictimTracker(config.tracker),
        ReportPolicy(1.0, 0.5, 1.0),
        eye,
    )
    poses = PoseHistory(60.0)
    for i in range(40):
        poses.add(PoseSample(i * 0.2, 10.0 + i * 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    temps = np.full((120, 160), 18.0, np.float32)
    for i in range(12):
        t_s = 10.2 + i * 0.2
        pipeline.process_thermal(ThermalFrame(temps, t_s, 1_700_000_000.0 + t_s, i), poses)
        image = np.full((480, 640, 3), grey, np.uint8)
        t_s += 0.1
        pipeline.process(Frame(image, t_s, 1_700_000_000.0 + t_s, i), poses)
    (victim,) = pipeline.tracker.victims()
    return victim.urgency.name


def test_a_warm_body_the_colour_camera_sees_nothing_of_in_good_light_is_critical() -> None:
    # Its warmth comes through a sheet or dust: nothing of the body shows.
    assert _urgency_of_a_warm_body(grey=128) == "CRITICAL"
    # In the dark the colour camera's looks say nothing: the warmth's 40 % stands.
    assert _urgency_of_a_warm_body(grey=5) == "MEDIUM"
