"""``rescue-companion detect``: what it prints for images and videos, what it writes
with --annotate, and how it names every input it cannot read (exit status 2)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.commands.detect import run_detect
from tests.badimages import avi_with_a_damaged_frame, huge_jpeg

URGENCIES = {"LIGHT", "MEDIUM", "CRITICAL", None}
DETECTION_KEYS = {"box", "score", "cues", "visibility_pct", "urgency"}


def _detect(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "companion.commands.cli", "detect", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


def _json_lines(stdout: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in stdout.splitlines() if line.strip()]


def _room(seed: int, size: tuple[int, int] = (480, 640)) -> np.ndarray:
    """An empty room the test draws: a floor, a wall, a box (no person)."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = np.full((h, w, 3), (150, 160, 170), np.uint8)
    img[h // 2 :] = (70, 100, 130)
    cv2.rectangle(img, (w // 3, h // 2 - 40), (w // 3 + 90, h // 2 + 30), (40, 80, 120), -1)
    noise = rng.integers(-6, 7, img.shape)
    return np.clip(img.astype(int) + noise, 0, 255).astype(np.uint8)


def _write_video(path: Path, frames: list[np.ndarray], fps: float = 10.0) -> None:
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()


def _frame_count(path: Path) -> int:
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def test_an_image_without_people_prints_no_detection_and_annotates(tmp_path: Path) -> None:
    image = tmp_path / "room.png"
    cv2.imwrite(str(image), _room(1))
    done = _detect("--json", "--annotate", tmp_path / "ann", image)
    assert done.returncode == 0, done.stderr
    (doc,) = _json_lines(done.stdout)
    assert doc["image"] == str(image) and doc["detections"] == []
    assert isinstance(doc["ms"], float) and doc["ms"] > 0.0
    drawn = cv2.imread(str(tmp_path / "ann" / "room.png"))
    assert drawn is not None and drawn.shape == (480, 640, 3)


def test_real_people_are_described_and_drawn(shared_data: Path, tmp_path: Path) -> None:
    frames = shared_data / "images" / "real_falls" / "frames"
    image = sorted(frames.iterdir())[0]
    done = _detect("--json", "--annotate", tmp_path, image)
    assert done.returncode == 0, done.stderr
    (doc,) = _json_lines(done.stdout)
    dets = doc["detections"]
    assert isinstance(dets, list) and dets
    for d in dets:
        assert set(d) == DETECTION_KEYS
        assert d["urgency"] in URGENCIES and "person" in d["cues"]
        x, y, w, h = d["box"]
        assert x >= 0 and y >= 0 and w > 0 and h > 0 and 0.0 <= d["score"] <= 1.0
    text = _detect(image)
    assert text.returncode == 0 and f"{image}: {len(dets)} detection(s)" in text.stdout
    original, drawn = cv2.imread(str(image)), cv2.imread(str(tmp_path / f"{image.stem}.png"))
    assert drawn.shape == original.shape and not np.array_equal(drawn, original)


def test_every_unreadable_input_is_named_and_the_rest_still_run(tmp_path: Path) -> None:
    good = tmp_path / "a_good.png"
    cv2.imwrite(str(good), _room(2))
    jpeg = cv2.imencode(".jpg", _room(3))[1].tobytes()
    png = cv2.imencode(".png", _room(4))[1].tobytes()
    bad = {
        "b_cut.jpg": jpeg[: len(jpeg) // 2],
        "c_cut.png": png[: len(png) // 2],
        "d_noise.jpg": bytes(range(256)) * 8,
        "e_empty.png": b"",
        "e_huge.jpg": huge_jpeg(),
        "f_noise.mp4": b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 4,
    }
    for name, data in bad.items():
        (tmp_path / name).write_bytes(data)
    done = _detect("--json", tmp_path, tmp_path / "g_missing.jpg")
    assert done.returncode == 2
    assert [d["image"] for d in _json_lines(done.stdout)] == [str(good)]
    complaints = [ln for ln in done.stderr.splitlines() if ln.startswith("rescue-companion")]
    for name in [*bad, "g_missing.jpg"]:
        assert sum(name in ln for ln in complaints) == 1, (name, done.stderr)
    assert "Traceback" not in done.stderr


def test_a_video_is_detected_frame_by_frame(tmp_path: Path) -> None:
    video = tmp_path / "walk.mp4"
    _write_video(video, [_room(i) for i in range(7)], fps=5.0)
    done = _detect("--json", "--every", "3", "--annotate", tmp_path / "ann", video)
    assert done.returncode == 0, done.stderr
    docs = _json_lines(done.stdout)
    assert [(d["image"], d["frame"], d["t_s"]) for d in docs] == [
        (str(video), 0, 0.0),
        (str(video), 3, 0.6),
        (str(video), 6, 1.2),
    ]
    assert all(d["detections"] == [] for d in docs)
    assert _frame_count(tmp_path / "ann" / "walk.mp4") == 3
    text = _detect(video)
    assert text.returncode == 0
    assert f"{video}: 7 frames, 7 detected (every 1), 0 with detections" in text.stdout


def test_a_cut_video_keeps_its_frames_and_is_named(tmp_path: Path) -> None:
    """An AVI cut in half still decodes its first frames; the shortfall is reported."""
    whole = tmp_path / "whole.avi"
    writer = cv2.VideoWriter(str(whole), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, (320, 240))
    for i in range(20):
        writer.write(cv2.resize(_room(i), (320, 240)))
    writer.release()
    cut = tmp_path / "cut.avi"
    data = whole.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    done = _detect("--json", cut)
    assert done.returncode == 2
    frames = [d["frame"] for d in _json_lines(done.stdout)]
    assert frames == list(range(len(frames))) and 0 < len(frames) < 20
    assert str(cut) in done.stderr and "Traceback" not in done.stderr


def test_frames_after_a_damaged_one_are_still_detected(tmp_path: Path) -> None:
    """One frame of an AVI of JPEG frames zeroed: it is skipped and counted, and the
    six frames after it are detected."""
    damaged = tmp_path / "damaged.avi"
    avi_with_a_damaged_frame(damaged, [cv2.resize(_room(i), (160, 120)) for i in range(12)], 5)
    done = _detect("--json", damaged)
    assert done.returncode == 2
    assert [d["frame"] for d in _json_lines(done.stdout)] == [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11]
    assert f"{damaged}: 1 of its 12 frames could not be decoded" in done.stderr


def test_damaged_video_bytes_are_detected_on_or_named(tmp_path: Path) -> None:
    """Videos with bytes changed or cut at seeded places (an AVI of JPEG frames and an
    MP4), all in one run: each file gives JSON lines, is named on stderr, or both;
    never a traceback, and the run ends."""
    rng = np.random.default_rng(7)
    frames = [cv2.resize(_room(i), (160, 120)) for i in range(12)]
    seeds = {}
    for suffix, codec in ((".avi", "MJPG"), (".mp4", "mp4v")):
        path = tmp_path / f"seed{suffix}"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*codec), 10.0, (160, 120))
        for f in frames:
            writer.write(f)
        writer.release()
        seeds[suffix] = path.read_bytes()
    names = []
    for k in range(16):
        suffix = (".avi", ".mp4")[k % 2]
        data = bytearray(seeds[suffix])
        for where in rng.integers(0, len(data), size=int(rng.integers(1, 40))):
            data[where] = int(rng.integers(0, 256))
        if k % 3 == 0:
            data = data[: int(rng.integers(0, len(data)))]
        name = f"damaged{k:02d}{suffix}"
        (tmp_path / name).write_bytes(bytes(data))
        names.append(name)
    done = _detect("--json", *(tmp_path / n for n in names))
    assert done.returncode in (0, 2)
    assert "Traceback" not in done.stderr
    printed = {Path(str(d["image"])).name for d in _json_lines(done.stdout)}
    complaints = [ln for ln in done.stderr.splitlines() if ln.startswith("rescue-companion")]
    for name in names:
        assert name in printed or any(name in ln for ln in complaints), name
    assert done.returncode == (2 if complaints else 0)


def test_people_in_the_real_video(shared_data: Path) -> None:
    """The shared video: a room, empty at first, then people walking in one at a time."""
    video = shared_data / "video" / "intel_one-by-one-person-detection.mp4"
    done = _detect("--json", "--every", "100", video)
    assert done.returncode == 0, done.stderr
    docs = _json_lines(done.stdout)
    assert [d["frame"] for d in docs] == list(range(0, 1394, 100))
    assert docs[0]["detections"] == []  # frame 0: the empty room (negatives/)
    people = [d for d in docs if d["detections"]]
    assert len(people) >= len(docs) // 2
    assert all("person" in det["cues"] for d in people for det in d["detections"])


def test_every_must_be_a_positive_whole_number() -> None:
    for value in ("0", "-2", "x"):
        done = _detect("--every", value, "a.mp4")
        assert done.returncode == 2 and "--every" in done.stderr and "Traceback" not in done.stderr


@settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    kind=st.sampled_from([".jpg", ".png"]),
    cut=st.floats(0.0, 1.0),
    flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=8),
)
def test_damaged_image_bytes_never_raise(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    kind: str,
    cut: float,
    flips: list[tuple[float, int]],
) -> None:
    """Any cut and any changed bytes of a valid image: the image is detected on or
    named as unreadable, never a traceback."""
    data = bytearray(cv2.imencode(kind, _room(5, (96, 128)))[1].tobytes())
    data = data[: max(0, round(cut * len(data)))] if cut < 0.98 else data
    for where, value in flips:
        if data:
            data[min(len(data) - 1, int(where * len(data)))] = value
    path = tmp_path / f"fuzz{kind}"
    path.write_bytes(bytes(data))
    status = run_detect(None, [path], True, None)
    out, err = capsys.readouterr()
    assert status in (0, 2)
    if status == 0:
        assert json.loads(out)["image"] == str(path)
    else:
        assert out == "" and str(path) in err


# --- thermal pictures ----------------------------------------------------------

THERMAL_KEYS = DETECTION_KEYS | {"peak_c", "mean_c", "area_m2"}


def _centikelvin_png(path: Path, temps_c: np.ndarray) -> None:
    assert cv2.imwrite(str(path), np.round((temps_c + 273.15) * 100.0).astype(np.uint16))


def _cold_room_with_a_hand(warm_c: float) -> np.ndarray:
    rng = np.random.default_rng(5)
    temps = 18.0 + rng.normal(0.0, 0.05, (120, 160))
    temps[70:76, 50:56] = warm_c  # a hand, 6x6 Lepton pixels
    return temps


@pytest.mark.skipif(shutil.which("exiftool") is None, reason="exiftool missing")
def test_a_radiometric_jpeg_gives_temperatures_and_a_false_colour_picture(
    shared_data: Path, tmp_path: Path
) -> None:
    photo = shared_data / "images" / "people_thermal" / "wm_man_in_water_ir.jpg"
    done = _detect("--json", "--annotate", tmp_path, photo)
    assert done.returncode == 0, done.stderr
    (doc,) = _json_lines(done.stdout)
    temps = doc["thermal"]
    assert isinstance(temps, dict)
    assert temps["min_c"] < temps["ambient_c"] < temps["max_c"]
    assert 5.0 < temps["ambient_c"] < 9.0 and 25.0 < temps["max_c"] < 29.0
    dets = doc["detections"]
    assert isinstance(dets, list)
    man = [d for d in dets if d["box"][0] <= 328 < d["box"][0] + d["box"][2]]
    assert len(man) == 1 and set(man[0]) == THERMAL_KEYS
    assert man[0]["cues"] == ["warm", "warm_part"] and man[0]["urgency"] == "CRITICAL"
    assert man[0]["peak_c"] == pytest.approx(temps["max_c"], abs=0.5)
    drawn = cv2.imread(str(tmp_path / "wm_man_in_water_ir.png"))
    assert drawn is not None and drawn.shape[0] == 480 and drawn.shape[1] > 640  # + the scale
    b, _g, r = (drawn[..., i].astype(int) for i in range(3))
    assert (np.abs(r - b) > 40).mean() > 0.1  # false colour, not grey
    text = _detect(photo)
    assert text.returncode == 0 and "ambient" in text.stdout and "peak" in text.stdout


def test_a_thermal_frames_folder_is_read_in_centi_kelvin(tmp_path: Path) -> None:
    frames = tmp_path / "thermal"
    frames.mkdir()
    t0_us = 1_764_000_000_000_000
    for i in range(3):
        _centikelvin_png(frames / f"{t0_us + i * 115_000}.png", _cold_room_with_a_hand(32.0))
    done = _detect("--json", "--annotate", tmp_path / "ann", frames)
    assert done.returncode == 0, done.stderr
    docs = _json_lines(done.stdout)
    assert [Path(str(d["image"])).name for d in docs] == sorted(p.name for p in frames.iterdir())
    for doc in docs:
        assert doc["thermal"]["ambient_c"] == pytest.approx(18.0, abs=0.1)  # type: ignore[index]
        dets = doc["detections"]
        assert isinstance(dets, list) and len(dets) == 1
        hand = dets[0]
        assert hand["box"] == [50, 70, 6, 6]
        assert hand["peak_c"] == pytest.approx(32.0, abs=0.01)
        assert hand["cues"] == ["warm", "warm_part"]
    assert len(list((tmp_path / "ann").glob("*.png"))) == 3


def test_thermal_pictures_that_are_not_temperatures_are_named(tmp_path: Path) -> None:
    zeros = tmp_path / "a_zeros.png"  # 0 centi-kelvin: a dead or unconverted frame
    assert cv2.imwrite(str(zeros), np.zeros((120, 160), np.uint16))
    good = tmp_path / "b_good.png"
    _centikelvin_png(good, _cold_room_with_a_hand(31.0))
    flir_cut = tmp_path / "c_cut.jpg"
    flir_cut.write_bytes(b"\xff\xd8\xff\xe1\x00\x10FLIR\x00\x01" + bytes(100))
    done = _detect("--json", zeros, good, flir_cut)
    assert done.returncode == 2
    assert [d["image"] for d in _json_lines(done.stdout)] == [str(good)]
    complaints = [ln for ln in done.stderr.splitlines() if ln.startswith("rescue-companion")]
    assert sum("a_zeros.png" in ln and "centi-kelvin" in ln for ln in complaints) == 1
    assert sum("c_cut.jpg" in ln for ln in complaints) == 1
    assert "Traceback" not in done.stderr


def test_with_a_thermal_camera_configured_finds_have_a_floor_area(tmp_path: Path) -> None:
    config = tmp_path / "rover.toml"
    config.write_text("[thermal]\n")  # a Lepton 3.5 on the default mount, 0.3 m up
    frame = tmp_path / "1764000000000000.png"
    temps = 18.0 + np.random.default_rng(6).normal(0.0, 0.05, (120, 160))
    temps[76:86, 70:82] = 32.0  # a hand about 1 m ahead, on the floor
    _centikelvin_png(frame, temps)
    done = _detect("--json", "--config", config, frame)
    assert done.returncode == 0, done.stderr
    (doc,) = _json_lines(done.stdout)
    dets = doc["detections"]
    assert isinstance(dets, list) and len(dets) == 1
    (hand,) = dets
    assert hand["box"] == [70, 76, 12, 10] and hand["cues"] == ["warm", "warm_part"]
    assert 0.004 < hand["area_m2"] < 0.055 and hand["urgency"] == "CRITICAL"
    alone = _detect("--json", frame)
    assert all(d["area_m2"] is None for d in _json_lines(alone.stdout)[0]["detections"])  # type: ignore[union-attr]
