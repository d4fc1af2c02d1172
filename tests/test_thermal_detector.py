"""The thermal detector (companion/vision/thermal.py): on the real radiometric
photos first (skips without them or exiftool), then each rule on frames the test
draws on a known floor (2 cm a pixel, as a Lepton at about 3 m)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.sources.flir import read_flir
from companion.vision.base import FrameGeometry, VisionError
from companion.vision.thermal import UNSETTLED, ThermalDetector, ThermalResult
from companion.vision.thermal_params import ThermalDetectorParams
from companion.vision.visibility import assess
from fusion.types import Urgency

needs_exiftool = pytest.mark.skipif(shutil.which("exiftool") is None, reason="exiftool missing")

# Each person's point in the raw thermal picture, counted by eye (bench/thermal_real.py).
PEOPLE = {
    "wm_infrared_people_in_laboratory.jpg": [(28, 39), (92, 43), (131, 45), (156, 41), (88, 81)],
    "wm_thermographie_de_rue_night.jpg": [(80, 50), (93, 47)],
    "wm_videocamera_termica_seated_group.jpg": [(3, 38), (37, 31), (72, 40), (142, 38)],
}
NOT_PEOPLE = [
    ("thermal_radiometric", "wm02_water_cooler.jpg"),
    ("thermal_radiometric", "wm08_radiator_through_wall.jpg"),
    # floor heating turned down as flat, and a 34 °C object cut by the top edge, three
    # rows of it in view: a sliver of something beyond the picture
    ("thermal_radiometric", "wm10_floor_heating_chair.jpg"),
    ("thermal_radiometric", "wm11_moving_car.jpg"),
    ("thermal_radiometric", "wm18_steam_valves.jpg"),
    ("thermal_radiometric", "wm20_flying_foxes_heat_event.jpg"),
    ("negatives", "wm_termografia_building_ir.jpg"),
]


def _holds(box: tuple[int, int, int, int], point: tuple[int, int]) -> bool:
    x, y, w, h = box
    return x <= point[0] < x + w and y <= point[1] < y + h


def _photo(shared_data: Path, folder: str, name: str) -> ThermalResult:
    temps = read_flir(shared_data / "images" / folder / name).temps_c
    return ThermalDetector().analyse(temps, None, 0.0)


@needs_exiftool
@pytest.mark.parametrize("name", PEOPLE)
def test_every_person_in_the_radiometric_photos_is_found(shared_data: Path, name: str) -> None:
    result = _photo(shared_data, "people_thermal", name)
    boxes = [f.detection.bbox_xywh_px for f in result.finds]
    assert all(any(_holds(b, p) for b in boxes) for p in PEOPLE[name])
    for f in result.finds:
        d = f.detection
        assert d.source == "thermal" and "warm" in d.cues and 0.0 <= d.score <= 1.0
        assert d.expected_area_px is not None  # a photo: the detector's own size prior


@needs_exiftool
def test_the_man_in_cold_water_is_one_critical_warm_part(shared_data: Path) -> None:
    result = _photo(shared_data, "people_thermal", "wm_man_in_water_ir.jpg")
    head, left_hand, right_hand = (328, 215), (291, 213), (366, 215)
    over = [f for f in result.finds if _holds(f.detection.bbox_xywh_px, head)]
    assert len(over) == 1
    find = over[0]
    box = find.detection.bbox_xywh_px
    assert _holds(box, left_hand) and _holds(box, right_hand)  # one find, not three
    assert find.detection.cues == ("warm", "warm_part")
    assert 25.0 <= find.peak_c <= 29.0  # "at most 27 °C" in 7 °C water
    a = assess(find.detection, None)
    assert a is not None and a.urgency is Urgency.CRITICAL
    assert 6.0 <= result.ambient_c <= 8.0


@needs_exiftool
@pytest.mark.parametrize("where", NOT_PEOPLE, ids=lambda w: w[1])
def test_warm_things_that_are_not_people_give_nothing(
    shared_data: Path, where: tuple[str, str]
) -> None:
    assert _photo(shared_data, *where).finds == []


@needs_exiftool
def test_machinery_is_turned_down_as_hotter_than_skin(shared_data: Path) -> None:
    result = _photo(shared_data, "thermal_radiometric", "wm18_steam_valves.jpg")
    assert result.rejected and all(r.reason == "hotter than skin" for r in result.rejected)


@needs_exiftool
def test_in_a_heat_event_the_background_is_the_ambient(shared_data: Path) -> None:
    result = _photo(shared_data, "thermal_radiometric", "wm20_flying_foxes_heat_event.jpg")
    assert result.ambient_c > 40.0 and result.finds == []


# --- rules on drawn frames -------------------------------------------------------

FLOOR_FROM_V = 30  # rows above it see no floor (above the horizon)
MPP = 0.02


def _geometry() -> FrameGeometry:
    return FrameGeometry.constant(MPP, floor_from_v_px=FLOOR_FROM_V)


def _scene(ambient_c: float = 18.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.full((120, 160), ambient_c, np.float32)
    t += np.linspace(-0.5, 0.5, 160, dtype=np.float32)[None, :]  # a gentle gradient
    return t + rng.normal(0.0, 0.05, t.shape).astype(np.float32)  # a Lepton's noise


def _ellipse(t: np.ndarray, centre: tuple[int, int], axes_m: tuple[float, float], c: float) -> None:
    mask = np.zeros(t.shape, np.uint8)
    axes = (max(1, round(axes_m[0] / 2 / MPP)), max(1, round(axes_m[1] / 2 / MPP)))
    cv2.ellipse(mask, centre, axes, 0, 0, 360, 1, -1)
    t[mask > 0] = c


def _lying_person(t: np.ndarray, centre: tuple[int, int] = (80, 80)) -> None:
    _ellipse(t, centre, (1.6, 0.4), 27.0)  # clothes
    cx, cy = centre
    _ellipse(t, (cx - 34, cy), (0.2, 0.16), 33.0)  # the face
    _ellipse(t, (cx - 5, cy + 9), (0.1, 0.06), 31.0)  # a hand


def test_a_lying_person_is_one_find_on_the_floor() -> None:
    t = _scene()
    _lying_person(t)
    finds = ThermalDetector().analyse(t, _geometry(), 0.0).finds
    assert len(finds) == 1
    d = finds[0].detection
    assert d.cues == ("warm",)
    assert finds[0].area_m2 is not None and 0.35 <= finds[0].area_m2 <= 0.65
    assert abs(d.u_px - 80) < 4 and abs(d.v_px - 80) < 4  # its centre: where it lies
    assert d.expected_area_px is None  # a geometry gives the size prior
    assert d.visible_area_px == pytest.approx(finds[0].area_m2 / MPP**2, rel=0.01)


def test_a_hand_alone_is_a_warm_part() -> None:
    t = _scene()
    _ellipse(t, (60, 90), (0.12, 0.08), 32.0)
    finds = ThermalDetector().analyse(t, _geometry(), 0.0).finds
    assert [f.detection.cues for f in finds] == [("warm", "warm_part")]


def test_a_head_and_two_cold_hands_are_one_part() -> None:
    t = _scene(ambient_c=7.0)
    _ellipse(t, (80, 80), (0.18, 0.2), 27.0)  # a head out of cold water
    _ellipse(t, (66, 82), (0.08, 0.06), 15.0)  # hands, cooled by the water
    _ellipse(t, (95, 82), (0.08, 0.06), 17.0)
    finds = ThermalDetector().analyse(t, _geometry(), 0.0).finds
    assert len(finds) == 1 and finds[0].detection.cues == ("warm", "warm_part")
    x, _y, w, _h = finds[0].detection.bbox_xywh_px
    assert x <= 64 and x + w >= 97


def _heating_pipes(t: np.ndarray) -> None:
    """2 m x 1.6 m of floor over heating pipes: 30 and 33 °C in stripes (not flat)."""
    t[40:120, 20:120] = 30.0
    t[40:120:6, 20:120] = 33.0


def _lepton_on_a_rover() -> FrameGeometry:
    """A Lepton 3.5 on the default mount (0.3 m up, 12° down) of a level rover."""
    from companion.calibration import camera_model
    from companion.config import Config, ThermalConfig
    from fusion.types import PoseSample

    pose = PoseSample(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return FrameGeometry.from_pose(camera_model(ThermalConfig()), pose, Config().geolocation)


def _hand_at(t: np.ndarray, geometry: FrameGeometry, north_m: float, east_m: float) -> None:
    """A 32 °C hand, 0.1 m square, on the floor at (north, east)."""
    corners = [(north_m + a, east_m + b) for a in (-0.05, 0.05) for b in (-0.05, 0.05)]
    px = geometry.pixels_of_floor(np.array(corners))
    assert px is not None and np.isfinite(px).all()
    (u0, v0), (u1, v1) = np.floor(px.min(axis=0)).astype(int), np.ceil(px.max(axis=0)).astype(int)
    t[v0 : max(v1, v0 + 2), u0 : max(u1, u0 + 2)] = 32.0


def test_the_merge_gap_is_on_the_floor_not_in_pixels() -> None:
    geometry = _lepton_on_a_rover()
    t = _scene()
    _hand_at(t, geometry, 3.5, -0.3)  # 0.6 m apart, 3.5 m away: two people's hands,
    _hand_at(t, geometry, 3.5, 0.3)  # about 25 pixels apart in the image
    _hand_at(t, geometry, 1.0, -0.13)  # 0.26 m apart, 1 m away: one person's hands,
    _hand_at(t, geometry, 1.0, 0.13)  # about 38 pixels apart
    finds = ThermalDetector().analyse(t, geometry, 0.0).finds
    ranges = sorted(
        float(geometry.floor_ne_m(np.array([[f.detection.u_px, f.detection.v_px]]))[0, 0])
        for f in finds
    )
    # The near pair one find, the far pair two; each placed where it meets the floor.
    assert ranges == pytest.approx([1.0, 3.5, 3.5], abs=0.25)
    assert all(f.detection.cues == ("warm", "warm_part") for f in finds)


@pytest.mark.parametrize(
    ("draw", "reason"),
    [
        (lambda t: _ellipse(t, (80, 80), (1.0, 0.5), 70.0), "hotter than skin"),
        (lambda t: _ellipse(t, (80, 80), (0.7, 0.7), 30.0), "large and flat"),
        (_heating_pipes, "larger than a person"),
        (lambda t: t.__setitem__((slice(2, 26), slice(40, 46)), 32.0), "above the floor"),
    ],
    ids=["machinery", "floor heating", "heated floor", "pipe on a wall"],
)
def test_what_a_person_cannot_be_is_turned_down(
    draw: Callable[[np.ndarray], None], reason: str
) -> None:
    t = _scene()
    t[35:, :] = _scene(seed=1)[35:, :]
    draw(t)
    result = ThermalDetector().analyse(t, _geometry(), 0.0)
    assert result.finds == []
    assert any(reason in r.reason for r in result.rejected), result.rejected


def test_colder_than_a_body_is_not_a_person_even_against_a_cold_scene() -> None:
    t = _scene(ambient_c=-3.0)
    _ellipse(t, (80, 80), (1.0, 0.5), 9.0)  # a radiator's heat through a winter wall
    assert ThermalDetector().analyse(t, _geometry(), 0.0).finds == []


def test_animals_cooler_than_a_hot_background_are_not_found() -> None:
    t = _scene(ambient_c=45.0)
    _ellipse(t, (80, 80), (0.3, 0.2), 38.0)
    assert ThermalDetector().analyse(t, _geometry(), 0.0).finds == []


def test_a_fading_imprint_is_dropped_and_a_person_is_not() -> None:
    detector = ThermalDetector()
    seen_imprint, seen_person = [], []
    for i in range(120):  # 14 s at 8.7 frames a second
        t_s = i / 8.7
        t = _scene(seed=i)
        _ellipse(t, (40, 80), (0.5, 0.3), 30.0 - 0.15 * t_s)  # an imprint, cooling
        _ellipse(t, (120, 80), (0.5, 0.3), 31.0)  # a person's torso
        finds = detector.analyse(t, _geometry(), t_s).finds
        seen_imprint.append(any(f.detection.u_px < 80 for f in finds))
        seen_person.append(any(f.detection.u_px > 80 for f in finds))
    assert all(seen_person)
    assert seen_imprint[0]  # at first it cannot be told from a person
    assert not any(seen_imprint[60:])  # once it has been seen cooling for seconds


def _receding_geometry(mpp: float) -> FrameGeometry:
    """A floor seen at ``mpp`` metres a pixel; pixel (80, 80) is always at (2, 0) m."""

    def floor(px: np.ndarray) -> np.ndarray:
        return (px[:, ::-1] - 80.0) * mpp + np.array([2.0, 0.0])

    return FrameGeometry(lambda _u, _v: mpp, lambda _u, _v: 0.57 / mpp**2, floor)


def test_a_person_the_rover_drives_away_from_is_not_taken_for_a_cooling_imprint() -> None:
    detector = ThermalDetector()
    for i in range(120):
        t_s = i / 8.7
        mpp = 0.01 * 1.012**i  # 1 cm a pixel to 4 cm: 1 m away, then about 3 m
        t = _scene(seed=i)
        # the same torso, fewer pixels and reading cooler (blended) as the range grows
        axes = (max(2, round(0.25 / mpp)), max(2, round(0.15 / mpp)))
        mask = np.zeros(t.shape, np.uint8)
        cv2.ellipse(mask, (80, 80), axes, 0, 0, 360, 1, -1)
        t[mask > 0] = 33.0 - 0.4 * t_s
        finds = detector.analyse(t, _receding_geometry(mpp), t_s).finds
        assert len(finds) == 1, (i, detector.analyse(t, _receding_geometry(mpp), t_s + 1e-3))


def test_finds_under_the_minimum_score_are_dropped() -> None:
    t = _scene()
    _ellipse(t, (60, 90), (0.12, 0.08), 27.0)  # 9 K over ambient: a low score
    (find,) = ThermalDetector().analyse(t, _geometry(), 0.0).finds
    strict = ThermalDetector(min_score=find.detection.score + 0.01).analyse(t, _geometry(), 0.0)
    assert strict.finds == [] and "min_score" in strict.rejected[0].reason


def test_a_photo_gets_the_pixel_size_prior() -> None:
    t = _scene()
    _lying_person(t)
    finds = ThermalDetector().analyse(t, None, 0.0).finds
    assert len(finds) == 1
    assert finds[0].detection.expected_area_px == pytest.approx(0.06 * 160 * 120)
    assert finds[0].area_m2 is None


def test_an_empty_scene_gives_nothing() -> None:
    result = ThermalDetector().analyse(_scene(), _geometry(), 0.0)
    assert result.finds == [] and result.rejected == []
    assert 17.5 < result.ambient_c < 18.5


@pytest.mark.parametrize(
    "frame",
    [
        np.zeros((4, 4, 3), np.float32),
        np.zeros((120, 160), np.uint16),
        np.zeros((0, 5), np.float32),
    ],
)
def test_a_frame_that_is_not_temperatures_is_refused(frame: np.ndarray) -> None:
    with pytest.raises(VisionError, match="2-D float"):
        ThermalDetector().detect(frame, None, 0.0)


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"min_contrast_k": 0.0}, "min_contrast_k"),
        ({"max_skin_c": float("nan")}, "max_skin_c"),
        ({"min_body_c": 45.0}, "min_body_c"),
        ({"part_max_area_m2": 2.0}, "part_max_area_m2"),
        ({"photo_body_share": 1.5}, "photo_body_share"),
        ({"min_blob_px": 2.5}, "min_blob_px"),
        ({"min_peak_contrast_k": 1.0}, "min_peak_contrast_k"),
        ({"fade_min_span_s": 30.0}, "fade_min_span_s"),
        ({"merge_gap_m": "wide"}, "merge_gap_m"),
    ],
)
def test_each_setting_is_checked(change: dict[str, object], named: str) -> None:
    with pytest.raises(ValueError, match=named):
        ThermalDetectorParams(**change)  # type: ignore[arg-type]


def test_a_person_filling_most_of_the_view_is_still_found_in_a_stream() -> None:
    # The rover drives up to a person: after frames of bare floor, one fills 70 % of
    # the view and lifts the frame's median to body temperature. The room did not
    # warm: the ambient of the stream rises slowly, and the person is found.
    detector = ThermalDetector()
    geometry = _lepton_on_a_rover()
    for i in range(5):
        assert detector.analyse(_scene(seed=i), geometry, 0.1 * i).finds == []
    close = _scene(seed=9)
    close[36:120, 10:150] = 31.0  # a body 0.6 m away, across the view
    close[60:80, 60:90] = 34.0  # a face
    result = detector.analyse(close, geometry, 0.6)
    assert result.ambient_c < 19.0
    assert len(result.finds) == 1
    # A photo (no stream) has only its own median: the same picture alone shows none.
    assert ThermalDetector().analyse(close, None, 0.0).finds == []


def _warm_patch_at(
    t: np.ndarray,
    north_m: float,
    east_m: float,
    up_m: float,
    size_m: float,
    c: float,
    width_m: float | None = None,
) -> None:
    """A warm rectangle facing the rover, ``width_m`` (default ``size_m``) across and
    ``size_m`` high, its bottom ``up_m`` above the floor."""
    width_m = size_m if width_m is None else width_m
    from companion.calibration import camera_model
    from companion.config import Config, ThermalConfig
    from fusion.camera import rotation_zyx

    camera = camera_model(ThermalConfig())
    floor_down = Config().geolocation.floor_down_m
    pts = np.array(
        [
            [north_m, east_m + a, floor_down - up_m - b]
            for a in (-width_m / 2, width_m / 2)
            for b in (0.0, size_m)
        ]
    )
    px, _ = camera.project_ned(pts, np.zeros(3), rotation_zyx(0.0, 0.0, 0.0))
    (u0, v0), (u1, v1) = np.floor(px.min(axis=0)).astype(int), np.ceil(px.max(axis=0)).astype(int)
    t[max(v0, 0) : v1, max(u0, 0) : u1] = c


def test_a_face_over_the_edge_of_a_slab_is_placed_by_its_size_and_is_critical() -> None:
    # A face 0.35 m up (over a slab's edge) 1.5 m ahead: placed on the floor behind it
    # it would read 1.5 m too far and as metres of warmth; by a face's size it lies
    # where it is, and a face alone is a small part: CRITICAL.
    geometry = _lepton_on_a_rover()
    t = _scene()
    _warm_patch_at(t, 1.5, 0.0, 0.35, 0.16, 34.0)
    (find,) = ThermalDetector().analyse(t, geometry, 0.0).finds
    d = find.detection
    north, east = geometry.floor_ne_m(np.array([[d.u_px, d.v_px]]))[0]
    assert abs(north - 1.5) < 0.35 and abs(east) < 0.15
    assert "warm_part" in d.cues
    assessment = assess(d, geometry)
    assert assessment is not None and assessment.urgency == Urgency.CRITICAL


def test_a_warm_pipe_high_on_a_wall_is_no_one_lying() -> None:
    geometry = _lepton_on_a_rover()
    t = _scene()
    _warm_patch_at(t, 10.0, 0.0, 1.0, 0.1, 38.0, width_m=3.0)  # a hot water pipe, 1 m up
    result = ThermalDetector().analyse(t, geometry, 0.0)
    assert result.finds == []
    assert any("above the floor" in r.reason for r in result.rejected)


def test_heat_through_a_blanket_finds_a_person_but_shows_none_of_them() -> None:
    # A person under a blanket (5 K over the floor through it) with one hand out:
    # one find where the body lies, but only the bare hand is seen: CRITICAL.
    t = _scene()
    _ellipse(t, (80, 80), (1.7, 0.6), 23.0)  # the blanket over the body
    _ellipse(t, (110, 92), (0.12, 0.08), 33.0)  # the hand out of it
    geometry = _geometry()
    (find,) = ThermalDetector().analyse(t, geometry, 0.0).finds
    d = find.detection
    assert find.area_m2 is not None and find.area_m2 > 0.3  # a body's size: the blanket
    assessment = assess(d, geometry)
    assert assessment is not None and assessment.urgency == Urgency.CRITICAL


@pytest.mark.parametrize(
    ("width_m", "part"),
    [(0.2, True), (0.5, False)],
    ids=["a head's end of a body, 0.2 m", "a torso's side, 0.5 m"],
)
def test_a_find_no_longer_than_a_forearm_is_a_part_whatever_its_pixels(
    width_m: float, part: bool
) -> None:
    # The uncovered end of a buried body, 0.2 m high, seen side on by the low camera
    # 2.5 m away: more pixels than 0.055 m² of a lying body would give there (its side
    # faces the camera, a lying body's top does not), yet no longer than a head: a
    # part alone, CRITICAL. A torso's side, as high and 0.5 m across, is no part.
    geometry = _lepton_on_a_rover()
    t = _scene()
    _warm_patch_at(t, 2.5, 0.0, 0.0, 0.2, 29.0, width_m=width_m)  # clothing, not skin
    (find,) = ThermalDetector().analyse(t, geometry, 0.0).finds
    assert find.area_m2 is not None and find.area_m2 > ThermalDetectorParams().part_max_area_m2
    assert ("warm_part" in find.detection.cues) is part
    assessment = assess(find.detection, geometry)
    assert assessment is not None and (assessment.urgency == Urgency.CRITICAL) is part


def test_a_small_find_cut_by_the_frame_is_not_sized_as_a_part() -> None:
    # The same 0.2 m end at the frame's left edge: how far it reaches out of view is
    # unknown, so its size says nothing.
    geometry = _lepton_on_a_rover()
    t = _scene()
    _warm_patch_at(t, 2.5, 0.0, 0.0, 0.2, 29.0)
    x = int(np.nonzero((t > 25.0).any(axis=0))[0].min())
    t = np.ascontiguousarray(t[:, x + 2 :])  # the patch's left 2 columns out of view
    t = np.pad(t, ((0, 0), (0, x + 2)), mode="edge")
    (find,) = ThermalDetector().analyse(t, geometry, 0.0).finds
    assert find.detection.bbox_xywh_px[0] == 0
    assert "warm_part" not in find.detection.cues


def _lepton_at(north_m: float) -> FrameGeometry:
    """The Lepton of ``_lepton_on_a_rover`` on a rover ``north_m`` north, facing north."""
    from companion.calibration import camera_model
    from companion.config import Config, ThermalConfig
    from fusion.types import PoseSample

    pose = PoseSample(0.0, 0.0, north_m, 0.0, 0.0, 0.0, 0.0, 0.0)
    return FrameGeometry.from_pose(camera_model(ThermalConfig()), pose, Config().geolocation)


def _quad(t: np.ndarray, geometry: FrameGeometry, near: list, far: list, c: float) -> None:
    """Fill the pixels between the floor points ``near`` (two, its lower corners) and
    ``far`` (two floor points whose pixels are its upper corners) with ``c``."""
    px = geometry.pixels_of_floor(np.array(near + far))
    assert px is not None and np.isfinite(px).all()
    cv2.fillConvexPoly(t, np.round(px[[0, 1, 3, 2]]).astype(np.int32), float(c))


@pytest.mark.parametrize("up_m", [0.0, 0.12])
def test_warmth_flat_on_the_floor_is_told_from_a_body_by_the_rovers_motion(up_m: float) -> None:
    # A warm patch 0.5 m wide, its near edge 3 m north; its far side (its top row) is
    # either on the floor 0.6 m beyond (floor heating) or 0.12 m up (a leg, a body's
    # upper side), which seen from 0.3 m up meets the floor at 5/3 of its range, a
    # point that moves as the rover does. The rover drives north 0.1 m a frame.
    detector = ThermalDetector()
    cues: list[tuple[str, ...]] = []
    reasons: list[str] = []
    for i in range(16):
        north = 0.1 * i
        geometry = _lepton_at(north)
        camera = geometry.along_ray(np.array([[80.0, 60.0]]), 0.0)
        assert camera is not None
        k = camera[0, 2] / (camera[0, 2] - up_m)  # where the far side's ray meets the floor
        far_n = north + (3.6 - north) * k
        t = _scene(seed=i)
        _quad(t, geometry, [(3.0, -0.25), (3.0, 0.25)], [(far_n, -0.25), (far_n, 0.25)], 31.0)
        result = detector.analyse(t, geometry, 0.2 * i)
        cues += [f.detection.cues for f in result.finds] or [()]
        reasons += [r.reason for r in result.rejected]
    # Found at once, but unsettled (no support for a victim) until the rover has
    # moved 1 m along the line of sight (frame 10 and on)...
    assert cues[:10] == [("warm", UNSETTLED)] * 10, cues
    if up_m == 0.0:
        # ...then turned down as flat on the floor.
        assert cues[11:] == [()] * 5, cues
        assert reasons[-1].startswith("flat on the floor"), reasons
    else:
        # ...then a settled find in every frame: raised.
        assert cues[11:] == [("warm",)] * 5, cues
        assert not any(r.startswith("flat on the floor") for r in reasons)
