"""The ``people`` backend: real MediaPipe models on real frames, their files, and
the geometry that places a body on the floor.

The models come from the project's set-up (`rescue-companion models fetch`); the
real frames from ../shared/data (tests that need them skip, naming the path).
"""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.burial import TEXTURES, measure_level
from bench.real_images import hits_box
from companion.commands.detect import read_image
from companion.config import DetectorConfig
from companion.vision import models, ssd
from companion.vision.backends import make_detector
from companion.vision.base import FrameGeometry
from companion.vision.people import PeopleDetector
from companion.vision.people_bodies import Body, add_body, box_overlap, mask_overlap
from companion.vision.people_params import FACE_SPEC, PALM_SPEC, POSE_SPEC, PeopleParams
from companion.vision.visibility import assess
from fusion.camera import CameraModel
from fusion.params import GeolocationParams
from fusion.types import Detection, PoseSample, Urgency
from scenarios.camera import default_camera


@pytest.fixture(scope="module")
def detector() -> PeopleDetector:
    return PeopleDetector(PeopleParams(extra_passes=99), None, 0.5)


def _falls(shared_data: Path) -> tuple[Path, dict[str, dict[str, object]]]:
    root = shared_data / "images" / "real_falls"
    return root, json.loads((root / "gt.json").read_text())


# -- the model files ---------------------------------------------------------------


def test_the_installed_models_are_the_ones_we_ship() -> None:
    assert models.verify() == []


def test_a_missing_model_is_named_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(models.ModelMissing) as err:
        PeopleDetector(model_dir=tmp_path)
    text = str(err.value)
    assert "pose_detection.tflite" in text and "missing" in text and "\n" not in text
    assert "rescue-companion models fetch" in text


def test_an_altered_model_is_refused(tmp_path: Path) -> None:
    for name in models.MODELS:
        (tmp_path / name).write_bytes(models.model_path(name).read_bytes())
    target = tmp_path / "palm_detection_lite.tflite"
    target.write_bytes(target.read_bytes()[:-10] + b"0123456789")
    problems = models.verify(tmp_path)
    assert len(problems) == 1 and "palm_detection_lite.tflite" in problems[0]
    assert "sha256" in problems[0]


def test_fetch_writes_nothing_when_every_file_is_there() -> None:
    assert models.fetch() == []  # all present and checked: no download


def test_cli_with_no_models_exits_2_with_one_line(tmp_path: Path) -> None:
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.zeros((48, 64, 3), np.uint8))
    proc = subprocess.run(
        [sys.executable, "-m", "companion.commands.cli", "detect", str(image)],
        capture_output=True,
        text=True,
        timeout=60,
        env={"RESCUE_MODEL_DIR": str(tmp_path / "empty"), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("rescue-companion")]
    assert len(lines) == 1 and "pose_detection.tflite" in lines[0]
    assert "Traceback" not in proc.stderr


# -- the detector heads ------------------------------------------------------------


@pytest.mark.parametrize(
    ("spec", "count"), [(POSE_SPEC, 2254), (PALM_SPEC, 2016), (FACE_SPEC, 2304)]
)
def test_anchor_counts_match_the_models_outputs(spec: ssd.SsdSpec, count: int) -> None:
    anchors = ssd.anchors(spec)
    assert anchors.shape == (count, 2)
    assert anchors.min() > 0.0 and anchors.max() < 1.0


def test_weighted_nms_merges_one_object_and_keeps_two() -> None:
    boxes = np.array([[0.1, 0.1, 0.3, 0.3], [0.11, 0.1, 0.31, 0.3], [0.6, 0.6, 0.8, 0.8]])
    kps = np.zeros((3, 1, 2))
    out = ssd.weighted_nms(boxes, np.array([0.9, 0.6, 0.7]), kps, 0.3)
    assert len(out) == 2
    assert out[0].score == pytest.approx(0.9)
    assert 0.1 < out[0].box[0] < 0.11  # averaged, weighted by score


# -- real frames -------------------------------------------------------------------


def test_finds_real_people_standing_and_lying(shared_data: Path, detector: PeopleDetector) -> None:
    """Regression guard on bench/real_images.py's figures (BENCHMARKS.md): of 24 real
    frames (11 people lying), every person is found (the two lying far away on a bed
    only by the zoomed centre tile), and nothing that is not a person (nor the same
    body twice, once per pass)."""
    root, gt = _falls(shared_data)
    found = found_lying = false = 0
    for rel, truth in gt.items():
        dets = detector.detect(cv2.imread(str(root / rel)), None, 0.0)
        box = truth["people"][0]  # type: ignore[index]
        hit = [d for d in dets if hits_box(d, box)]
        false += len(dets) - len(hit)
        found += bool(hit)
        found_lying += bool(hit) and truth["lying"][0]  # type: ignore[index]
        for d in hit:
            assert "person" in d.cues or "face" in d.cues or "hand" in d.cues
    assert false == 0
    assert found == 24 and found_lying == 11


@pytest.mark.parametrize(
    "name",
    [
        "skimage_gravel_gray.png",
        "skimage_brick_gray.png",
        "intel_one_by_one_frame0000_empty_room.png",
        "wm_barcroft_car_damaged_by_tree.jpg",
    ],
)
def test_no_person_in_debris_or_an_empty_room(
    shared_data: Path, detector: PeopleDetector, name: str
) -> None:
    image = cv2.imread(str(shared_data / "images" / "negatives" / name))
    assert detector.detect(image, None, 0.0) == []


def test_a_fully_visible_person_is_light(shared_data: Path, detector: PeopleDetector) -> None:
    root, _gt = _falls(shared_data)
    image = cv2.imread(str(root / "frames" / "Subject_1-Fall-15_f169.jpg"))
    (det,) = detector.detect(image, None, 0.0)
    a = assess(det, None)
    assert a is not None and a.urgency is Urgency.LIGHT
    assert {"person", "landmarks", "mask"} <= set(det.cues)


@pytest.mark.parametrize(
    ("visible_pct", "right", "min_right_share"),
    [(100, Urgency.LIGHT, 0.8), (20, Urgency.MEDIUM, 0.8)],
)
def test_people_under_real_debris_read_as_partly_visible(
    shared_data: Path, visible_pct: int, right: Urgency, min_right_share: float
) -> None:
    """bench/burial.py's levels: real frames, each person's box covered by real brick
    and gravel texture until ``visible_pct`` of it shows. The landmark mask fills in
    the covered body: by the mask alone 1 of the 16 people found at 20 % read MEDIUM
    (2026-11-27, lite landmark model); capped by the share of joints its heatmaps
    see, 14 (full, the default since 2026-11-28: 16). Of the 24 uncovered people 20
    stay LIGHT (24 by the mask alone)."""
    root, gt = _falls(shared_data)
    textures = [read_image(shared_data / "images" / "negatives" / n) for n in TEXTURES]
    single = make_detector(DetectorConfig(backend="people", enhance=False), single_images=True)
    level = measure_level(single, root, gt, textures, visible_pct)
    assert len(level.urgencies) >= 14
    assert sum(u is right for u in level.urgencies) >= min_right_share * len(level.urgencies)


def test_the_full_landmark_model_finds_more_buried_people_than_lite(shared_data: Path) -> None:
    """Why full is the default (docs/VISION.md "Which landmark model"): with 95 % of
    each person's box under real debris, full finds 12 of 24 and lite 9 (2026-11-28);
    ``detector.pose_landmarks = "lite"`` still loads the lite model."""
    root, gt = _falls(shared_data)
    textures = [read_image(shared_data / "images" / "negatives" / n) for n in TEXTURES]
    found = {}
    for name in ("full", "lite"):
        config = DetectorConfig(backend="people", enhance=False, pose_landmarks=name)
        single = make_detector(config, single_images=True)
        assert isinstance(single, PeopleDetector) and single.params.landmarks == name
        found[name] = measure_level(single, root, gt, textures, 5).found
    assert found["lite"] >= 7 and found["full"] >= found["lite"] + 2


def test_more_model_threads_find_the_same_people(shared_data: Path) -> None:
    """``detector.model_threads`` reaches every model; the people found do not change."""
    root, gt = _falls(shared_data)
    one, two = (
        make_detector(DetectorConfig(enhance=False, model_threads=n), single_images=True)
        for n in (1, 2)
    )
    assert isinstance(two, PeopleDetector)
    models = ("_pose", "_landmarks", "_segment", "_palm", "_face", "_hand")
    assert [getattr(two, m).threads for m in models] == [2] * len(models)
    for rel in sorted(gt)[:6]:
        image = read_image(root / rel)
        boxes = [
            np.array([d.bbox_xywh_px for d in det.detect(image, None, 0.0)]) for det in (one, two)
        ]
        assert boxes[0].shape == boxes[1].shape and boxes[0].size > 0
        assert np.abs(boxes[0] - boxes[1]).max() <= 2, rel


def test_nothing_in_frames_without_people(detector: PeopleDetector) -> None:
    """Without the real data: images this test makes (flat, noise, a dark frame)."""
    rng = np.random.default_rng(3)
    frames = [
        np.full((480, 640, 3), 128, np.uint8),
        rng.integers(0, 255, (480, 640, 3), dtype=np.uint8),
        (rng.random((480, 640, 3)) * 20).astype(np.uint8),
    ]
    for frame in frames:
        assert detector.detect(frame, None, 0.0) == []


def test_live_detector_spreads_extra_passes_over_frames() -> None:
    live = make_detector(DetectorConfig(backend="people"))
    single = make_detector(DetectorConfig(backend="people"), single_images=True)
    assert isinstance(live, PeopleDetector) and isinstance(single, PeopleDetector)
    geometry, _camera, _pose, _params = _geometry()
    # A photo: the whole frame, both turned passes and (no geometry, so no far band)
    # a 2:1 tile at the centre that zooms a small body.
    photo = single._passes(None, 640, 480)
    assert [v.turn for v in photo[:3]] == [
        None,
        cv2.ROTATE_90_CLOCKWISE,
        cv2.ROTATE_90_COUNTERCLOCKWISE,
    ]
    assert len(photo) == 4 and photo[3].tile == (80, 120, 560, 360)
    # Live, with the rover's geometry: the whole frame plus one extra pass per frame,
    # taking turns over the turned frames and the tiles of the far floor band.
    views = [live._passes(geometry, 640, 480) for _ in range(12)]
    assert all(len(v) == 2 and v[0].turn is None and v[0].tile is None for v in views)
    extras = {v[1] for v in views}
    tiles = [x.tile for x in extras if x.tile is not None]
    assert {x.turn for x in extras} >= {cv2.ROTATE_90_CLOCKWISE, cv2.ROTATE_90_COUNTERCLOCKWISE}
    assert len(tiles) >= 2
    for x0, y0, x1, y1 in tiles:
        assert x1 - x0 == 2 * (y1 - y0) and 0 <= x0 < x1 <= 640 and 0 <= y0 < y1 <= 480
    assert min(t[0] for t in tiles) == 0 and max(t[2] for t in tiles) == 640


def test_live_detector_looks_for_faces_and_hands_on_alternate_frames(shared_data: Path) -> None:
    """Live, the face and palm detectors take turns (a hand in view is still searched
    every other frame); a photo gets both. This frame shows a face and a hand."""
    root, _truth = _falls(shared_data)
    image = cv2.imread(str(root / "frames" / "Subject_1-Fall-13_f012.jpg"))
    live = make_detector(DetectorConfig(backend="people"))
    single = make_detector(DetectorConfig(backend="people"), single_images=True)

    def cues(det) -> set[str]:  # type: ignore[no-untyped-def]
        return {c for d in det.detect(image, None, 0.0) for c in d.cues}

    assert {"face", "hand"} <= cues(single)
    first, second = cues(live), cues(live)
    assert {"face", "hand"} <= first | second
    assert not {"face", "hand"} <= first and not {"face", "hand"} <= second


# -- geometry: where a body lies -----------------------------------------------------


def _geometry() -> tuple[FrameGeometry, CameraModel, PoseSample, GeolocationParams]:
    camera = default_camera()
    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    params = GeolocationParams()
    return FrameGeometry.from_pose(camera, pose, params), camera, pose, params


def test_pixels_of_floor_round_trips_floor_points() -> None:
    geometry, *_ = _geometry()
    pixels = np.array([[320.0, 400.0], [100.0, 300.0], [600.0, 470.0]])
    floor = geometry.floor_ne_m(pixels)
    assert np.all(np.isfinite(floor))
    back = geometry.pixels_of_floor(floor)
    assert back is not None
    np.testing.assert_allclose(back, pixels, atol=1e-6)


def test_a_joint_above_the_floor_is_placed_nearer_than_its_floor_ray() -> None:
    """The ray of a point 0.1 m up meets that height before the floor: taking the
    mask's pixel to the floor puts a lying body too far or, from its centroid, too
    near; the joint plane puts it where it is."""
    geometry, camera, _pose, params = _geometry()
    pixel = np.array([[320.0, 300.0]])
    floor = geometry.floor_ne_m(pixel)[0]
    joint = geometry.plane_ne_m(pixel, 0.10)[0]
    assert 0.0 < joint[0] < floor[0]
    height = -camera.mount.z_m + params.floor_down_m  # camera above the floor
    ahead = camera.mount.x_m  # camera ahead of the vehicle point (yaw 0: north)
    ratio = (joint[0] - ahead) / (floor[0] - ahead)
    assert ratio == pytest.approx((height - 0.10) / height, rel=1e-6)


def test_visibility_without_geometry_uses_the_bodys_own_extent() -> None:
    det = Detection(0.0, 10.0, 10.0, (0, 0, 20, 20), 30.0, 0.9, "people", ("hand",), 1000.0)
    a = assess(det, None)
    assert a is not None and a.visibility_pct == pytest.approx(3.0)
    assert a.urgency is Urgency.CRITICAL
    assert assess(Detection(0.0, 1.0, 1.0, (0, 0, 2, 2), 3.0, 0.9), None) is None


def test_the_seen_share_caps_what_the_mask_says() -> None:
    """A mask as large as a whole body, on a body whose heatmaps see a quarter of its
    joints, is MEDIUM; a mask showing 3 % stays CRITICAL whatever the heatmaps see."""
    whole = Detection(0.0, 10.0, 10.0, (0, 0, 20, 20), 1000.0, 0.9, expected_area_px=1000.0)
    a = assess(whole, None)
    assert a is not None and a.urgency is Urgency.LIGHT
    capped = dataclasses.replace(whole, seen_share_max=0.25)
    a = assess(capped, None)
    assert a is not None and a.visibility_pct == pytest.approx(25.0)
    assert a.urgency is Urgency.MEDIUM
    small = dataclasses.replace(capped, visible_area_px=30.0, seen_share_max=1.0)
    a = assess(small, None)
    assert a is not None and a.urgency is Urgency.CRITICAL


def _lying(x0: int, x1: int, score: float, cues: set[str], box_x0: float) -> Body:
    """A body lying across rows 120-220 with its mask from x0 to x1; its landmarks'
    box may reach out of the frame (``box_x0`` < 0)."""
    mask = np.zeros((480, 640), bool)
    mask[120:220, x0:x1] = True
    pts = np.zeros((33, 2))
    return Body(
        score, cues, mask.astype(np.uint8), mask, pts, np.array([(x0 + x1) / 2, 170.0]),
        (box_x0, 105.0, float(x1), 235.0),
    )  # fmt: skip


def test_one_body_cut_by_the_frame_is_one_detection() -> None:
    """A head at the frame's left edge, found by one pass with its landmarks' box
    reaching far out of the frame, and the whole body found by another: the boxes
    overlap by less than ``same_body_overlap`` but the masks are one body's, so one
    body stays (the higher score, with the cues of both). Two people side by side,
    with masks apart, stay two."""
    same = PeopleParams().same_body_overlap
    head = _lying(0, 100, 0.7, {"person", "landmarks", "mask", "face"}, box_x0=-230.0)
    whole = _lying(0, 340, 0.9, {"person", "landmarks", "mask"}, box_x0=-2.0)
    assert box_overlap(head.box, whole.box) < same
    bodies: list[Body] = [head]
    add_body(bodies, whole, same)
    assert len(bodies) == 1 and bodies[0] is whole and "face" in whole.cues
    left = _lying(0, 300, 0.9, {"person", "landmarks", "mask"}, box_x0=0.0)
    right = _lying(320, 640, 0.8, {"person", "landmarks", "mask"}, box_x0=320.0)
    bodies = [left]
    add_body(bodies, right, same)
    assert len(bodies) == 2 and bodies[0] is left and bodies[1] is right


_BOX = st.tuples(
    st.integers(-100, 700), st.integers(-100, 500), st.integers(1, 300), st.integers(1, 300)
)


@settings(max_examples=200, deadline=None)
@given(_BOX, _BOX, st.integers(0, 2**32 - 1))
def test_masks_are_compared_inside_the_boxes_as_over_the_whole_frame(
    box_a: tuple[int, int, int, int], box_b: tuple[int, int, int, int], seed: int
) -> None:
    """``mask_overlap`` looks only where the two boxes meet (a body's box holds its
    mask): the same share as comparing the whole frames, boxes out of the frame too."""
    rng = np.random.default_rng(seed)

    def body(box: tuple[int, int, int, int]) -> Body:
        x, y, w, h = box
        mask = np.zeros((480, 640), bool)
        inside = mask[max(0, y) : max(0, y + h), max(0, x) : max(0, x + w)]
        inside[...] = rng.random(inside.shape) < 0.6
        return Body(
            0.9, {"person"}, mask.astype(np.uint8), mask, None, np.zeros(2),
            (x + 0.4, y + 0.3, x + w - 0.2, y + h - 0.7),
        )  # fmt: skip

    a, b = body(box_a), body(box_b)
    smaller = min(int(a.mask.sum()), int(b.mask.sum()))
    want = float((a.mask & b.mask).sum()) / smaller if smaller else 0.0
    assert mask_overlap(a, b) == pytest.approx(want)


def test_heatmaps_alone_never_make_a_body_critical(detector: PeopleDetector) -> None:
    """A body whose every joint heatmap is weak (a skeleton fitted badly, or a body
    mostly covered) is capped at ``seen_share_floor``: MEDIUM, not CRITICAL."""
    mask = np.zeros((480, 640), bool)
    mask[200:260, 100:400] = True
    body = Body(
        0.9, {"person", "landmarks", "mask"}, mask.astype(np.uint8), mask, None,
        np.array([250.0, 230.0]), (100.0, 200.0, 400.0, 260.0), seen_share=0.0,
    )  # fmt: skip
    det = detector._detection(body, None, 0.0, 640, 480)
    assert det is not None and det.seen_share_max == PeopleParams().seen_share_floor
    a = assess(det, None)
    assert a is not None and a.urgency is Urgency.MEDIUM


def test_a_lone_face_is_critical_against_a_whole_body(detector: PeopleDetector) -> None:
    """A lone face 30 px high: a body ~230 px tall behind it; 30x30 visible is ~6 %."""
    body = detector._part(
        "face", 0.9, np.array([100, 100, 130, 130]), lambda: np.zeros((480, 640)), 640, 480
    )
    det = detector._detection(body, None, 0.0, 640, 480)
    assert det is not None and det.cues == ("face",)
    a = assess(det, None)
    assert a is not None and a.urgency is Urgency.CRITICAL
    assert math.isclose(
        a.visibility_pct, 900 / ((30 / 0.13) ** 2 * 0.26 * 0.75) * 100, rel_tol=1e-6
    )


def test_a_lying_body_whose_joints_miss_the_floor_is_placed_by_its_near_edge() -> None:
    """A lying body seen above the horizon the pose gives (the rover pitched, or the
    frame cuts it) has few joints that meet the floor in view. Its ankles alone must
    not place it (they lie up to a body's length from its centre, and the model
    guesses them when they are out of sight): its near edge, where the mask meets the
    floor, and half a body's width beyond it do."""
    from types import SimpleNamespace

    from companion.vision.floorpoint import ANKLES, FloorParams, floor_pixel

    geometry, *_ = _geometry()
    mask = np.zeros((480, 640), bool)
    mask[250:301, 250:391] = True  # the body's visible pixels; its near edge is row 300
    points = np.tile(np.array([320.0, 100.0]), (33, 1))  # above the horizon: no floor
    points[0] = (300.0, 120.0)  # nose
    points[list(ANKLES)] = [(380.0, 200.0), (390.0, 200.0)]  # on the floor, far away
    body = SimpleNamespace(
        mask=mask, points=points, seen=np.ones(33), hip_px=np.array([320.0, 100.0]),
        box=(250.0, 100.0, 391.0, 301.0), part="", seen_share=None,
    )  # fmt: skip
    u, v, heading, _whole = floor_pixel(body, geometry, FloorParams(), 640, 480)
    placed = geometry.floor_ne_m(np.array([[u, v]]))[0]
    edge = geometry.plane_ne_m(np.array([[320.5, 300.5]]), FloorParams().contact_height_m)[0]
    ankles = geometry.floor_ne_m(points[list(ANKLES)]).mean(axis=0)
    assert heading is None  # nothing in view tells the body's axis
    assert 0.1 < placed[0] - edge[0] < 0.3  # half a body's width beyond its near edge
    assert np.hypot(*(placed - ankles)) > 1.0


def test_a_mostly_hidden_body_is_placed_where_it_shows_not_beyond() -> None:
    """A lying body along the view is placed beyond its near edge by half its length,
    from its joints' span. A body mostly hidden (its head past the end of a slab
    that hides the rest of it on the camera's side) may go on beyond what shows
    towards the camera: where its heatmaps see at most half its main joints, or its
    mask covers less than half of what a whole body would there, its joints are
    guesses and it is placed by its near edge and half a body's width. The
    simulator's head peeking past a slab was placed 1.5 m beyond itself so."""
    from types import SimpleNamespace

    from companion.vision.floorpoint import FloorParams, floor_pixel

    geometry, *_ = _geometry()
    params = FloorParams()
    points = np.column_stack([np.full(33, 320.0), np.linspace(250.0, 300.0, 33)])
    points[0] = (320.0, 250.0)  # nose far, ankles near: lying along the view
    edge = geometry.plane_ne_m(np.array([[320.5, 300.5]]), params.contact_height_m)[0]

    def placed(seen_share: float, mask_px: float) -> tuple[float, float, float]:
        mask = np.zeros((480, 640), bool)
        half_w = max(1, round(mask_px / 51 / 2))
        mask[250:301, 320 - half_w : 320 + half_w] = True  # near edge: row 300
        body = SimpleNamespace(
            mask=mask, points=points, seen=np.ones(33), hip_px=points[24],
            box=(320.0 - half_w, 250.0, 320.0 + half_w, 301.0), part="",
            seen_share=seen_share,
        )  # fmt: skip
        u, v, heading, whole_uv = floor_pixel(body, geometry, params, 640, 480)
        assert heading == pytest.approx(0.0, abs=0.05)  # feet to head: north, away
        # Its visibility is still judged against the whole body its joints describe.
        at = geometry.floor_ne_m(np.array([whole_uv if whole_uv is not None else (u, v)]))
        assert at[0, 0] - edge[0] > 0.6
        return float(geometry.floor_ne_m(np.array([[u, v]]))[0, 0] - edge[0]), u, v

    beyond, u, v = placed(1.0, 20000.0)
    whole = geometry.expected_body_area_px(u, v, 0.0)
    assert whole is not None and 0.5 * whole < 20000.0
    assert beyond > 0.6  # seen whole: half its length beyond its near edge
    assert 0.1 < placed(0.3, 20000.0)[0] < 0.3  # the heatmaps see few of its joints
    assert 0.1 < placed(1.0, 0.1 * whole)[0] < 0.3  # a tenth of a body shows


def _sim_frame(preset_name: str, t_s: float, north_m: float, east_m: float, yaw_rad: float):  # type: ignore[no-untyped-def]
    from scenarios.motion import TruePose
    from scenarios.render import Renderer
    from scenarios.world import preset

    pose = TruePose(t_s, north_m, east_m, 0.0, 0.0, 0.0, yaw_rad)
    return Renderer(preset(preset_name)).render(pose, frame_key=1).image


def test_a_lone_palm_counts_only_when_the_hand_model_sees_a_hand() -> None:
    """The palm detector alone fires on the simulator's skin-coloured planks as on its
    exposed hands. The hand landmark model tells them apart: the arm and hand out of
    the rubble of the ``critical`` preset is a lone hand, the plank of the
    ``skin_debris`` preset (palm score 0.76 from this pose) is nothing."""
    detector = PeopleDetector(PeopleParams(parts_take_turns=False), None, 0.5)
    hand = _sim_frame("critical", 81.5, 5.99, 4.036, -0.38)
    rgb = cv2.cvtColor(hand, cv2.COLOR_BGR2RGB)
    palms = detector._ssd(detector._palm, PALM_SPEC, "palm", rgb, 0.0)
    assert [detector._hand_flag(rgb, b, k) >= 0.5 for _d, b, k in palms] == [True]
    assert [
        d for d in detector.detect(hand, None, 0.0) if "hand" in d.cues and "person" not in d.cues
    ]
    plank = _sim_frame("skin_debris", 72.75, 2.49, 4.059, -0.38)
    rgb = cv2.cvtColor(plank, cv2.COLOR_BGR2RGB)
    palms = detector._ssd(detector._palm, PALM_SPEC, "palm", rgb, 0.0)
    assert palms and max(d.score for d, _b, _k in palms) >= 0.5  # the palm detector fires
    assert all(detector._hand_flag(rgb, b, k) < 0.1 for _d, b, k in palms)
    assert not [d for d in detector.detect(plank, None, 0.0) if "hand" in d.cues]


def test_live_detector_looks_again_for_a_hand_it_just_saw() -> None:
    """Live, the palm detector runs every other frame, but on the frame after a lone
    hand too: a rover passing an exposed hand sees it for a second or so."""
    live = PeopleDetector(PeopleParams(), None, 0.5)
    hand = _sim_frame("critical", 81.5, 5.99, 4.036, -0.38)
    runs = []
    real = live._palm

    class Counting:
        def __call__(self, x):  # type: ignore[no-untyped-def]
            runs.append(live._parts_turn)
            return real(x)

    live._palm = Counting()  # type: ignore[assignment]
    hands = [any("hand" in d.cues for d in live.detect(hand, None, 0.0)) for _ in range(4)]
    assert hands == [False, True, True, True]  # the face's turn first, then every frame
    assert len(runs) == 3
