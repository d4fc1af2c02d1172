"""Thermal burial (simulated): the thermal detector's recall and urgency per visible share.

The simulated burial benchmark's bodies and slabs (section sim_burial: the same
seeded victims, each buried by a slab until about 50, 20 or 5 % of its footprint
stays uncovered), seen through the simulator's Lepton 3.5 (160x120, 57 deg, beside
the colour camera 0.3 m up and 12 deg down) from 1.5, 2.5 and 3.5 m at four
bearings (bench.sim_burial.thermal_views: a view counts when the renderer shows at
least a few warm pixels of the body). Each view is one frame to a fresh thermal
detector (no history: a first sight), with the geometry built from the pose as the
pipeline does; it is found when a find's floor point lies within 1 m of the body's
centre or of its visible part, and its urgency is the one the pipeline gives that
find alone (its warm area against a whole lying adult's there; a small part alone
is CRITICAL). Targets (issue 41): at 5 % visible recall >= 0.9 and CRITICAL in >=
0.8 of the finds; at 20 % recall >= 0.95. The renderer is ours: the detector was
judged first on the real radiometric photos (section thermal_real).

"Driving up": the same views, each the last of five frames the rover takes 0.3 m
apart as it drives the last 1.2 m up to it along its bearing (a frame every 0.75 s,
0.4 m/s), all to one fresh detector: what its memory over frames (a fading imprint,
warmth flat on the floor: thermal_track) makes of a body seen while the rover moves.
A find larger than a part whose height the motion has not shown yet is still a find
here (cue ``warm_unsettled``: in the pipeline it gives a victim no support until it
is settled).
"""

from __future__ import annotations

from typing import Any

from companion.vision.base import FrameGeometry
from companion.vision.thermal import ThermalDetector
from companion.vision.visibility import assess
from fusion.types import Detection, Urgency

LEVELS_PCT = (50, 20, 5)
APPROACH_M = 1.2  # driving up to a view: the last 1.2 m, a frame every 0.3 m
FRAME_S = 0.75  # 0.3 m at the simulated rover's 0.4 m/s


def _detect(frames: list[tuple[Any, FrameGeometry]]) -> list[Detection]:
    """A fresh detector's detections in the last frame, the others seen before it."""
    detector = ThermalDetector()
    for i, (temps_c, geometry) in enumerate(frames[:-1]):
        detector.detect(temps_c, geometry, FRAME_S * i)
    temps_c, geometry = frames[-1]
    return detector.detect(temps_c, geometry, FRAME_S * (len(frames) - 1))


def _urgency(detection: Detection, geometry: FrameGeometry) -> Urgency | None:
    assessment = assess(detection, geometry)
    return None if assessment is None else assessment.urgency


def run() -> dict[str, Any]:
    from bench.sim_burial import measure_thermal_level

    out: dict[str, Any] = {}
    for level in LEVELS_PCT:
        m = measure_thermal_level(level, _detect, _urgency)
        out[f"recall at {level} % visible (views: {m['views']})"] = m["recall"]
        out[f"urgency right at {level} % visible"] = m["urgency_right"]
    for level in LEVELS_PCT:
        m = measure_thermal_level(level, _detect, _urgency, approach_m=APPROACH_M)
        out[f"driving up: recall at {level} % visible"] = m["recall"]
        out[f"driving up: urgency right at {level} % visible"] = m["urgency_right"]
    return out


if __name__ == "__main__":  # pragma: no cover
    for key, value in run().items():
        print(f"{key}: {value}")
