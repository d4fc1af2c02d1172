"""The [thermal] config section: absent means no thermal camera; present, it is
validated once (one line naming the key), its detector settings and mount are typed,
the thermal camera model is built as the colour one is, and check-config says which
cameras the rover has."""

from __future__ import annotations

import copy
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from companion.calibration import camera_model
from companion.config import ThermalConfig
from companion.config_load import ConfigError, config_from_dict, load_config
from companion.vision.thermal_params import ThermalDetectorParams
from tests.jsonfuzz import fuzz_settings, json_values

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "companion.commands.cli"]


def _load(tmp_path: Path, toml: str) -> Any:
    cfg = tmp_path / "c.toml"
    cfg.write_text(toml)
    return load_config(cfg)


def test_no_section_no_thermal_camera(tmp_path: Path) -> None:
    assert _load(tmp_path, "[camera]\nsource = 'sim'\n").thermal is None


def test_an_empty_section_is_a_lepton_with_its_geometry(tmp_path: Path) -> None:
    thermal = _load(tmp_path, "[thermal]\n").thermal
    assert thermal == ThermalConfig()
    assert (thermal.source, thermal.width_px, thermal.height_px) == ("lepton", 160, 120)
    assert thermal.emissivity == 0.98
    model = camera_model(thermal)
    k = model.intrinsics
    assert (k.width_px, k.height_px) == (160, 120)
    hfov_deg = math.degrees(2 * math.atan(k.width_px / 2 / k.fx_px))
    assert hfov_deg == pytest.approx(57.0)
    # The figure: one Lepton pixel is about 2 cm at 3 m.
    assert 3.0 / k.fx_px == pytest.approx(0.02, abs=0.001)


def test_mount_detector_and_intrinsics_are_read(tmp_path: Path) -> None:
    thermal = _load(
        tmp_path,
        """
[thermal]
source = "infiray:/dev/video4"
width_px = 256
height_px = 192
fx_px = 250.0
fy_px = 251.0
emissivity = 0.95
[thermal.mount]
y_m = 0.05
pitch_deg = -20.0
[thermal.detector]
min_contrast_k = 4.5
""",
    ).thermal
    assert thermal.detector == ThermalDetectorParams(min_contrast_k=4.5)
    model = camera_model(thermal)
    assert (model.intrinsics.fx_px, model.intrinsics.fy_px) == (250.0, 251.0)
    assert (model.intrinsics.cx_px, model.intrinsics.cy_px) == (127.5, 95.5)
    assert model.mount.y_m == 0.05
    assert model.mount.pitch_rad == pytest.approx(math.radians(-20.0))


def test_a_thermal_calibration_file_is_read_and_scaled(tmp_path: Path) -> None:
    (tmp_path / "lepton.yaml").write_text(
        "image_width: 320\nimage_height: 240\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [300, 0, 160, 0, 300, 120, 0, 0, 1]\n"
    )
    thermal = _load(tmp_path, '[thermal]\ncalibration_file = "lepton.yaml"\n').thermal
    k = camera_model(thermal).intrinsics
    assert (k.width_px, k.fx_px) == (160, pytest.approx(150.0))


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ('[thermal]\nsource = "flir"\n', "[thermal] source 'flir': not understood; use lepton"),
        ('[thermal]\nsource = "lepton:video0"\n', "expected lepton:/dev/videoN"),
        ('[thermal]\nsource = "infiray:"\n', "expected infiray:/dev/videoN"),
        ('[thermal]\nsource = ""\n', "[thermal] source: must not be empty"),
        ("[thermal]\nemissivity = 0.05\n", "[thermal] emissivity = 0.05: must be in (0.1, 1]"),
        ("[thermal]\nemissivity = 1.5\n", "[thermal] emissivity = 1.5: must be in (0.1, 1]"),
        ("[thermal]\nemissivity = nan\n", "thermal.emissivity = nan: must be a finite"),
        ("[thermal]\nwidth_px = 0\n", "[thermal] width_px x height_px = 0x120: must be positive"),
        ("[thermal]\nhfov_deg = 200.0\n", "[thermal] hfov_deg = 200.0: must be in [1, 179)"),
        ("[thermal]\nfx_px = 100.0\n", "[thermal] fx_px, fy_px: give both"),
        ("[thermal]\nstall_timeout_s = -1.0\n", "[thermal] stall_timeout_s = -1.0: must be >= 0"),
        ("[thermal]\nemisivity = 0.9\n", "[thermal] has unknown key 'emisivity'"),
        ("[thermal.mount]\npitch_deg = 'down'\n", "thermal.mount.pitch_deg = 'down': expected a"),
        ("[thermal.detector]\nmin_contrast_k = -1.0\n", "[thermal.detector] min_contrast_k = -1.0"),
        ("[thermal.detector]\nmax_skin_c = 90.0\n", "[thermal.detector] min_body_c = 22.0"),
        ("[thermal.detector]\nwarmth = 1\n", "[thermal.detector] has unknown key 'warmth'"),
        ("thermal = 3\n", "thermal = 3: expected a table [thermal]"),
        ('[thermal]\ncalibration_file = "none.yaml"\n', "thermal.calibration_file '"),
    ],
)
def test_bad_values_name_the_key(tmp_path: Path, toml: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        _load(tmp_path, toml)
    assert expected in str(info.value)
    assert "\n" not in str(info.value)


BASE: dict[str, Any] = {
    "thermal": {
        "source": "frames:/nonexistent",
        "width_px": 160,
        "height_px": 120,
        "fps": 8.7,
        "hfov_deg": 57.0,
        "fx_px": 0.0,
        "fy_px": 0.0,
        "distortion": [0.0, 0.0, 0.0, 0.0, 0.0],
        "emissivity": 0.98,
        "reopen_max_backoff_s": 5.0,
        "stall_timeout_s": 5.0,
        "mount": {"x_m": 0.1, "pitch_deg": -12.0},
        "detector": {"min_contrast_k": 3.0, "max_skin_c": 40.0, "min_area_m2": 0.004},
    }
}
PLACES = [("thermal", k) for k in BASE["thermal"]] + [
    ("thermal", sub, k) for sub in ("mount", "detector") for k in BASE["thermal"][sub]
]
edge_values = json_values.filter(lambda v: v is not None) | st.sampled_from(
    [0, -1, 2**63 - 1, 1e308, -1e-308, float("nan"), float("inf"), "", "lepton:", "a\nb", 0.1]
)


@fuzz_settings(300)
@given(edits=st.lists(st.tuples(st.sampled_from(PLACES), edge_values), min_size=1, max_size=4))
def test_any_value_in_the_section_is_a_config_or_one_line(
    edits: list[tuple[tuple[str, ...], Any]],
) -> None:
    data = copy.deepcopy(BASE)
    for place, value in edits:
        parent = data
        for key in place[:-1]:
            parent = parent[key] if isinstance(parent, dict) else None
        if isinstance(parent, dict):
            parent[place[-1]] = value
    try:
        config = config_from_dict(data, Path("/nonexistent-base"))
        assert config.thermal is not None
        camera_model(config.thermal)  # as load_config does
    except ConfigError as exc:
        assert str(exc) and "\n" not in str(exc)


def _check(tmp_path: Path, toml: str, *extra: str) -> subprocess.CompletedProcess[str]:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[camera]\nsource = "sim"\n' + toml)
    return subprocess.run(
        [*CLI, "check-config", "--config", str(cfg), *extra],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def test_check_config_says_colour_camera_only(tmp_path: Path) -> None:
    result = _check(tmp_path, "")
    assert result.returncode == 0, result.stderr
    assert "colour camera only" in result.stdout


def test_check_config_names_the_thermal_camera(tmp_path: Path) -> None:
    (tmp_path / "thermal").mkdir()  # a source's folder is as given (not config-relative)
    result = _check(tmp_path, f'[thermal]\nsource = "frames:{tmp_path}/thermal"\n')
    assert result.returncode == 0, result.stderr
    assert "/thermal 160x120 fx=147.3px emissivity 0.98" in result.stdout


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("frames:nowhere", "thermal.source = 'frames:nowhere': no such thermal frames folder"),
        ("lepton:/dev/video97", "no such thermal camera device /dev/video97"),
        ("flir", "[thermal] source 'flir': not understood"),
    ],
)
def test_check_config_refuses_a_missing_thermal_camera(
    tmp_path: Path, source: str, expected: str
) -> None:
    result = _check(tmp_path, f'[thermal]\nsource = "{source}"\n')
    assert result.returncode == 2, result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and expected in lines[0], result.stderr


def test_check_config_looks_for_a_purethermal_board(tmp_path: Path) -> None:
    boards = [
        p for p in Path("/sys/class/video4linux").glob("video*/name") if "PureTh" in p.read_text()
    ]
    if boards:
        pytest.skip(f"a PureThermal board is plugged in here: {boards[0]}")
    result = _check(tmp_path, '[thermal]\nsource = "lepton"\n')
    assert result.returncode == 2
    assert "thermal.source = 'lepton': lepton: no PureThermal board found" in result.stderr
    assert _check(tmp_path, '[thermal]\nsource = "lepton"\n', "--no-devices").returncode == 0


def test_check_config_accepts_the_simulators_thermal_camera(tmp_path: Path) -> None:
    # A network camera: the service waits for it; there is no device to look for.
    result = _check(tmp_path, '[thermal]\nsource = "sim:127.0.0.1:5601"\n')
    assert result.returncode == 0, result.stderr
