"""FLIR radiometric JPEGs: the real photos read to plausible temperatures with
exiftool, false-colour pictures refused by name, damaged files refused in one line
(companion/sources/flir.py). Skips, naming what is missing, without the real data
or exiftool."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.errors import CompanionError
from companion.sources import flir
from companion.sources.flir import (
    ExiftoolMissing,
    FlirCalibration,
    FlirError,
    NotRadiometric,
    calibration_of,
    decode_raw,
    raw_to_celsius,
    read_flir,
)

needs_exiftool = pytest.mark.skipif(
    shutil.which("exiftool") is None,
    reason="exiftool not installed (tools/system-packages.sh installs libimage-exiftool-perl)",
)

# (folder, file): (median lo..hi, max lo..hi) in °C, from what each photo shows and
# what its README / the data's README says of it.
RADIOMETRIC = {
    ("people_thermal", "wm_infrared_people_in_laboratory.jpg"): ((18, 24), (32, 37)),
    ("people_thermal", "wm_videocamera_termica_seated_group.jpg"): ((20, 30), (33, 38)),
    # two people in a street at night: cold surroundings, faces barely resolved
    ("people_thermal", "wm_thermographie_de_rue_night.jpg"): ((2, 10), (18, 26)),
    # cold water; "about 27 °C at most"
    ("people_thermal", "wm_man_in_water_ir.jpg"): ((3, 10), (25, 29)),
    ("thermal_radiometric", "wm02_water_cooler.jpg"): ((15, 22), (20, 30)),
    ("thermal_radiometric", "wm03_ducks_swimming.jpg"): ((5, 12), (18, 27)),
    # a winter wall outside, the radiator's heat through it
    ("thermal_radiometric", "wm08_radiator_through_wall.jpg"): ((-8, 3), (5, 15)),
    # "floor heating up to about 34 °C"
    ("thermal_radiometric", "wm10_floor_heating_chair.jpg"): ((17, 23), (32, 36)),
    ("thermal_radiometric", "wm11_moving_car.jpg"): ((-5, 10), (10, 25)),
    ("thermal_radiometric", "wm13_hot_water_bowl.jpg"): ((17, 26), (33, 45)),
    ("thermal_radiometric", "wm18_steam_valves.jpg"): ((40, 150), (150, 250)),
    # "a background warmer than they are (about 40 °C)"
    ("thermal_radiometric", "wm20_flying_foxes_heat_event.jpg"): ((38, 48), (42, 55)),
    ("negatives", "wm_termografia_building_ir.jpg"): ((18, 30), (25, 35)),
}
FALSE_COLOUR = [
    ("people_thermal", "tdp_IMG_0002_4_two_people_far.jpg"),
    ("people_thermal", "tdp_IMG_0006_5_person_and_dog.jpg"),
    ("people_thermal", "tdp_IMG_0043_2_three_people_walking.jpg"),
    ("negatives", "tdp_IMG_0022_dog_only_thermal.jpg"),
]


@needs_exiftool
@pytest.mark.parametrize(("where", "bounds"), RADIOMETRIC.items(), ids=lambda x: str(x))
def test_each_radiometric_photo_reads_to_plausible_temperatures(
    shared_data: Path, where: tuple[str, str], bounds: tuple[tuple[int, int], tuple[int, int]]
) -> None:
    image = read_flir(shared_data / "images" / where[0] / where[1])
    t = image.temps_c
    assert t.dtype == np.float32 and t.ndim == 2 and np.isfinite(t).all()
    (med_lo, med_hi), (max_lo, max_hi) = bounds
    assert med_lo <= float(np.median(t)) <= med_hi
    assert max_lo <= float(t.max()) <= max_hi
    assert image.model  # the camera's name, for the benchmark's table


@needs_exiftool
def test_a_lepton_sized_photo_keeps_its_raw_size(shared_data: Path) -> None:
    street = shared_data / "images" / "people_thermal" / "wm_thermographie_de_rue_night.jpg"
    assert read_flir(street).temps_c.shape == (120, 160)


@needs_exiftool
@pytest.mark.parametrize("where", FALSE_COLOUR, ids=lambda x: x[1])
def test_false_colour_pictures_are_refused_by_name(
    shared_data: Path, where: tuple[str, str]
) -> None:
    path = shared_data / "images" / where[0] / where[1]
    with pytest.raises(NotRadiometric) as err:
        read_flir(path)
    message = str(err.value)
    assert str(path) in message and "not a FLIR radiometric JPEG" in message
    assert "\n" not in message
    assert isinstance(err.value, CompanionError)


@needs_exiftool
def test_damaged_files_are_refused_in_one_line(shared_data: Path, tmp_path: Path) -> None:
    source = shared_data / "images" / "people_thermal" / "wm_thermographie_de_rue_night.jpg"
    data = source.read_bytes()
    rng = np.random.default_rng(41)
    cases = {
        "empty.jpg": b"",
        "noise.jpg": rng.integers(0, 256, 5000, dtype=np.uint8).tobytes(),
        "cut_half.jpg": data[: len(data) // 2],
        "cut_early.jpg": data[:2000],
    }
    for i in range(8):
        damaged = bytearray(data)
        at = rng.integers(0, len(data), 40)
        damaged[at[0] : at[0] + 64] = rng.integers(
            0, 256, len(damaged[at[0] : at[0] + 64]), dtype=np.uint8
        ).tobytes()
        for a in at[1:]:
            damaged[a] ^= 0xFF
        cases[f"flipped_{i}.jpg"] = bytes(damaged)
    refused = 0
    for name, content in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        try:
            t = read_flir(path).temps_c
        except FlirError as exc:
            message = str(exc)
            assert message.startswith(str(path)) and "\n" not in message, message
            refused += 1
            continue
        # a flip that missed everything that matters still gives real temperatures
        assert np.isfinite(t).all() and t.min() >= -60 and t.max() <= 2100
    assert refused >= 4  # the empty, noise and cut files at least


@needs_exiftool
def test_raw_counts_in_the_wrong_byte_order_are_caught(
    shared_data: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The camera's RawValueMedian tells a misread raw image from a real one."""
    real_decode = flir.decode_raw

    def swapped(data: bytes, kind: str, path: Path) -> np.ndarray:
        return real_decode(data, kind, path).byteswap()

    monkeypatch.setattr(flir, "decode_raw", swapped)
    ducks = shared_data / "images" / "thermal_radiometric" / "wm03_ducks_swimming.jpg"  # PNG raw
    with pytest.raises(FlirError, match="wrong byte order"):
        read_flir(ducks)


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(FlirError, match="no such file"):
        read_flir(tmp_path / "nothing.jpg")


def test_without_exiftool_says_what_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "x.jpg"
    path.write_bytes(b"\xff\xd8\xff\xd9")
    monkeypatch.setattr(flir, "EXIFTOOL", "no-such-exiftool-here")
    with pytest.raises(ExiftoolMissing, match="libimage-exiftool-perl"):
        read_flir(path)


def _calibration(**change: float) -> FlirCalibration:
    values = dict(
        planck_r1=14936.059,
        planck_r2=0.011179726,
        planck_b=1397.1,
        planck_f=1.0,
        planck_o=-6159.0,
        emissivity=1.0,
        object_distance_m=0.0,
        reflected_c=20.0,
        atmosphere_c=20.0,
        humidity=0.5,
        window_c=20.0,
        window_transmission=1.0,
    )
    values.update(change)
    return FlirCalibration(**values)


def test_the_planck_curve_gives_back_a_black_body_temperature() -> None:
    cal = _calibration()
    for t_c in (-10.0, 0.0, 20.0, 37.0, 100.0):
        assert float(raw_to_celsius(_raw_of(cal, t_c), cal)[0]) == pytest.approx(t_c, abs=1e-6)


def _raw_of(cal: FlirCalibration, t_c: float) -> np.ndarray:
    """Raw counts of a black body at t_c."""
    radiance = cal.planck_r1 / (cal.planck_r2 * (np.exp(cal.planck_b / (t_c + 273.15)) - 1.0))
    return np.array([radiance - cal.planck_o])


def test_emissivity_below_one_corrects_towards_the_reflected_temperature() -> None:
    cal = _calibration()  # reflected 20 °C
    warm, cold = _raw_of(cal, 30.0), _raw_of(cal, 10.0)
    skin = _calibration(emissivity=0.95)
    # less emissive: what it shows is partly the 20 °C room, so it is truly farther from it
    assert 30.0 < float(raw_to_celsius(warm, skin)[0]) < 31.5
    assert 8.5 < float(raw_to_celsius(cold, skin)[0]) < 10.0


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"emissivity": 0.0}, "Emissivity"),
        ({"planck_r1": -1.0}, "Planck"),
        ({"planck_b": float("nan")}, "planck_b"),
        ({"reflected_c": 5000.0}, "ReflectedApparentTemperature"),
        ({"object_distance_m": -3.0}, "ObjectDistance"),
        ({"window_transmission": 0.0}, "IRWindowTransmission"),
    ],
)
def test_absurd_constants_are_named(change: dict[str, float], named: str) -> None:
    with pytest.raises(FlirError, match=named):
        _calibration(**change).check("x.jpg")


def test_constants_from_exiftool_tags_are_checked(tmp_path: Path) -> None:
    tags: dict[str, object] = {
        "PlanckR1": 14936.059,
        "PlanckR2": 0.011179726,
        "PlanckB": 1397.1,
        "PlanckF": 1,
        "PlanckO": -6159,
        "Emissivity": 0.95,
        "ObjectDistance": 4.0,
        "ReflectedApparentTemperature": 20.0,
        "AtmosphericTemperature": 25.0,
        "RelativeHumidity": 0.42,
    }
    cal = calibration_of(tags, tmp_path / "x.jpg")
    assert cal.humidity == pytest.approx(0.42) and cal.window_transmission == 1.0
    with pytest.raises(FlirError, match="no PlanckB"):
        calibration_of({k: v for k, v in tags.items() if k != "PlanckB"}, tmp_path / "x.jpg")
    with pytest.raises(FlirError, match="not a number"):
        calibration_of({**tags, "Emissivity": "high"}, tmp_path / "x.jpg")


def test_a_flir_png_raw_image_is_byte_swapped() -> None:
    counts = np.array([[15000, 16000], [17000, 18000]], np.uint16)
    ok, png = cv2.imencode(".png", counts.byteswap())  # as FLIR writes it
    assert ok
    assert (decode_raw(png.tobytes(), "PNG", Path("x.jpg")) == counts).all()
    ok, tiff = cv2.imencode(".tiff", counts)
    assert ok
    assert (decode_raw(tiff.tobytes(), "TIFF", Path("x.jpg")) == counts).all()
    with pytest.raises(FlirError, match="not 16-bit"):
        decode_raw(cv2.imencode(".png", counts.astype(np.uint8))[1].tobytes(), "PNG", Path("x"))
    with pytest.raises(FlirError, match="does not decode"):
        decode_raw(b"not a picture", "PNG", Path("x.jpg"))
