"""Camera calibration files, and the camera models built from [camera] and [thermal].

Two layouts are read, both through OpenCV's FileStorage:
- OpenCV's own (``cv2.FileStorage`` YAML or XML from ``calibrateCamera`` tools):
  ``camera_matrix`` (or ``K``) and ``distortion_coefficients`` (or ``D``/``dist_coeffs``)
  as ``!!opencv-matrix`` nodes, optional ``image_width``/``image_height``;
- ROS ``camera_info`` YAML (camera_calibration's output): the same keys as
  ``{rows, cols, data}`` maps, and ``image_width``/``image_height``. It has no
  ``%YAML`` header, which FileStorage needs, so one is added in memory.

A calibration made at another resolution of the same aspect ratio is scaled to the
configured frame size (binned sensor modes); a different aspect ratio is an error.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np

from companion.config import CameraConfig, ThermalConfig
from companion.config_load import ConfigError
from fusion.camera import CameraModel, Intrinsics, Mount

_MATRIX_KEYS = ("camera_matrix", "K", "cameraMatrix")
_DIST_KEYS = ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs")


Dist5 = tuple[float, float, float, float, float]


def _dist5(coeffs: object) -> Dist5:
    """Plumb-bob coefficients padded to five (k3 = 0 when only four are given)."""
    c = [float(x) for x in list(coeffs)[:5]] + [0.0] * 5  # type: ignore[call-overload]
    return (c[0], c[1], c[2], c[3], c[4])


def _read_matrix(node: cv2.FileNode) -> np.ndarray | None:
    if node.empty() or node.isNone():
        return None
    if node.isMap() and not node.getNode("data").empty():  # ROS {rows, cols, data}
        data = node.getNode("data")
        return np.array([data.at(i).real() for i in range(data.size())], dtype=float)
    mat = node.mat()
    return None if mat is None else np.asarray(mat, dtype=float).ravel()


def _open(path: Path, key: str) -> cv2.FileStorage:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{key} {str(path)!r}: cannot read: {exc.strerror}") from None
    text = raw.decode("utf-8", errors="replace")
    stripped = text.lstrip()
    if path.suffix.lower() in (".yaml", ".yml") and not stripped.startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text  # ROS camera_info has no header
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # the binding wraps cv2.error in SystemError
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ else exc
        lines = [ln for ln in str(cause).splitlines() if ln.strip()]
        first = lines[-1].strip() if lines else "parse error"
        raise ConfigError(
            f"{key} {str(path)!r}: not a readable YAML/XML calibration ({first})"
        ) from None
    if not fs.isOpened():
        raise ConfigError(f"{key} {str(path)!r}: not a readable YAML/XML calibration")
    return fs


def read_calibration(path: Path, key: str = "camera.calibration_file") -> Intrinsics:
    """Intrinsics from an OpenCV or ROS calibration file; ConfigError (naming ``key``)
    if unusable."""
    fs = _open(path, key)
    try:
        k, d, width, height = _read_nodes(fs, path, key)
    except cv2.error as exc:  # a node of the wrong kind (a cut file: "camera_matrix:" alone)
        lines = [ln for ln in str(exc).splitlines() if ln.strip()]
        raise ConfigError(
            f"{key} {str(path)!r}: not a usable calibration "
            f"({lines[-1].strip() if lines else 'unreadable node'})"
        ) from None
    finally:
        fs.release()
    if d.size not in (4, 5, 8, 12, 14) or (d.size > 5 and np.any(d[5:] != 0)):
        raise ConfigError(
            f"{key} {str(path)!r}: distortion with {d.size} coefficients is not plumb-bob (k1 k2 p1 p2 [k3])"
        )
    dist = _dist5(d)
    fx, fy, cx, cy = float(k[0]), float(k[4]), float(k[2]), float(k[5])
    try:
        if not (width > 0 and height > 0):
            # Without a stated size, assume the principal point is near the centre.
            width, height = round(2 * cx + 1), round(2 * cy + 1)
        return Intrinsics(int(width), int(height), fx, fy, cx, cy, dist)
    except (ValueError, OverflowError) as exc:  # NaN or infinite sizes and centres
        raise ConfigError(f"{key} {str(path)!r}: {exc}") from None


def _read_nodes(
    fs: cv2.FileStorage, path: Path, key: str
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The camera matrix (9 values), distortion, and stated image size (0 if none)."""
    root = fs.root()
    k = next(
        (m for name in _MATRIX_KEYS if (m := _read_matrix(root.getNode(name))) is not None), None
    )
    if k is None or k.size != 9:
        raise ConfigError(
            f"{key} {str(path)!r}: no 3x3 camera_matrix (looked for {', '.join(_MATRIX_KEYS)})"
        )
    d = next(
        (m for name in _DIST_KEYS if (m := _read_matrix(root.getNode(name))) is not None),
        np.zeros(5),
    )
    width = root.getNode("image_width").real()
    height = root.getNode("image_height").real()
    return k, d, width, height


def camera_model(cam: CameraConfig | ThermalConfig) -> CameraModel:
    """The camera model of [camera] or [thermal] for its frame size and mount (a
    thermal detection is placed on the floor by the same geometry as a colour one)."""
    key = f"{'thermal' if isinstance(cam, ThermalConfig) else 'camera'}.calibration_file"
    if cam.calibration_file is not None:
        intr = read_calibration(cam.calibration_file, key)
        if (intr.width_px, intr.height_px) != (cam.width_px, cam.height_px):
            if not math.isclose(
                intr.width_px / intr.height_px, cam.width_px / cam.height_px, rel_tol=0.01
            ):
                raise ConfigError(
                    f"{key} {str(cam.calibration_file)!r} is for "
                    f"{intr.width_px}x{intr.height_px}, whose aspect differs from the configured "
                    f"{cam.width_px}x{cam.height_px}"
                )
            try:
                intr = intr.scaled(cam.width_px, cam.height_px)
            except ValueError as exc:  # a focal length near the float limit overflows
                raise ConfigError(f"{key} {str(cam.calibration_file)!r}: {exc}") from None
    elif cam.fx_px > 0:
        cx = cam.cx_px if cam.cx_px > 0 else (cam.width_px - 1) / 2.0
        cy = cam.cy_px if cam.cy_px > 0 else (cam.height_px - 1) / 2.0
        intr = Intrinsics(
            cam.width_px, cam.height_px, cam.fx_px, cam.fy_px, cx, cy, _dist5(cam.distortion)
        )
    else:
        base = Intrinsics.from_fov(cam.width_px, cam.height_px, cam.hfov_deg)
        intr = dataclasses.replace(base, distortion=_dist5(cam.distortion))
    m = cam.mount
    mount = Mount(
        m.x_m,
        m.y_m,
        m.z_m,
        math.radians(m.roll_deg),
        math.radians(m.pitch_deg),
        math.radians(m.yaw_deg),
    )
    return CameraModel(intr, mount)
