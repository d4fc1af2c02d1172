"""Thermal camera sources: the Lepton on a PureThermal board and the InfiRay P2 Pro /
TC001 against a pseudo-device behind cv2.VideoCapture's interface (no camera is
plugged in here), the recorded frames folder with real PNG files, the simulator's
thermal camera over real sockets, and every input that is not temperatures giving one
line (CameraError, or a frame skipped and said) and never a traceback."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import queue
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.config import ThermalConfig
from companion.sources.base import CameraError, CameraTimeout, EndOfStream
from companion.sources.sim import encode_sim_frame
from companion.sources.thermal import ThermalFrame, ThermalSpec, parse_thermal_source
from companion.sources.thermal_folder import ThermalFramesDir, write_thermal_frame
from companion.sources.thermal_live import ThermalCaptureSource, find_purethermal
from companion.sources.thermal_open import ReopeningThermalSource, open_thermal
from companion.sources.thermal_raw import ThermalJudge, object_temps_c
from companion.sources.thermal_sim import ThermalSimSource
from tests.jsonfuzz import fuzz_settings

FOURCC_Y16 = float(cv2.VideoWriter.fourcc(*"Y16 "))
FOURCC_YUYV = float(cv2.VideoWriter.fourcc(*"YUYV"))
RNG = np.random.default_rng(41)


class PseudoV4L2:
    """A V4L2 thermal camera where none is plugged in: the part of cv2.VideoCapture
    the sources use (open/set/get/read/release), recording every property call. As
    OpenCV does, setting the format turns the conversion to RGB back on, and a frame
    read with it on arrives as an 8-bit BGR picture."""

    def __init__(self, formats: tuple[str, ...] = ("Y16 ", "YUYV"), opens: bool = True) -> None:
        self.formats = formats
        self.opens = opens
        self.calls: list[tuple[Any, ...]] = []
        self.convert_rgb = True
        self.fourcc = FOURCC_YUYV
        self.frames: queue.Queue[np.ndarray | None] = queue.Queue()  # None: pulled out
        self.unplugged = False
        self.released = False

    def open(self, filename: str, api: int, /) -> bool:
        self.calls.append(("open", filename, api))
        return self.opens

    def set(self, prop: int, value: float, /) -> bool:
        self.calls.append(("set", prop, value))
        if prop == cv2.CAP_PROP_FOURCC:
            code = "".join(chr((int(value) >> (8 * i)) & 0xFF) for i in range(4))
            if code not in self.formats:
                return False
            self.fourcc, self.convert_rgb = value, True
        elif prop == cv2.CAP_PROP_CONVERT_RGB:
            self.convert_rgb = bool(value)
        return True

    def get(self, prop: int, /) -> float:
        self.calls.append(("get", prop))
        return self.fourcc if prop == cv2.CAP_PROP_FOURCC else 0.0

    def read(self) -> tuple[bool, Any]:
        while not self.unplugged:
            try:
                frame = self.frames.get(timeout=0.02)
            except queue.Empty:
                continue
            if frame is None:
                break
            if self.convert_rgb and frame.ndim == 2:
                gray = cv2.normalize(frame, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
                return True, cv2.applyColorMap(gray, cv2.COLORMAP_INFERNO)
            return True, frame
        return False, None

    def release(self) -> None:
        self.released = True


@pytest.fixture
def devices() -> Iterator[list[tuple[PseudoV4L2, Any]]]:
    """(device, source) pairs made by the test, unplugged and closed after it."""
    made: list[tuple[PseudoV4L2, Any]] = []
    yield made
    for device, source in made:
        device.unplugged = True
        source.close()


def _open(
    devices: list[tuple[PseudoV4L2, Any]],
    kind: str = "lepton",
    size: tuple[int, int] = (160, 120),
    emissivity: float = 1.0,
    device: PseudoV4L2 | None = None,
) -> tuple[PseudoV4L2, ThermalCaptureSource]:
    dev = device or PseudoV4L2()
    source = ThermalCaptureSource(
        "/dev/video3",
        kind,
        size[0],
        size[1],
        8.7,
        emissivity,
        lambda: dev,
    )
    devices.append((dev, source))
    return dev, source


def _centi_k(temps_c: np.ndarray) -> np.ndarray:
    return np.rint((temps_c + 273.15) * 100).astype(np.uint16)


def _scene_c(h: int = 120, w: int = 160) -> np.ndarray:
    """A room at 20 °C with sensor noise and a person's warm patch at 34 °C."""
    temps = 20.0 + RNG.normal(0.0, 0.05, (h, w))
    temps[40:70, 60:100] = 34.0 + RNG.normal(0.0, 0.05, (30, 40))
    return temps


def _yuyv(temps_c: np.ndarray) -> np.ndarray:
    """An InfiRay frame: a false-colour picture above, kelvin x 64 below, as bytes."""
    h, w = temps_c.shape
    words = np.rint((temps_c + 273.15) * 64).astype("<u2")
    below = words.view(np.uint8).reshape(h, w, 2)
    above = RNG.integers(0, 256, (h, w, 2), dtype=np.uint8)
    return np.concatenate([above, below])


def test_lepton_sets_y16_then_convert_rgb_off(devices: list[Any]) -> None:
    dev, source = _open(devices)
    assert dev.calls[0] == ("open", "/dev/video3", cv2.CAP_V4L2)
    sets = [c for c in dev.calls if c[0] == "set"]
    props = [c[1] for c in sets]
    assert sets[props.index(cv2.CAP_PROP_FOURCC)][2] == FOURCC_Y16
    assert props.index(cv2.CAP_PROP_FOURCC) < props.index(cv2.CAP_PROP_CONVERT_RGB)
    assert sets[-1] == ("set", cv2.CAP_PROP_CONVERT_RGB, 0)  # nothing turns it back on
    scene = _scene_c()
    dev.frames.put(_centi_k(scene))
    frame = source.read(2.0)
    assert isinstance(frame, ThermalFrame) and frame.temps_c.dtype == np.float32
    assert np.abs(frame.temps_c - scene).max() < 0.006  # centi-kelvin, exactly
    assert frame.index == 0 and abs(frame.t_unix_s - time.time()) < 2.0
    assert source.status == "ok"


def test_lepton_drops_its_two_telemetry_rows(devices: list[Any]) -> None:
    dev, source = _open(devices)
    scene = _scene_c()
    telemetry = RNG.integers(0, 65536, (2, 160), dtype=np.uint16)  # not temperatures
    dev.frames.put(np.concatenate([_centi_k(scene), telemetry]))
    frame = source.read(2.0)
    assert frame.temps_c.shape == (120, 160)
    assert np.abs(frame.temps_c - scene).max() < 0.006


def test_emissivity_corrects_what_differs_from_the_room(devices: list[Any]) -> None:
    dev, source = _open(devices, emissivity=0.98)
    scene = _scene_c()
    dev.frames.put(_centi_k(scene))
    temps = source.read(2.0).temps_c
    # Skin seen at 34 °C in a 20 °C room is warmer than it looks; the room is the room.
    assert 34.2 < float(np.median(temps[40:70, 60:100])) < 34.4
    assert float(np.median(temps[:30])) == pytest.approx(20.0, abs=0.02)
    unchanged = object_temps_c(np.full((2, 2), 300.0, np.float32), 1.0)  # emissivity 1
    assert np.allclose(unchanged, 26.85, atol=1e-4)


@pytest.mark.parametrize("flat", [False, True])
def test_infiray_bottom_half_in_kelvin_x64(devices: list[Any], flat: bool) -> None:
    dev, source = _open(devices, "infiray", (256, 192))
    sets = [c[1] for c in dev.calls if c[0] == "set"]
    assert sets.index(cv2.CAP_PROP_FOURCC) < sets.index(cv2.CAP_PROP_CONVERT_RGB) == len(sets) - 1
    assert ("set", cv2.CAP_PROP_FRAME_HEIGHT, 384) in dev.calls
    scene = _scene_c(192, 256)
    raw = _yuyv(scene)
    assert raw.shape == (384, 256, 2)
    dev.frames.put(raw.reshape(1, -1) if flat else raw)  # OpenCV hands either over
    frame = source.read(2.0)
    assert frame.temps_c.shape == (192, 256)
    assert np.abs(frame.temps_c - scene).max() < 1 / 64 / 2 + 1e-3


@pytest.mark.parametrize(
    ("kind", "size", "picture", "expected"),
    [
        ("lepton", (160, 120), np.zeros((120, 160), np.uint8), "an 8-bit picture where 16-bit"),
        (
            "lepton",
            (160, 120),
            np.zeros((120, 160, 3), np.uint8),
            "a false-colour (3-channel 8-bit) picture where temperatures were expected",
        ),
        (
            "lepton",
            (160, 120),
            np.full((240, 320), 29315, np.uint16),
            "frames are 320x240, [thermal] is configured for 160x120",
        ),
        ("lepton", (160, 120), np.zeros((120, 160), np.float32), "float32 pixels where 16-bit"),
        (
            "infiray",
            (256, 192),
            np.zeros((192, 256, 2), np.uint8),
            "frames are 256x192, an InfiRay of [thermal] 256x192 sends 256x384",
        ),
        (
            "infiray",
            (256, 192),
            np.zeros((384, 256, 3), np.uint8),
            "a false-colour (3-channel 8-bit) picture",
        ),
        ("infiray", (256, 192), np.zeros((1, 1000), np.uint8), "frames are 1000 bytes"),
    ],
)
def test_a_device_that_does_not_send_temperatures_says_what_it_sends(
    devices: list[Any], kind: str, size: tuple[int, int], picture: np.ndarray, expected: str
) -> None:
    dev, source = _open(devices, kind, size)
    dev.frames.put(picture)
    with pytest.raises(CameraError) as info:
        source.read(2.0)
    assert expected in str(info.value) and "\n" not in str(info.value)
    assert str(info.value).startswith(f"{kind}:/dev/video3: ")


def test_convert_rgb_left_on_gives_false_colour(devices: list[Any]) -> None:
    # What a source that set CONVERT_RGB before the format would read.
    dev, source = _open(devices)
    dev.convert_rgb = True
    dev.frames.put(_centi_k(_scene_c()))
    with pytest.raises(CameraError, match=r"false-colour \(3-channel 8-bit\) picture"):
        source.read(2.0)


@pytest.mark.parametrize(
    ("device", "expected"),
    [
        (
            PseudoV4L2(opens=False),
            "lepton:/dev/video3: cannot open (no such device, or it is busy)",
        ),
        (PseudoV4L2(formats=("YUYV", "MJPG")), "lepton:/dev/video3: the device refuses the Y16"),
    ],
)
def test_a_device_that_cannot_be_a_lepton_is_refused(device: PseudoV4L2, expected: str) -> None:
    with pytest.raises(CameraError) as info:
        ThermalCaptureSource("/dev/video3", "lepton", 160, 120, 8.7, 1.0, lambda: device)
    assert str(info.value) == expected or str(info.value).startswith(expected)
    assert device.released


def test_a_device_that_claims_y16_and_sends_another_format() -> None:
    class Liar(PseudoV4L2):
        def get(self, prop: int, /) -> float:
            return FOURCC_YUYV

    with pytest.raises(CameraError, match=r"sends 'YUYV', not 'Y16 ': not a Lepton"):
        ThermalCaptureSource("/dev/video3", "lepton", 160, 120, 8.7, 1.0, Liar)


def test_flat_field_correction_is_skipped_and_said_once_per_episode(
    devices: list[Any], caplog: pytest.LogCaptureFixture
) -> None:
    dev, source = _open(devices)
    caplog.set_level(logging.WARNING, "companion.sources.thermal_raw")
    for episode in range(2):
        fresh = _centi_k(_scene_c())
        dev.frames.put(fresh)
        assert source.read(2.0).temps_c.shape == (120, 160)
        for _ in range(3):  # the shutter is closed: the same picture again
            dev.frames.put(fresh.copy())
            with pytest.raises(CameraTimeout):
                source.read(0.3)
            assert source.status == "frozen frames (flat-field correction): not evidence"
        said = [r for r in caplog.records if "flat-field" in r.getMessage()]
        assert len(said) == episode + 1
    dev.frames.put(_centi_k(_scene_c()))
    source.read(2.0)
    assert source.status == "ok" and source.frames_skipped == 6


def test_absurd_values_are_skipped_and_said(devices: list[Any]) -> None:
    dev, source = _open(devices)
    dev.frames.put(np.full((120, 160), 8000, np.uint16))  # raw counts: radiometry is off
    with pytest.raises(CameraTimeout):
        source.read(0.5)
    assert source.status.startswith(
        "absurd temperatures (-193.1 to -193.1 °C, outside -40 to 400): not radiometric"
    )


def test_unusable_frames_for_too_long_fail_the_camera() -> None:
    judge = ThermalJudge("lepton:/dev/video3", 1.0, give_up_after_s=3.0)
    frame = np.full((120, 160), 300.0, np.float32)
    assert judge.judge(frame, 0.0) is not None
    for t_s in (0.5, 1.5, 3.0):
        assert judge.judge(frame, t_s) is None
    with pytest.raises(CameraError) as info:
        judge.judge(frame, 4.0)
    assert str(info.value) == (
        "lepton:/dev/video3: frozen frames (flat-field correction): not evidence, for 3.5 s"
    )
    nan = frame.copy()
    nan[5, 5] = np.nan
    assert judge.judge(nan, 5.0) is None and judge.status.startswith("NaN or infinite")


def test_low_emissivity_that_makes_nonsense_is_said() -> None:
    judge = ThermalJudge("t", 0.11, None)
    scene = np.full((10, 10), 300.0, np.float32)
    scene[0, 0] = 240.0  # far colder than the room it reflects at emissivity 0.11
    assert judge.judge(scene, 0.0) is None
    assert judge.status.endswith("after the emissivity correction")


def test_find_purethermal_by_its_card_name(tmp_path: Path) -> None:
    for node, name, index in [
        ("video0", "UVC Camera (046d:0825)", "0"),
        ("video3", "PureThermal (fw:v1.3.0): PureTh", "1"),  # its metadata node
        ("video2", "PureThermal (fw:v1.3.0): PureTh", "0"),
        ("video9", "PureThermal (fw:v1.3.0): PureTh", "0"),  # a second board
    ]:
        (tmp_path / node).mkdir()
        (tmp_path / node / "name").write_text(name + "\n")
        (tmp_path / node / "index").write_text(index + "\n")
    assert find_purethermal(tmp_path) == "/dev/video2"
    with pytest.raises(CameraError, match="no PureThermal board found"):
        find_purethermal(tmp_path / "video0")


class UsbPort:
    """Where the pseudo-device is plugged: each open gets the next device."""

    def __init__(self) -> None:
        self.next = PseudoV4L2()
        self.opened: list[PseudoV4L2] = []

    def __call__(self) -> PseudoV4L2:
        device, self.next = self.next, PseudoV4L2()
        self.opened.append(device)
        return device


def test_open_thermal_reopens_and_its_status_names_both_sizes(tmp_path: Path) -> None:
    port = UsbPort()
    (tmp_path / "video5").mkdir()
    (tmp_path / "video5" / "name").write_text("PureThermal (fw:v1.3.0)\n")
    thermal = ThermalConfig(source="lepton", reopen_max_backoff_s=0.5)
    camera = open_thermal(thermal, port, tmp_path)
    try:
        assert camera.status == "not open yet"
        port.next.frames.put(_centi_k(_scene_c()))
        assert camera.read(2.0).temps_c.shape == (120, 160)
        assert camera.name == "lepton:/dev/video5" and camera.status == "ok" and camera.healthy
        first = port.opened[0]
        first.frames.put(np.full((240, 320), 29315, np.uint16))
        first.frames.put(None)
        with pytest.raises(CameraError) as info:
            camera.read(0.1)
        assert str(info.value).startswith(
            "camera down: lepton:/dev/video5: frames are 320x240, "
            "[thermal] is configured for 160x120 (next attempt in "
        )
        assert camera.status.startswith("down: lepton:/dev/video5: frames are 320x240")
        assert not camera.healthy
        port.next.frames.put(_centi_k(_scene_c()))  # reopened with backoff: frames again
        assert camera.read(3.0).temps_c.shape == (120, 160)
        assert camera.status == "ok" and len(port.opened) == 2
    finally:
        for device in port.opened:
            device.unplugged = True
        camera.close()


# -- the recorded frames folder ------------------------------------------------------------


def _frame(t_unix_s: float, temps_c: np.ndarray, index: int = 0) -> ThermalFrame:
    return ThermalFrame(temps_c.astype(np.float32), 0.0, t_unix_s, index)


def test_written_frames_read_back(tmp_path: Path) -> None:
    scenes = [_scene_c() for _ in range(3)]
    scenes[1][0, 0] = 395.0  # above what 16 bits of centi-kelvin hold: written as 382.2 °C
    times = [1_700_000_000.125, 1_700_000_000.240, 1_700_000_000.355]
    for t_s, scene in reversed(list(zip(times, scenes, strict=True))):
        path = write_thermal_frame(tmp_path, _frame(t_s, scene))
        assert path.name == f"{round(t_s * 1e6)}.png"
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert raw.dtype == np.uint16 and raw.ndim == 2  # one channel, centi-kelvin
    (tmp_path / "notes.txt").write_text("not a frame")
    folder = ThermalFramesDir(tmp_path, 160, 120)
    assert len(folder) == 3
    for i, (t_s, scene) in enumerate(zip(times, scenes, strict=True)):
        frame = folder.read(1.0)
        assert frame.index == i and frame.t_unix_s == pytest.approx(t_s, abs=1e-6)
        assert frame.t_mono_s == pytest.approx(t_s + folder.mono_minus_unix_s)
        expected = np.minimum(scene, 382.2)
        assert np.abs(frame.temps_c - expected).max() < 0.006
    with pytest.raises(EndOfStream, match="end after 3 frames"):
        folder.read(1.0)


def _png(path: Path, image: np.ndarray) -> None:
    assert cv2.imwrite(str(path), image)


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("8bit", "is an 8-bit picture where 16-bit temperatures were expected"),
        ("colour", "is a false-colour (3-channel 8-bit) picture where temperatures were expected"),
        ("colour16", "is a false-colour (3-channel 16-bit) picture where temperatures were"),
        ("truncated", "is a truncated PNG (no IEND chunk)"),
        ("garbage", "is not a readable image"),
    ],
)
def test_a_file_that_is_not_temperatures_is_skipped_and_named(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, content: str, expected: str
) -> None:
    good = _centi_k(_scene_c())
    _png(tmp_path / "1000000.png", good)
    bad = tmp_path / "2000000.png"
    if content == "8bit":
        _png(bad, (good // 256).astype(np.uint8))
    elif content == "colour":
        _png(bad, cv2.applyColorMap((good // 256).astype(np.uint8), cv2.COLORMAP_JET))
    elif content == "colour16":
        _png(bad, np.dstack([good, good, good]))
    elif content == "truncated":
        _png(bad, good)
        bad.write_bytes(bad.read_bytes()[:-40])
    else:
        bad.write_bytes(b"\x00garbage" * 10)
    _png(tmp_path / "3000000.png", _centi_k(_scene_c()))
    caplog.set_level(logging.WARNING)
    folder = ThermalFramesDir(tmp_path, 160, 120)
    assert [folder.read(1.0).index for _ in range(2)] == [0, 2]
    assert folder.frames_skipped == 1
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and said[0].startswith(f"frames:{tmp_path}: 2000000.png {expected}")
    assert said[0].endswith("; skipped")


def test_a_folder_of_frozen_and_absurd_frames(tmp_path: Path) -> None:
    frozen = _centi_k(_scene_c())
    for t_us, words in [
        (1, frozen),
        (2, frozen),
        (3, frozen),
        (4, np.zeros((120, 160), np.uint16)),  # -273.15 °C
        (5, _centi_k(_scene_c())),
    ]:
        _png(tmp_path / f"{t_us}.png", words)
    folder = ThermalFramesDir(tmp_path, 160, 120)
    assert folder.read(1.0).index == 0
    assert folder.read(1.0).index == 4
    assert folder.frames_skipped == 3 and folder.status == "ok"


def test_a_folder_of_another_size_stops_naming_both(tmp_path: Path) -> None:
    _png(tmp_path / "1.png", np.full((192, 256), 29315, np.uint16))
    folder = ThermalFramesDir(tmp_path, 160, 120)
    with pytest.raises(CameraError) as info:
        folder.read(1.0)
    assert str(info.value) == (
        f"frames:{tmp_path}: 1.png is 256x192, [thermal] is configured for 160x120"
    )


def test_no_folder_no_frames_and_nan_are_refused(tmp_path: Path) -> None:
    with pytest.raises(CameraError, match="no such folder"):
        ThermalFramesDir(tmp_path / "none", 160, 120)
    (tmp_path / "a.png").write_bytes(b"")
    with pytest.raises(CameraError, match=r"holds no thermal frames named <unix_time_us>\.png"):
        ThermalFramesDir(tmp_path, 160, 120)
    nan = _scene_c()
    nan[3, 3] = np.nan
    with pytest.raises(CameraError, match="NaN or infinite temperatures"):
        write_thermal_frame(tmp_path, _frame(1.0, nan))
    with pytest.raises(CameraError, match="cannot write"):
        write_thermal_frame(tmp_path / "none", _frame(1.0, _scene_c()))


# -- fuzz: anything a device or a file can hold --------------------------------------------

SHAPES = [
    (120, 160),
    (122, 160),
    (120, 160, 1),
    (120, 160, 3),
    (384, 256, 2),
    (384, 256),
    (1, 196608),
    (2, 2),
    (0, 160),
    (7,),
    (192, 256, 4),
]


def _picture(dtype: Any, shape: tuple[int, ...], seed: int, style: str) -> np.ndarray:
    """A random picture drawn by numpy from a small seed (hypothesis varies the seed,
    the kind and the shape; the pixels would make too large an example one by one)."""
    rng = np.random.default_rng(seed)
    if style == "noise":
        values = rng.uniform(-1e5, 1e5, shape)
        values[rng.random(shape) < 0.01] = np.nan
    elif style == "room":  # centi-kelvin, or kelvin x 64, of a plausible scene
        scale = rng.choice([100.0, 64.0])
        values = (293.15 + rng.normal(0.0, 5.0, shape)) * scale
    else:  # one value everywhere: frozen, or a dead sensor
        values = np.full(shape, float(seed % 65536))
    if np.dtype(dtype).kind in "ui":
        info = np.iinfo(dtype)
        values = np.clip(np.nan_to_num(values), info.min, info.max)
    return values.astype(dtype)


pictures = st.builds(
    _picture,
    st.sampled_from([np.uint8, np.uint16, np.int16, np.float32, np.float64, np.bool_]),
    st.sampled_from(SHAPES),
    st.integers(0, 2**32 - 1),
    st.sampled_from(["noise", "room", "constant"]),
)


@pytest.fixture(scope="module")
def fuzz_cameras() -> Iterator[dict[str, tuple[PseudoV4L2, ThermalCaptureSource]]]:
    cams = {}
    for kind, size in (("lepton", (160, 120)), ("infiray", (256, 192))):
        dev = PseudoV4L2()
        cams[kind] = (
            dev,
            ThermalCaptureSource("/dev/video3", kind, *size, 8.7, 0.98, lambda d=dev: d),
        )
    yield cams
    for dev, source in cams.values():
        dev.unplugged = True
        source.close()


@fuzz_settings(150)
@given(kind=st.sampled_from(["lepton", "infiray"]), picture=pictures)
def test_any_picture_from_a_device_is_a_frame_or_one_line(
    fuzz_cameras: dict[str, tuple[PseudoV4L2, ThermalCaptureSource]], kind: str, picture: Any
) -> None:
    dev, source = fuzz_cameras[kind]
    dev.frames.put(picture)
    try:
        frame = source.read(2.0)
    except CameraTimeout:
        assert source.status != "ok"  # skipped, and said
    except CameraError as exc:
        assert str(exc).startswith(f"{kind}:/dev/video3: ") and "\n" not in str(exc)
    else:
        assert np.isfinite(frame.temps_c).all()
        assert float(frame.temps_c.min()) >= -40.0 and float(frame.temps_c.max()) <= 400.0


def _mutated_png(image: np.ndarray, cut: int, flips: list[tuple[int, int]]) -> bytes:
    ok, buf = cv2.imencode(".png", image)
    assert ok
    data = bytearray(buf.tobytes())
    for at, value in flips:
        data[at % len(data)] = value
    return bytes(data[: len(data) - cut] if cut < len(data) else data)


files = st.one_of(
    st.binary(max_size=300),
    st.builds(
        _mutated_png,
        st.sampled_from(
            [
                np.full((120, 160), 29815, np.uint16),
                np.zeros((120, 160), np.uint16),
                np.full((120, 160), 90, np.uint8),
                np.full((120, 160, 3), 30000, np.uint16),
                np.full((12, 16), 29815, np.uint16),
            ]
        ),
        st.integers(0, 64),
        st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=3),
    ),
)


@fuzz_settings(150)
@given(contents=st.lists(files, min_size=1, max_size=4))
def test_any_bytes_in_a_frames_folder_are_frames_or_one_line(
    tmp_path_factory: pytest.TempPathFactory, contents: list[bytes]
) -> None:
    folder = tmp_path_factory.mktemp("thermal")
    for i, data in enumerate(contents):
        (folder / f"{1_000_000 + i}.png").write_bytes(data)
    source = ThermalFramesDir(folder, 160, 120)
    read = 0
    try:
        while True:
            frame = source.read(1.0)
            assert np.isfinite(frame.temps_c).all()
            read += 1
    except EndOfStream:
        assert read + source.frames_skipped == len(contents)
    except CameraError as exc:
        assert "is 16x12, [thermal] is configured for 160x120" in str(exc)


def test_a_real_lepton_sized_scene_through_the_camera_and_the_folder(
    shared_data: Path, tmp_path: Path, devices: list[Any]
) -> None:
    """Two people in a street at night, a FLIR photo whose raw image is 160x120 (a
    Lepton's size): as the Lepton would send it (Y16 centi-kelvin with telemetry rows),
    then recorded and replayed, it comes back to the centi-kelvin."""
    import shutil

    from companion.sources.flir import read_flir

    if shutil.which("exiftool") is None:
        pytest.skip("exiftool (libimage-exiftool-perl) is not installed")
    photo = shared_data / "images" / "people_thermal" / "wm_thermographie_de_rue_night.jpg"
    scene = read_flir(photo).temps_c
    assert scene.shape == (120, 160)
    dev, source = _open(devices)
    dev.frames.put(np.concatenate([_centi_k(scene), np.zeros((2, 160), np.uint16)]))
    live = source.read(2.0)
    assert np.abs(live.temps_c - scene).max() < 0.006
    write_thermal_frame(tmp_path, live)
    replayed = ThermalFramesDir(tmp_path, 160, 120).read(1.0)
    assert np.abs(replayed.temps_c - scene).max() < 0.011
    assert replayed.t_unix_s == pytest.approx(live.t_unix_s, abs=1e-6)


# -- the simulator's thermal camera: sim:HOST:PORT -----------------------------------------


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("sim:127.0.0.1:5601", ThermalSpec("sim", "127.0.0.1", 5601)),
        (" sim:rover.local:7000 ", ThermalSpec("sim", "rover.local", 7000)),
        ("sim:127.0.0.1", "source 'sim:127.0.0.1': expected sim:HOST:PORT (port 1..65535)"),
        ("sim::5601", "source 'sim::5601': expected sim:HOST:PORT (port 1..65535)"),
        ("sim:h:70000", "source 'sim:h:70000': expected sim:HOST:PORT (port 1..65535)"),
    ],
)
def test_the_sim_source_string(text: str, expected: ThermalSpec | str) -> None:
    if isinstance(expected, ThermalSpec):
        assert parse_thermal_source(text) == expected
        return
    with pytest.raises(CameraError) as info:
        parse_thermal_source(text)
    assert str(info.value) == expected


class FrameFeed:
    """A TCP server on 127.0.0.1 that sends what a test gives it, framed as the
    simulator's camera servers frame their pictures (``encode_sim_frame``)."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(5.0)
        self.port = self.listener.getsockname()[1]
        self.source = f"sim:127.0.0.1:{self.port}"
        self.clients: list[socket.socket] = []

    def accept(self) -> socket.socket:
        conn, _ = self.listener.accept()
        self.clients.append(conn)
        return conn

    def close(self) -> None:
        for conn in self.clients:
            conn.close()
        self.listener.close()


@pytest.fixture
def feed() -> Iterator[FrameFeed]:
    server = FrameFeed()
    yield server
    server.close()


def _packet(words: np.ndarray, t_unix_s: float | None = None) -> bytes:
    ok, png = cv2.imencode(".png", words)
    assert ok
    return encode_sim_frame(png.tobytes(), time.time() if t_unix_s is None else t_unix_s)


def _down(camera: ReopeningThermalSource, within_s: float) -> str:
    """What the camera says when it goes down (read in short steps: a longer read would
    already be waiting on the reopened one)."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            camera.read(0.05)
        except CameraTimeout:
            continue
        except CameraError as exc:
            return str(exc)
    raise AssertionError(f"still up after {within_s} s: {camera.status}")


def test_sim_frames_are_temperatures_on_both_clocks(feed: FrameFeed) -> None:
    source = ThermalSimSource("127.0.0.1", feed.port, 160, 120, 1.0)
    try:
        conn = feed.accept()
        scene = _scene_c()
        stamp = time.time() - 0.25
        conn.sendall(_packet(_centi_k(scene), stamp))
        frame = source.read(2.0)
        assert np.abs(frame.temps_c - scene).max() < 0.006
        assert frame.t_unix_s == pytest.approx(stamp, abs=1e-6)
        assert frame.t_mono_s == pytest.approx(time.monotonic() - 0.25, abs=0.1)
        # Bytes that are no PNG are skipped and counted; the stream stays in step.
        conn.sendall(encode_sim_frame(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40, time.time()))
        with pytest.raises(CameraTimeout):
            source.read(0.5)
        assert source.frames_corrupt == 1
        conn.sendall(_packet(_centi_k(_scene_c())))
        assert source.read(2.0).temps_c.shape == (120, 160)
        assert source.status == "ok"
        # Raw counts (radiometry off) are absurd temperatures: skipped and said.
        conn.sendall(_packet(np.full((120, 160), 8000, np.uint16)))
        with pytest.raises(CameraTimeout):
            source.read(0.5)
        assert source.status.startswith("absurd temperatures (-193.1 to -193.1 °C")
        assert source.frames_skipped == 1
    finally:
        source.close()


@pytest.mark.parametrize(
    ("words", "why"),
    [
        (np.full((120, 160), 200, np.uint8), "an 8-bit picture where 16-bit temperatures"),
        (np.zeros((120, 160, 3), np.uint8), "a false-colour (3-channel 8-bit) picture where"),
        (np.full((240, 320), 29315, np.uint16), "frames are 320x240, [thermal] is configured"),
    ],
)
def test_sim_frames_that_are_not_temperatures_fail_the_camera_until_they_are(
    feed: FrameFeed, words: np.ndarray, why: str
) -> None:
    camera = open_thermal(ThermalConfig(source=feed.source, reopen_max_backoff_s=0.5))
    try:
        with pytest.raises(CameraTimeout):  # the first read connects
            camera.read(0.2)
        conn = feed.accept()
        conn.sendall(_packet(words))
        assert _down(camera, 2.0).startswith(f"camera down: {feed.source}: {why}")
        assert camera.status.startswith(f"down: {feed.source}: {why}") and not camera.healthy
        with pytest.raises(CameraTimeout):  # reconnects with backoff
            camera.read(1.0)
        again = feed.accept()  # temperatures again
        again.sendall(_packet(_centi_k(_scene_c())))
        assert camera.read(3.0).temps_c.shape == (120, 160)
        assert camera.status == "ok" and camera.healthy
    finally:
        camera.close()


def test_a_sim_camera_that_is_not_there_is_said_and_tried_again() -> None:
    with socket.create_server(("127.0.0.1", 0)) as s:
        port = s.getsockname()[1]  # closed again: nothing listens there
    camera = open_thermal(ThermalConfig(source=f"sim:127.0.0.1:{port}", reopen_max_backoff_s=0.5))
    try:
        with pytest.raises(CameraError) as info:
            camera.read(0.1)
        assert str(info.value).startswith(
            f"camera down: sim:127.0.0.1:{port}: cannot connect: Connection refused"
        )
        with socket.create_server(("127.0.0.1", port)) as late:  # the simulator starts
            late.settimeout(5.0)
            with pytest.raises(CameraTimeout):
                camera.read(1.0)
            conn, _ = late.accept()
            with conn:
                conn.sendall(_packet(_centi_k(_scene_c())))
                assert camera.read(2.0).temps_c.shape == (120, 160)
    finally:
        camera.close()


def test_the_simulators_thermal_camera_end_to_end() -> None:
    """The simulator's thermal camera server renders from the rover's true pose at each
    frame's capture time; the companion's sim source reads back exactly the renderer's
    temperatures; flat-field frames (the last one again) are skipped as a Lepton's."""
    from scenarios.camserver import ThermalCameraServer
    from scenarios.motion import Trajectory
    from scenarios.thermal import ThermalOptions, ThermalRenderer
    from scenarios.world import preset

    world = preset("thermal_covered")
    victim = world.victims[0]
    trajectory = Trajectory((victim.north_m - 2.5, victim.east_m), 0.0, ((9.0, victim.east_m),))
    options = ThermalOptions(noise_k=0.0, ffc_period_s=1.0, ffc_duration_s=0.4)
    t0_unix_s = float(int(time.time()))
    t0_mono_s = time.monotonic()

    def pose_now() -> tuple[Any, float]:
        # Whole milliseconds: the frame's capture time (whole µs) gives back this t_s.
        t_s = round(time.monotonic() - t0_mono_s, 3)
        return trajectory.pose_at(t_s), t0_unix_s + t_s

    server = ThermalCameraServer(ThermalRenderer(world, options=options), pose_now).start()
    camera = open_thermal(
        ThermalConfig(source=f"sim:127.0.0.1:{server.address[1]}", emissivity=1.0)
    )
    reference = ThermalRenderer(world, options=dataclasses.replace(options, ffc=False))
    try:
        frames = []
        deadline = time.monotonic() + 20.0
        while len(frames) < 8 and time.monotonic() < deadline:
            with contextlib.suppress(CameraTimeout):
                frames.append(camera.read(1.0))
        assert len(frames) == 8, camera.status
        for frame in frames:
            t_s = round(frame.t_unix_s - t0_unix_s, 3)
            expected = reference.render(trajectory.pose_at(t_s), t_s).temps_c
            assert np.abs(frame.temps_c - expected).max() < 0.006
        assert frames[-1].temps_c.max() > world.floor.temperature_c + 5.0  # the warm blanket
        assert server.frames_frozen > 0  # the shutter closed: those frames were not read
        assert len({f.index for f in frames}) == 8 and camera.healthy
        assert camera.read(3.0).temps_c.shape == (120, 160)
    finally:
        camera.close()
        server.close()
