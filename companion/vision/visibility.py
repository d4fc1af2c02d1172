"""Visibility: the visible share of a body, and the urgency class it implies.

visibility_pct = 100 * visible mask pixels / pixels a whole lying adult would cover
at that floor point (FrameGeometry.expected_body_area_px), clamped to [0, 100].
Urgency follows fusion.types.Urgency.from_visibility: over 50 % LIGHT, 10-50 %
MEDIUM, under 10 % CRITICAL. An exposed hand (~0.015 m^2 of a ~0.57 m^2 body) is
~3 %: CRITICAL; a half-buried body MEDIUM; a fully visible one LIGHT.

A detection that says how much of the body its detector saw by other evidence
(``Detection.seen_share_max``: the person models' joint heatmaps, where the mask
fills in a covered body) is capped at that share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.vision.base import FrameGeometry
from fusion.types import Detection, Urgency


def visibility_pct(visible_area_px: float, expected_body_area_px: float) -> float:
    """Visible share of a whole body in percent, in [0, 100]."""
    if not (math.isfinite(visible_area_px) and math.isfinite(expected_body_area_px)):
        raise ValueError(
            f"visibility needs finite areas, got {visible_area_px!r} / {expected_body_area_px!r}"
        )
    if expected_body_area_px <= 0.0:
        raise ValueError(f"expected_body_area_px must be > 0, got {expected_body_area_px}")
    return min(100.0, max(0.0, 100.0 * visible_area_px / expected_body_area_px))


def urgency(visible_area_px: float, expected_body_area_px: float) -> Urgency:
    return Urgency.from_visibility(visibility_pct(visible_area_px, expected_body_area_px))


@dataclass(frozen=True)
class Assessment:
    visibility_pct: float
    urgency: Urgency
    expected_body_area_px: float


def assess(detection: Detection, geometry: FrameGeometry | None) -> Assessment | None:
    """Visibility and urgency of a detection; None where the geometry has no floor.

    With a geometry, the pixels a whole lying adult would cover where the body lies
    (at ``Detection.whole_uv_px`` where the detector placed a mostly hidden body
    apart from the whole body its joints describe). Without one (a photo) the
    detector's own estimate of the whole body's pixels is used
    (``Detection.expected_area_px``); None if it gave none."""
    if geometry is None:
        expected: float | None = detection.expected_area_px
    else:
        u, v = detection.whole_uv_px or (detection.u_px, detection.v_px)
        expected = geometry.expected_body_area_px(u, v, detection.body_heading_rad)
    if expected is None or expected <= 0.0:
        return None
    pct = visibility_pct(detection.visible_area_px, expected)
    if detection.seen_share_max is not None:
        pct = min(pct, 100.0 * detection.seen_share_max)
    return Assessment(pct, Urgency.from_visibility(pct), expected)
