"""The simulated camera: the companion's default [camera] settings, and how to write them.

The renderer and the companion must agree on the camera exactly, so the sim's
default camera is built by the companion's own code from its default config
(640x480, 70 degrees horizontal field of view, 12 degrees down, 15 cm forward and
20 cm above the vehicle reference point), and recordings carry a ``camera.toml``
that the companion's config loader reads back into the same model.
"""

from __future__ import annotations

import math
from pathlib import Path

from fusion.camera import CameraModel

VEHICLE_HEIGHT_M = (
    0.10  # the vehicle reference point above the floor (GeolocationParams.floor_down_m)
)


def default_camera() -> CameraModel:
    from companion.calibration import camera_model
    from companion.config import CameraConfig

    return camera_model(CameraConfig(source="sim"))


def _deg(rad: float) -> float:
    """Degrees, rounded to 1e-9: the config's degrees -> radians -> degrees round trip
    (-12 -> -12.000000000000002) must read back as the same radians."""
    return round(math.degrees(rad), 9)


def camera_toml(camera: CameraModel, source: str, fps: float) -> str:
    """A [camera] config fragment that rebuilds exactly this camera model. The detector
    is the product's default (the real person models), as on the Pi."""
    k, m = camera.intrinsics, camera.mount
    dist = ", ".join(repr(float(c)) for c in k.distortion)
    return "\n".join(
        [
            "# The camera the frames were rendered with (rescue-sim).",
            "[camera]",
            f"source = {source!r}".replace("'", '"'),
            f"width_px = {k.width_px}",
            f"height_px = {k.height_px}",
            f"fps = {float(fps)!r}",
            f"fx_px = {k.fx_px!r}",
            f"fy_px = {k.fy_px!r}",
            f"cx_px = {k.cx_px!r}",
            f"cy_px = {k.cy_px!r}",
            f"distortion = [{dist}]",
            "",
            "[camera.mount]",
            f"x_m = {m.x_m!r}",
            f"y_m = {m.y_m!r}",
            f"z_m = {m.z_m!r}",
            f"roll_deg = {_deg(m.roll_rad)!r}",
            f"pitch_deg = {_deg(m.pitch_rad)!r}",
            f"yaw_deg = {_deg(m.yaw_rad)!r}",
            "",
        ]
    )


def write_camera_toml(camera: CameraModel, path: Path, source: str, fps: float) -> None:
    Path(path).write_text(camera_toml(camera, source, fps), encoding="utf-8")
