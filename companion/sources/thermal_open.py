"""The configured thermal camera: ``open_thermal(config.thermal)``.

The camera is opened behind ``reopen.ReopeningSource``, as the colour one is: a
failed or vanished device is reopened with backoff up to
``thermal.reopen_max_backoff_s``, a live one silent for ``thermal.stall_timeout_s``
is reopened, a recording never is (EndOfStream passes through). ``read`` raises only
CameraError and its subclasses: the colour pipeline goes on whatever the thermal
camera does. ``status`` is one line for the operator.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import cast

import cv2

from companion.config import ThermalConfig
from companion.sources.base import FrameSource
from companion.sources.reopen import ReopeningSource
from companion.sources.thermal import ThermalFrame, parse_thermal_source
from companion.sources.thermal_folder import ThermalFramesDir
from companion.sources.thermal_live import (
    VIDEO4LINUX,
    ThermalCaptureSource,
    VideoCaptureLike,
    find_purethermal,
)
from companion.sources.thermal_sim import ThermalSimSource

AnyThermal = ThermalCaptureSource | ThermalFramesDir | ThermalSimSource


def open_thermal_source(
    thermal: ThermalConfig,
    capture: Callable[[], VideoCaptureLike] = cv2.VideoCapture,
    video4linux: Path = VIDEO4LINUX,
) -> AnyThermal:
    """Open the configured thermal camera once; CameraError when it cannot be opened."""
    spec = parse_thermal_source(thermal.source)
    if spec.kind == "frames":
        return ThermalFramesDir(Path(spec.target), thermal.width_px, thermal.height_px)
    if spec.kind == "sim":
        return ThermalSimSource(
            spec.target, spec.port, thermal.width_px, thermal.height_px, thermal.emissivity
        )
    device = spec.target or find_purethermal(video4linux)
    return ThermalCaptureSource(
        device,
        spec.kind,
        thermal.width_px,
        thermal.height_px,
        thermal.fps,
        thermal.emissivity,
        capture,
    )


class ReopeningThermalSource:
    """The thermal camera behind a ReopeningSource (see the module)."""

    def __init__(
        self,
        thermal: ThermalConfig,
        capture: Callable[[], VideoCaptureLike] = cv2.VideoCapture,
        video4linux: Path = VIDEO4LINUX,
    ) -> None:
        spec = parse_thermal_source(thermal.source)  # a malformed string is a config error
        live = spec.kind != "frames"
        self.name = thermal.source
        self._current: AnyThermal | None = None

        def factory() -> FrameSource:
            self._current = open_thermal_source(thermal, capture, video4linux)
            self.name = self._current.name
            # ReopeningSource is typed for colour sources; it only calls read and
            # close, and hands back what read returned: here ThermalFrames.
            return cast(FrameSource, self._current)

        self._reopening = ReopeningSource(
            factory,
            max_backoff_s=thermal.reopen_max_backoff_s,
            initial_backoff_s=min(0.2, thermal.reopen_max_backoff_s),
            stall_timeout_s=thermal.stall_timeout_s
            if live and thermal.stall_timeout_s > 0
            else None,
            name=thermal.source,
        )

    @property
    def status(self) -> str:
        """One line: "ok", why frames are being skipped, or why the camera is down."""
        if self._reopening.last_error:
            return f"down: {self._reopening.last_error}"
        if self._current is None:
            return "not open yet"
        return self._current.status

    @property
    def healthy(self) -> bool:
        return self._reopening.healthy

    def read(self, timeout_s: float) -> ThermalFrame:
        return cast(ThermalFrame, self._reopening.read(timeout_s))

    def close(self) -> None:
        self._reopening.close()


def open_thermal(
    thermal: ThermalConfig,
    capture: Callable[[], VideoCaptureLike] = cv2.VideoCapture,
    video4linux: Path = VIDEO4LINUX,
) -> ReopeningThermalSource:
    """The configured thermal camera, reopened with backoff (the companion's use)."""
    return ReopeningThermalSource(thermal, capture, video4linux)
