"""Where the pipeline lets a miss count against a tentative track: only within
``tracker.miss_max_range_m``. Farther, the person detector often misses a body in
plain view, so three detections spread over a few seconds confirm a far body, while
a near spot that the detector stops seeing dies."""

from __future__ import annotations

import numpy as np

from companion.config import Config
from companion.pipeline import Pipeline
from companion.reporting import ReportPolicy
from companion.sources import Frame
from companion.vision import FrameGeometry
from fusion.pose import PoseHistory
from fusion.registry import EventKind
from fusion.tracker import VictimTracker
from fusion.types import Detection, PoseSample
from scenarios.camera import default_camera


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
