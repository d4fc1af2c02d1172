"""The simulated camera: the companion's default [camera] settings, and how to write them.

The renderer and the companion must agree on the camera exactly, so the sim's
default camera is built by the companion's own code from its default config
(640x480, 70 degrees horizontal field of view, 12 degrees down, 15 cm forward and
20 cm above the vehicle reference point), and recordings carry a ``camera.toml``
that the companion's config loader reads back into the same model.

The thermal camera (``default_thermal_camera``) is a FLIR Lepton 3.5 as the
companion's [thermal] section describes one: 160x120, 57 degrees across, 8.7
frames/s, mounted 5 cm to the right of the colour camera at the same pitch; a
recording's ``camera.toml`` carries its [thermal] section too (``thermal_toml``).
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


THERMAL_SIZE_PX = (160, 120)
THERMAL_HFOV_DEG = 57.0
THERMAL_FPS = 8.7
THERMAL_BESIDE_M = 0.05  # to the right of the colour camera


def default_thermal_camera() -> CameraModel:
    """The Lepton 3.5 beside the colour camera: built by the companion's own code, so
    the sim and the [thermal] section of a recording agree on it exactly."""
    from companion.calibration import camera_model
    from companion.config import CameraConfig, MountConfig

    colour = CameraConfig(source="sim").mount
    mount = MountConfig(
        x_m=colour.x_m,
        y_m=colour.y_m + THERMAL_BESIDE_M,
        z_m=colour.z_m,
        roll_deg=colour.roll_deg,
        pitch_deg=colour.pitch_deg,
        yaw_deg=colour.yaw_deg,
    )
    w, h = THERMAL_SIZE_PX
    return camera_model(
        CameraConfig(source="sim", width_px=w, height_px=h, hfov_deg=THERMAL_HFOV_DEG, mount=mount)
    )


def _deg(rad: float) -> float:
    """Degrees, rounded to 1e-9: the config's degrees -> radians -> degrees round trip
    (-12 -> -12.000000000000002) must read back as the same radians."""
    return round(math.degrees(rad), 9)


def camera_toml(camera: CameraModel, source: str, fps: float, section: str = "camera") -> str:
    """A [camera] config fragment that rebuilds exactly this camera model. The detector
    is the product's default (the real person models), as on the Pi. ``section``:
    "thermal" for the thermal camera's (its mount in [thermal.mount])."""
    k, m = camera.intrinsics, camera.mount
    dist = ", ".join(repr(float(c)) for c in k.distortion)
    return "\n".join(
        [
            f"# The {'colour' if section == 'camera' else section} camera the frames were "
            "rendered with (rescue-sim).",
            f"[{section}]",
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
            f"[{section}.mount]",
            f"x_m = {m.x_m!r}",
            f"y_m = {m.y_m!r}",
            f"z_m = {m.z_m!r}",
            f"roll_deg = {_deg(m.roll_rad)!r}",
            f"pitch_deg = {_deg(m.pitch_rad)!r}",
            f"yaw_deg = {_deg(m.yaw_rad)!r}",
            "",
        ]
    )


def thermal_toml(camera: CameraModel, source: str, fps: float = THERMAL_FPS) -> str:
    """The [thermal] section (and [thermal.mount]) that rebuilds this thermal camera;
    emissivity as the companion's default for skin (0.98)."""
    text = camera_toml(camera, source, fps, section="thermal")
    return text.replace("\n\n[thermal.mount]", "\nemissivity = 0.98\n\n[thermal.mount]", 1)


def write_camera_toml(
    camera: CameraModel,
    path: Path,
    source: str,
    fps: float,
    thermal: tuple[CameraModel, str, float] | None = None,
) -> None:
    """Write the [camera] section and, given (camera, source, fps), the [thermal] one."""
    text = camera_toml(camera, source, fps)
    if thermal is not None:
        text += "\n" + thermal_toml(*thermal)
    Path(path).write_text(text, encoding="utf-8")
