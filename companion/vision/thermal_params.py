"""Settings of the thermal detector (the config file's ``[thermal.detector]``).

Temperatures in degrees Celsius, areas on the floor in square metres. Every value is
checked here, once, where the config enters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ThermalDetectorParams:
    """How warm regions are found and judged (companion/vision/thermal.py)."""

    # A pixel is warm when it is this much above the frame's ambient level.
    min_contrast_k: float = 3.0
    # Nothing a person shows is hotter than this (machinery, hot water, lamps).
    max_skin_c: float = 40.0
    # Nor colder than this, whatever the ambient (a cold room with a warm draught).
    min_body_c: float = 22.0
    # Smallest warm area that can be a person's exposed part (a hand), m² on the floor.
    min_area_m2: float = 0.004
    # Largest warm area one person can cover (a whole body with arms out), m².
    max_area_m2: float = 1.2

    def __post_init__(self) -> None:
        for name in ("min_contrast_k", "max_skin_c", "min_body_c", "min_area_m2", "max_area_m2"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f"{name} = {value}: must be a finite number")
        if self.min_contrast_k <= 0.0:
            raise ValueError(f"min_contrast_k = {self.min_contrast_k}: must be > 0")
        if not -20.0 <= self.min_body_c < self.max_skin_c <= 60.0:
            raise ValueError(
                f"min_body_c = {self.min_body_c}, max_skin_c = {self.max_skin_c}: "
                "need -20 <= min_body_c < max_skin_c <= 60"
            )
        if not 0.0 < self.min_area_m2 < self.max_area_m2:
            raise ValueError(
                f"min_area_m2 = {self.min_area_m2}, max_area_m2 = {self.max_area_m2}: "
                "need 0 < min_area_m2 < max_area_m2"
            )
