"""Fuzz camera calibration files (`camera.calibration_file`, ROS camera_info or OpenCV
YAML): numbers replaced by anything, lines dropped, bytes cut or changed give a
camera model or one ConfigError line naming the file, never another exception."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from companion.calibration import camera_model
from companion.config_load import ConfigError, config_from_dict
from tests.jsonfuzz import fuzz_settings

# The layout of ../shared/data/calibration's Raspberry Pi camera files (ROS camera_info).
ROS = """image_width: 640
image_height: 480
camera_name: test
camera_matrix:
  rows: 3
  cols: 3
  data: [502.1, 0, 319.2, 0, 500.8, 241.3, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [0.16, -0.27, 0.001, -0.0016, 0]
"""
# OpenCV's own FileStorage layout, as calibrateCamera tools write it.
OPENCV = """%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 502.1, 0., 319.2, 0., 500.8, 241.3, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ 0.16, -0.27, 0.001, -0.0016, 0. ]
"""
NUMBER = re.compile(r"-?\d+\.?\d*(?:e-?\d+)?")
ODD = ["nan", ".nan", "inf", "-.inf", "1e308", "-1e308", "0", "-1", "1e-320", "x", "", "[", "]"]


@st.composite
def damaged(draw: st.DrawFn) -> bytes:
    text = draw(st.sampled_from([ROS, OPENCV]))
    spans = [m.span() for m in NUMBER.finditer(text)]
    for _ in range(draw(st.integers(0, 3))):
        a, b = draw(st.sampled_from(spans))
        text = text[:a] + draw(st.sampled_from(ODD) | st.text(max_size=4)) + text[b:]
        spans = [m.span() for m in NUMBER.finditer(text)]
    lines = text.splitlines(keepends=True)
    if draw(st.booleans()):
        del lines[draw(st.integers(0, len(lines) - 1))]
    data = "".join(lines).encode()
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data)))]
    if draw(st.booleans()):
        i = draw(st.integers(0, max(0, len(data) - 1)))
        data = data[:i] + draw(st.binary(min_size=1, max_size=3)) + data[i + 1 :]
    return data


@fuzz_settings(300)
@given(data=damaged())
def test_a_damaged_calibration_file_is_a_camera_or_one_line(tmp_path: Path, data: bytes) -> None:
    path = tmp_path / "cal.yaml"
    path.write_bytes(data)
    try:
        model = camera_model(config_from_dict({"camera": {"calibration_file": str(path)}}).camera)
    except ConfigError as exc:
        assert "cal.yaml" in str(exc) and "\n" not in str(exc), str(exc)
        return
    # A model that loads is one the geolocation can use: finite, and the image centre
    # looks forward.
    intr = model.intrinsics
    assert all(np.isfinite([intr.fx_px, intr.fy_px, intr.cx_px, intr.cy_px]))
    assert intr.fx_px > 0 and intr.fy_px > 0
