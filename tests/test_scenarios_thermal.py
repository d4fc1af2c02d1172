"""The simulated thermal camera: temperatures where they belong, the Lepton's noise and
flat-field pauses, determinism, the recorded thermal folder, and the world keys."""

from __future__ import annotations

import itertools
import json
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.calibration import camera_model
from companion.config_load import load_config
from fusion.camera import rotation_zyx
from scenarios.camera import THERMAL_FPS, default_camera, default_thermal_camera
from scenarios.motion import TruePose
from scenarios.record import record
from scenarios.render import Renderer, RenderOptions
from scenarios.thermal import (
    ThermalOptions,
    ThermalRenderer,
    decode_centikelvin_png,
    encode_centikelvin_png,
)
from scenarios.world import Debris, Floor, Victim, World, WorldError, preset, warm_object
from scenarios.worldfile import load_world_text, world_to_toml

CLEAN = ThermalOptions(noise_k=0.0, blur_sigma_px=0.0, ffc=False)
AMBIENT_C = 18.0
BODY_NE = (5.0, 4.0)


def _pose(n: float, e: float, yaw_deg: float) -> TruePose:
    return TruePose(0.0, n, e, -0.10, 0.0, 0.0, math.radians(yaw_deg))


def _victim(**kw: float) -> Victim:
    # Lying across the camera's view (head to the east), 2.5 m north of the pose below.
    return Victim(
        1, *BODY_NE, math.radians(90.0), 1.75, (198, 134, 66), (60, 90, 150), (50, 60, 90), **kw
    )


LOOK = _pose(BODY_NE[0] - 2.5, BODY_NE[1], 0.0)


def _pixel(pose: TruePose, point_ned: tuple[float, float, float]) -> tuple[int, int]:
    """Where a point lies in the thermal camera's image from the pose."""
    camera = default_thermal_camera()
    r_nb = rotation_zyx(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)
    px, inside = camera.project_ned(
        np.array([point_ned]), np.array([pose.north_m, pose.east_m, pose.down_m]), r_nb
    )
    assert inside[0]
    return round(float(px[0, 0])), round(float(px[0, 1]))


def _flat_world(**floor: float) -> World:
    return World(floor=Floor(temperature_variation_c=0.0, **floor), seed=4)


def test_the_thermal_camera_sits_beside_the_colour_one_as_a_lepton() -> None:
    thermal, colour = default_thermal_camera(), default_camera()
    k = thermal.intrinsics
    assert (k.width_px, k.height_px) == (160, 120)
    assert math.degrees(2 * math.atan(k.width_px / 2 / k.fx_px)) == pytest.approx(57.0, abs=0.5)
    assert thermal.mount.pitch_rad == colour.mount.pitch_rad
    offset = np.asarray(thermal.mount.position_body_m) - np.asarray(colour.mount.position_body_m)
    assert 0.0 < float(np.linalg.norm(offset)) <= 0.1


def test_a_body_is_warm_against_its_floor_skin_warmer_than_clothes() -> None:
    world = World(victims=(_victim(),), seed=1)
    frame = ThermalRenderer(world, options=CLEAN).render(LOOK, 1.0)
    temps = frame.temps_c
    assert temps.shape == (120, 160) and temps.dtype == np.float32
    body = world.victims[0].body()
    head = _pixel(LOOK, tuple(body.head_centre))
    chest = next(s for s in body.solids if s.name == "chest")
    torso = _pixel(LOOK, tuple(chest.a))
    floor_near = temps[115, 80]  # the floor a metre in front of the rover
    assert abs(floor_near - AMBIENT_C) < 2.0
    assert 32.0 <= temps[head[1], head[0]] <= 35.5  # the face or hair side: warm
    assert 27.0 <= temps[torso[1], torso[0]] <= 31.5  # clothing: cooler than skin
    assert temps[torso[1], torso[0]] > floor_near + 8.0
    assert frame.warm_px.get(1, 0) > 300


def test_a_slab_over_a_body_stays_ambient_thin_cover_shows_attenuated_warmth() -> None:
    def covered(kind: str) -> tuple[float, dict[int, int], World]:
        cover = Debris.box(kind, (120, 118, 110), *BODY_NE, 0.9, 2.2, 0.0)
        world = World(victims=(_victim(),), debris=(cover,), seed=1)
        frame = ThermalRenderer(world, options=CLEAN).render(LOOK, 1.0)
        return float(frame.temps_c.max()), frame.warm_px, world

    slab_max, slab_warm, slab_world = covered("slab")
    assert slab_world.victims[0].visibility_pct == 0.0
    assert slab_world.victims[0].warm_visibility_pct == 0.0
    assert slab_max < AMBIENT_C + 2.0 and slab_warm == {}
    cloth_max, cloth_warm, cloth_world = covered("cloth")
    assert cloth_world.victims[0].visibility_pct == 0.0  # the colour camera sees cloth
    assert cloth_world.victims[0].warm_visibility_pct == 100.0
    # 55 % of the body's excess over ambient: well above the floor, well below skin.
    assert AMBIENT_C + 4.0 < cloth_max < 30.0 and cloth_warm.get(1, 0) > 100
    dust = Debris.box("dust", (150, 150, 150), *BODY_NE, 0.9, 2.2, 0.0, heat_through=0.9)
    dusty = World(victims=(_victim(),), debris=(dust,), seed=1)
    dust_max = float(ThermalRenderer(dusty, options=CLEAN).render(LOOK, 1.0).temps_c.max())
    assert dust_max > cloth_max + 2.0  # more heat through: warmer


def test_warm_things_at_their_temperatures_and_drawn_in_colour() -> None:
    things = (
        warm_object("radiator", 5.0, 4.0, heading_rad=math.radians(90.0), temperature_c=55.0),
        warm_object("dog", 4.5, 3.0, heading_rad=math.radians(90.0)),
    )
    world = World(warm_objects=things, seed=2)
    look = _pose(1.5, 4.0, 0.0)
    frame = ThermalRenderer(world, options=CLEAN).render(look, 1.0)
    u, v = _pixel(look, (5.0, 4.0, -0.42))  # the radiator panel's middle
    assert 50.0 <= frame.temps_c[v, u] <= 60.0
    du, dv = _pixel(look, (4.5, 2.95, -0.12))  # the dog's flank
    assert 30.0 <= frame.temps_c[dv, du] <= 37.0
    assert frame.warm_px == {}  # no person
    colour = Renderer(world, options=RenderOptions(noise=False)).render(look).image
    bare = Renderer(World(seed=2), options=RenderOptions(noise=False)).render(look).image
    changed = np.abs(colour.astype(int) - bare.astype(int)).max(axis=2) > 30
    assert changed.sum() > 500  # the colour camera sees the radiator and the dog


def test_a_heated_floor_is_warm_and_an_imprint_fades() -> None:
    world = World(
        warm_objects=(
            warm_object("heated_floor", 4.0, 3.0, length_m=1.5, width_m=1.5, temperature_c=30.0),
            warm_object("imprint", 4.0, 5.0, length_m=1.6, width_m=0.6, fade_s=60.0),
        ),
        floor=Floor(temperature_variation_c=0.0),
        seed=2,
    )
    renderer = ThermalRenderer(world, options=CLEAN)
    pose = _pose(1.0, 4.0, 0.0)
    heated = _pixel(pose, (4.0, 3.0, 0.0))
    imprint = _pixel(pose, (4.0, 5.0, 0.0))
    early = renderer.render(pose, 0.0).temps_c
    late = renderer.render(pose, 300.0).temps_c
    assert 27.0 <= early[heated[1], heated[0]] <= 31.0
    assert late[heated[1], heated[0]] == pytest.approx(early[heated[1], heated[0]], abs=0.01)
    assert early[imprint[1], imprint[0]] > AMBIENT_C + 5.0
    assert late[imprint[1], imprint[0]] < AMBIENT_C + 0.2  # 5 time constants later


def test_deterministic_by_seed_and_noise_about_50_mk() -> None:
    world = World(victims=(_victim(),), floor=Floor(temperature_variation_c=0.0), seed=1)
    opts = ThermalOptions(ffc=False)
    a = ThermalRenderer(world, options=opts, seed=3).render(LOOK, 1.0, frame_key=7).temps_c
    b = ThermalRenderer(world, options=opts, seed=3).render(LOOK, 1.0, frame_key=7).temps_c
    c = ThermalRenderer(world, options=opts, seed=4).render(LOOK, 1.0, frame_key=7).temps_c
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    noise = (a - c)[100:, :].std() / math.sqrt(2.0)  # the floor: noise alone differs
    assert 0.04 <= noise <= 0.06


def test_flat_field_pauses_repeat_the_last_frame_for_half_a_second() -> None:
    world = World(victims=(_victim(),), seed=1)
    opts = ThermalOptions(ffc_period_s=20.0)
    renderer = ThermalRenderer(world, options=opts)
    frames = [
        renderer.render(LOOK, t, frame_key=i)
        for i, t in enumerate(np.arange(0.0, 60.0, 1.0 / THERMAL_FPS))
    ]
    frozen = [i for i, f in enumerate(frames) if f.frozen]
    runs = np.split(frozen, np.nonzero(np.diff(frozen) > 1)[0] + 1)
    assert len(runs) in (2, 3)  # every 20 s from a phase within the first period
    for run in runs:
        assert 4 <= len(run) <= 5  # 0.5 s at 8.7 frames/s
        for i in run:
            assert np.array_equal(frames[i].temps_c, frames[run[0] - 1].temps_c)
    live = [f.temps_c for f in frames if not f.frozen]
    assert not any(np.array_equal(x, y) for x, y in itertools.pairwise(live))
    # The default: one pause every three minutes.
    default = ThermalRenderer(world)
    ticks = np.arange(0.0, 400.0, 0.05)
    active = np.array([default.ffc_active(t) for t in ticks])
    starts = np.nonzero(active[1:] & ~active[:-1])[0]
    assert len(starts) == 2 and np.diff(ticks[starts])[0] == pytest.approx(180.0, abs=0.1)


def test_centikelvin_png_round_trip() -> None:
    temps = np.array([[18.0, 34.25], [-5.5, 88.0]], np.float32)
    back = decode_centikelvin_png(encode_centikelvin_png(temps))
    assert np.allclose(back, temps, atol=0.006)


def test_record_writes_thermal_frames_by_time_and_the_thermal_section(tmp_path: Path) -> None:
    world = preset("thermal_covered")
    res = record(world, tmp_path, duration_s=3.0, fps=5.0, start_unix_s=1_700_000_000.0)
    files = sorted((tmp_path / "thermal").iterdir())
    assert res.thermal_frames == len(files) == round(3.0 * THERMAL_FPS)
    stamps = []
    for path in files:
        assert re.fullmatch(r"\d+\.png", path.name)
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint16 and img.shape == (120, 160)
        celsius = img.astype(float) / 100.0 - 273.15
        assert 5.0 < float(np.median(celsius)) < 30.0
        stamps.append(int(path.stem))
    gaps_s = np.diff(stamps) / 1e6
    assert np.allclose(gaps_s, 1.0 / THERMAL_FPS, atol=2e-6)
    colour = sorted(int(p.stem) for p in (tmp_path / "frames").iterdir())
    assert stamps[0] >= 1_700_000_000_000_000 and stamps[-1] <= 1_700_000_003_000_000
    assert colour[0] < stamps[3] < colour[-1]  # interleaved on one clock
    config = load_config(tmp_path / "camera.toml")
    assert config.thermal is not None
    assert config.thermal.source == f"frames:{(tmp_path / 'thermal').resolve()}"
    assert camera_model(config.thermal) == default_thermal_camera()
    truth = json.loads((tmp_path / "ground_truth.json").read_text())
    shares = {v["victim_id"]: v["warm_visibility_pct"] for v in truth["victims"]}
    assert shares == {1: 100.0, 2: 100.0}
    assert truth["thermal"]["fps"] == THERMAL_FPS


def test_record_without_thermal_writes_neither_folder_nor_section(tmp_path: Path) -> None:
    res = record(preset("empty"), tmp_path, duration_s=1.0, fps=5.0, thermal=False)
    assert res.thermal_frames == 0 and not (tmp_path / "thermal").exists()
    assert load_config(tmp_path / "camera.toml").thermal is None


def test_the_thermal_presets_load_and_say_what_they_hold() -> None:
    assert preset("thermal_dark").floor.ambient_light < 0.05
    covered = preset("thermal_covered")
    assert all(v.visibility_pct < 10.0 < 99.0 < v.warm_visibility_pct for v in covered.victims)
    for name in ("thermal_warm_things", "thermal_warm_things2"):
        world = preset(name)
        assert world.victims == () and len({w.kind for w in world.warm_objects}) == 6
        assert load_world_text(world_to_toml(world), name) == world  # saved and read back


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ("[floor]\ntemperature_c = 99.0\n", r"w\.toml: floor\.temperature_c = 99\.0"),
        ("[floor]\ntemperature_variation_c = -1\n", r"floor\.temperature_variation_c"),
        (
            '[[debris]]\nkind = "cloth"\ncolour = "#808080"\n'
            "polygon_ne_m = [[1, 1], [1, 2], [2, 2]]\nheat_through = 1.5\n",
            r"w\.toml\.debris\[0\]: .*heat_through = 1\.5: must be in \[0, 1\]",
        ),
        (
            '[[warm_objects]]\nkind = "lamp"\nnorth_m = 1.0\neast_m = 1.0\n',
            r"w\.toml\.warm_objects\[0\]\.kind = 'lamp': one of radiator",
        ),
        (
            '[[warm_objects]]\nkind = "pipe"\nnorth_m = 1.0\neast_m = 1.0\ntemperature_c = 900\n',
            r"w\.toml\.warm_objects\[0\]: .*temperature_c = 900.*\[-30, 150\]",
        ),
        (
            '[[warm_objects]]\nkind = "dog"\nnorth_m = 1.0\neast_m = 1.0\nbark = 1\n',
            r"w\.toml\.warm_objects\[0\]\.bark: unknown key",
        ),
        (
            '[[warm_objects]]\nkind = "dog"\nnorth_m = 1.0\n',
            r"w\.toml\.warm_objects\[0\]\.east_m: missing",
        ),
        (
            '[[warm_objects]]\nkind = "radiator"\nnorth_m = 50.0\neast_m = 1.0\n',
            r"w\.toml: warm_objects \(radiator\) at \(50\.0, 1\.0\) is off the floor",
        ),
        (
            '[[warm_objects]]\nkind = "imprint"\nnorth_m = 1.0\neast_m = 1.0\nfade_s = 0\n',
            r"w\.toml\.warm_objects\[0\]: .*fade_s must be in \(0, 1e6\]",
        ),
        (
            "[[victims]]\nvictim_id = 1\nnorth_m = 5.0\neast_m = 4.0\nheading_deg = 0\n"
            'height_m = 1.7\nskin = "#c68642"\ntop = "#1e286e"\ntrousers = "#6e6446"\n'
            "skin_c = 50\n",
            r"w\.toml\.victims\[0\]: .*skin_c = 50\.0: must be in \[20, 42\]",
        ),
    ],
)
def test_world_file_errors_for_the_thermal_keys_name_file_and_key(edit: str, message: str) -> None:
    with pytest.raises(WorldError, match=message) as info:
        load_world_text('format = "rescue-sim-world/1"\n' + edit, "w.toml")
    assert "\n" not in str(info.value)


def test_the_thermal_burial_benchmark_views_show_the_warm_share_asked_for() -> None:
    from bench.sim_burial import MIN_THERMAL_VIEW_PX, thermal_views

    view = next(thermal_views(5))
    assert 4.0 <= view.victim.warm_visibility_pct <= 6.5
    assert view.warm_px >= MIN_THERMAL_VIEW_PX
    assert view.temps_c.shape == (120, 160)
    assert float(view.temps_c.max()) > 30.0  # the part that shows is warm


def test_a_victim_seen_only_warm_counts_as_in_view_from_its_first_warm_frame() -> None:
    from scenarios.score import truth_from_dict

    def entry(vid: int, colour: float | None, warm: float | None) -> dict[str, object]:
        return {
            "victim_id": vid,
            "north_m": 1.0,
            "east_m": 1.0,
            "urgency": "CRITICAL",
            "first_in_view_unix_s": colour,
            "first_warm_in_view_unix_s": warm,
        }

    truth = truth_from_dict(
        {
            "victims": [
                entry(1, None, 12.5),  # under a blanket: only the thermal camera sees it
                entry(2, 30.0, 20.0),
                entry(3, 5.0, None),
                entry(4, None, None),
            ]
        }
    )
    seen = {v.victim_id: v.first_in_view_unix_s for v in truth.victims}
    assert seen == {1: 12.5, 2: 20.0, 3: 5.0, 4: None}


def test_the_rover_drives_around_solid_warm_things_and_over_warm_floor() -> None:
    from scenarios.pathplan import Obstacles

    world = World(
        warm_objects=(
            warm_object("machinery", 4.0, 2.0),
            warm_object("dog", 8.0, 2.0),
            warm_object("heated_floor", 6.0, 5.0),
            warm_object("imprint", 9.0, 5.0),
        ),
        seed=2,
    )
    obstacles = Obstacles(world)
    for n, e, blocked in ((4.0, 2.0, True), (8.0, 2.0, True), (6.0, 5.0, False), (9.0, 5.0, False)):
        assert bool(obstacles.blocked[obstacles.cell((n, e))]) is blocked


def test_the_contact_sheet_shows_warm_things_and_thermal_insets() -> None:
    from scenarios.sheet import contact_sheet

    world = World(warm_objects=(warm_object("machinery", 3.0, 0.9, temperature_c=80.0),), seed=2)
    sheet = contact_sheet(world, frames=2)
    magenta = (sheet[:, :, 0] > 200) & (sheet[:, :, 1] < 120) & (sheet[:, :, 2] > 200)
    assert magenta.sum() > 100  # the machine outlined on the map
    # Each of the two tiles has its thermal inset: the floor near ambient in inferno's
    # dark purple, which no grey or lit colour frame shows.
    b, g, r = (sheet[:, :, i].astype(int) for i in range(3))
    purple = (g < 30) & (b > g + 25) & (r > g + 5)
    assert purple.sum() > 2 * 128 * 96 * 0.25  # the floor: below the dark walls
