"""Configuration: typed loading, clear one-line errors, exit status 2, docs in step."""

from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
import typing
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.calibration import camera_model, read_calibration
from companion.config import Config
from companion.config_load import ConfigError, config_from_dict, load_config

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "systemd" / "config.example.toml"
CLI = [sys.executable, "-m", "companion.commands.cli"]


def _all_keys(cls: type, prefix: str) -> set[str]:
    keys: set[str] = set()
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        optional = [a for a in typing.get_args(tp) if a is not type(None)]  # [thermal]: X | None
        if len(optional) == 1 and dataclasses.is_dataclass(optional[0]):
            tp = optional[0]
        if dataclasses.is_dataclass(tp):
            keys |= _all_keys(tp, f"{prefix}.{f.name}" if prefix else f.name)  # type: ignore[arg-type]
        else:
            keys.add(f"{prefix}.{f.name}")
    return keys


def test_defaults_need_no_file() -> None:
    config = config_from_dict({})
    assert config == Config()
    assert config.vehicle.component_id == 191


def test_example_config_loads_and_sets_every_section(tmp_path: Path) -> None:
    config = load_config(EXAMPLE)
    assert config.vehicle.url == "serial:/dev/ttyAMA0:921600"
    assert config.camera.mount.pitch_deg == -12.0


def test_docs_and_example_cover_every_key() -> None:
    doc = (ROOT / "docs" / "CONFIG.md").read_text()
    example = EXAMPLE.read_text()
    for key in sorted(_all_keys(Config, "")):
        section, _, name = key.rpartition(".")
        assert f"## [{section}]" in doc, f"docs/CONFIG.md has no section [{section}]"
        body = doc.split(f"## [{section}]", 1)[1].split("\n## ", 1)[0]
        assert f"| `{name}` |" in body, f"docs/CONFIG.md does not document {key}"
        ex_body = example.split(f"[{section}]", 1)[1]
        assert re.search(rf"^#?\s*{name}\s*=", ex_body, re.M), f"example lacks {key}"


def test_relative_paths_are_relative_to_the_config_file(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[paths]\nstate_dir = "state"\n')
    assert load_config(cfg).paths.state_dir == tmp_path / "state"


@pytest.mark.parametrize(
    ("toml", "expected"),
    [
        ('[camera]\nwidth_px = "wide"\n', "camera.width_px = 'wide': expected an integer"),
        ("[tracker]\ngate_chii2 = 3.0\n", "[tracker] has unknown key 'gate_chii2'"),
        ("[cammera]\n", "unknown section [cammera]"),
        ("[geolocation]\nmax_range_m = -1.0\n", "[geolocation] max_range_m = -1.0"),
        ('[vehicle]\nurl = "udp:1.2.3.4"\n', "[vehicle] link 'udp:1.2.3.4'"),
        ('[detector]\nbackend = "yolo"\n', "detector.backend = 'yolo': expected one of"),
        ("[detector]\nmodel_threads = 0\n", "[detector] model_threads = 0: must be 1..16"),
        ("[signing]\nenabled = true\n", "key_file: required when enabled = true"),
        ("[hq]\ntunnel = 1\n", "hq.tunnel = 1: expected true or false"),
        ("[camera]\nwidth_px = 640\nwidth_px = 320\n", "not valid TOML"),
        ("[camera.mount]\npitch_deg = nan\n", "camera.mount.pitch_deg = nan: must be a finite"),
        ("[camera]\nfx_px = inf\nfy_px = 500.0\n", "camera.fx_px = inf: must be a finite"),
        ("[tracker]\ngate_chi2 = -inf\n", "tracker.gate_chi2 = -inf: must be a finite"),
        ("[vehicle]\nattitude_rate_hz = 100000\n", "attitude_rate_hz = 100000.0: must be in"),
        ("[vehicle]\nglobal_position_rate_hz = 0\n", "global_position_rate_hz = 0.0: must"),
        ("[reporting]\ndialect_report = true\n", "unknown key 'dialect_report'"),
        ("[pictures]\nmax_bytes = 100\n", "[pictures] max_bytes = 100: must be 500..22016"),
        ("[pictures]\nmax_bytes = 30000\n", "max_bytes = 30000: must be 500..22016"),
        ("[pictures]\nwidth_px = 8\n", "[pictures] width_px = 8: must be 32..1280"),
        ("[pictures]\nrate_bytes_s = nan\n", "pictures.rate_bytes_s = nan: must be a finite"),
        ("[pictures]\nrate_bytes_s = 50.0\n", "rate_bytes_s = 50.0: must be 100..100000"),
        ("[pictures]\nmin_gain = -0.5\n", "min_gain = -0.5: must be 0..10"),
        ("[pictures]\nmin_interval_s = 4000.0\n", "min_interval_s = 4000.0: must be 0..3600"),
        ("[pictures]\nenabled = 1\n", "pictures.enabled = 1: expected true or false"),
    ],
)
def test_bad_values_name_key_and_value(tmp_path: Path, toml: str, expected: str) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    with pytest.raises(ConfigError) as info:
        load_config(cfg)
    assert expected in str(info.value)
    assert "\n" not in str(info.value)


def _run_check(path: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLI, "check-config", "--config", str(path), *extra],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


@pytest.mark.parametrize(
    ("name", "toml", "expected"),
    [
        ("wrong_type", "[camera]\nfps = 'fast'\n", "camera.fps = 'fast'"),
        ("unknown_key", "[reporting]\nstatus_text = true\n", "unknown key 'status_text'"),
        ("missing_file", None, "config file not found"),
        (
            "bad_calibration",
            '[camera]\ncalibration_file = "cal.yaml"\n',
            "not a readable YAML/XML calibration",
        ),
        ("missing_calibration", '[camera]\ncalibration_file = "nope.yaml"\n', "cannot read"),
        ("infinite_fx", "[camera]\nfx_px = inf\nfy_px = inf\n", "camera.fx_px = inf"),
    ],
)
def test_console_script_exits_2_with_one_line(
    tmp_path: Path, name: str, toml: str | None, expected: str
) -> None:
    cfg = tmp_path / f"{name}.toml"
    if toml is not None:
        cfg.write_text(toml)
    (tmp_path / "cal.yaml").write_text("camera_matrix: [unclosed\n  : :\n")
    result = _run_check(cfg)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert expected in lines[0]
    assert "Traceback" not in result.stderr


def test_console_script_accepts_the_example() -> None:
    # The example is for the Pi: its serial port and camera are not on this machine.
    result = _run_check(EXAMPLE, "--no-devices")
    assert result.returncode == 0, result.stderr
    assert "config ok" in result.stdout


def test_ros_camera_info_calibration(shared_data: Path) -> None:
    intr = read_calibration(shared_data / "calibration" / "raspicam_v2_camerav2_1280x960.yaml")
    assert (intr.width_px, intr.height_px) == (1280, 960)
    assert intr.fx_px == pytest.approx(999.461170663331)
    assert intr.cy_px == pytest.approx(474.1471906434548)
    assert intr.distortion[0] == pytest.approx(0.1644274736100891)


def test_calibration_is_scaled_to_the_frame_size(shared_data: Path) -> None:
    cal = shared_data / "calibration" / "raspicam_v2_camerav2_1280x960.yaml"
    config = config_from_dict({"camera": {"calibration_file": str(cal)}})
    intr = camera_model(config.camera).intrinsics
    assert (intr.width_px, intr.height_px) == (640, 480)
    assert intr.fx_px == pytest.approx(999.461170663331 / 2)


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_opencv_filestorage_calibration(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"cal{suffix}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", np.array([[500.0, 0, 321.5], [0, 501.0, 239.5], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, -0.2, 0.001, 0.002, 0.03]]))
    fs.release()
    intr = read_calibration(path)
    assert (intr.fx_px, intr.fy_px, intr.cx_px, intr.cy_px) == (500.0, 501.0, 321.5, 239.5)
    assert intr.distortion == pytest.approx((0.1, -0.2, 0.001, 0.002, 0.03))


def test_calibration_of_another_aspect_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "wide.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1920)
    fs.write("image_height", 1080)
    fs.write("camera_matrix", np.array([[1000.0, 0, 960], [0, 1000, 540], [0, 0, 1]]))
    fs.release()
    config = config_from_dict({"camera": {"calibration_file": str(path)}})
    with pytest.raises(ConfigError, match="aspect"):
        camera_model(config.camera)
