"""Thermal cameras: frames of temperatures, one interface for every kind of source.

A thermal frame is a float32 H x W array of temperatures in degrees Celsius, every
value finite, with its capture time on both clocks (as a colour ``Frame``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class ThermalFrame:
    """One thermal picture: temperatures with their capture time on both clocks."""

    temps_c: np.ndarray = field(repr=False)  # float32 H x W, degrees Celsius, finite
    t_mono_s: float  # capture time on the companion's time.monotonic()
    t_unix_s: float  # capture time on the wall clock
    index: int  # frame number from the source

    def __post_init__(self) -> None:
        t = self.temps_c
        if t.dtype != np.float32 or t.ndim != 2 or t.size == 0:
            raise ValueError(
                f"ThermalFrame.temps_c must be float32 H x W, got {t.dtype} {tuple(t.shape)}"
            )


class ThermalSource(Protocol):
    """A thermal camera. ``read`` raises CameraTimeout, CameraError or EndOfStream."""

    name: str

    def read(self, timeout_s: float) -> ThermalFrame: ...

    def close(self) -> None: ...
