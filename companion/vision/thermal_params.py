"""Settings of the thermal detector (the config file's ``[thermal.detector]``).

Temperatures in degrees Celsius, areas on the floor in square metres. Every value is
checked here, once, where the config enters. The defaults were judged on the real
radiometric photos (docs/VISION.md, "Thermal"); none was fitted to the simulator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class ThermalDetectorParams:
    """How warm regions are found and judged (companion/vision/thermal.py)."""

    # A pixel is warm when it is this much above the frame's ambient level.
    min_contrast_k: float = 3.0
    # Nothing a person shows is hotter than this (machinery, hot water, lamps).
    max_skin_c: float = 40.0
    # A find's warmest part reaches this, whatever the ambient (a cold room with a
    # warm draught); the rest of it (clothes, hands in cold water) may be colder.
    min_body_c: float = 22.0
    # ... and stands this far above the ambient level: exposed skin, not a wall or a
    # floor a few kelvin warmer than the rest (a façade's windows, floor heating).
    min_peak_contrast_k: float = 8.0
    # Smallest warm area that can be a person's exposed part (a hand), m² on the floor.
    min_area_m2: float = 0.004
    # Largest warm area one person can cover (a whole body with arms out), m².
    max_area_m2: float = 1.2
    # A find at most this large is an exposed part alone (a hand ~0.015, a face
    # ~0.03, a forearm ~0.025, a head and two hands ~0.05 m²): cue "warm_part". Under
    # a tenth of a lying adult's 0.57 m², so a part alone reads CRITICAL.
    part_max_area_m2: float = 0.055
    # ... and so is a find whose longest extent where it lies (its box's width or
    # height at the range of its floor point) is at most this: a hand 0.19 m, a head
    # 0.23, a forearm 0.3; a body's torso is 0.45 m across, longer than that lying.
    # A low camera sees a raised part's side, which its pixel area overstates against
    # a lying body's; its size in metres does not. Not for a find cut by the frame.
    part_max_extent_m: float = 0.3
    # Warm parts this close on the floor are one person (a head and its hands).
    merge_gap_m: float = 0.4
    # Large and flat: at least this large with a temperature spread (standard
    # deviation) under flat_std_k is a heated surface (floor heating, a radiator
    # behind a wall), not a person (skin and clothes differ by several kelvin).
    flat_min_area_m2: float = 0.25
    flat_std_k: float = 0.6
    # At least this share of a find's pixels must see the floor (rays below the
    # horizon, in range): a lying person is on it, a warm pipe on a wall is not.
    min_floor_share: float = 0.5
    # Photos (no geometry): a whole lying adult is taken to cover this share of the
    # frame (a Lepton's 57° at about 3 m), and the merge gap is this share of its width.
    photo_body_share: float = 0.06
    photo_merge_gap_share: float = 0.06
    # ... and a find cut by the photo's edge that reaches less than this share of its
    # height (or width) into it is a sliver of something beyond the picture: its size
    # and warmth say nothing of what it is.
    photo_min_cut_share: float = 0.02
    # Warm clusters smaller than this are sensor noise, not evidence.
    min_blob_px: int = 3
    # Over frames: a find whose excess over ambient falls at least fade_k_per_s,
    # measured over at least fade_min_span_s of the last fade_window_s, is a warm
    # imprint cooling where a person lay, not a person.
    fade_k_per_s: float = 0.03
    fade_min_span_s: float = 4.0
    fade_window_s: float = 20.0
    # ... comparing only views whose metres per pixel differ by at most this share
    # (a person's parts read cooler from farther: fewer pixels, blended with the floor).
    fade_scale_tolerance: float = 0.25
    # A find is the same warm thing as one remembered within this distance
    # (floor metres with a geometry, pixels in a photo), forgotten after forget_s.
    track_radius_m: float = 0.4
    track_radius_px: float = 8.0
    track_forget_s: float = 5.0
    # Height from the rover's motion (thermal_track): a find larger than a part whose
    # top row meets the floor at a point that stays put (less than flat_max_height_m
    # high by the slope), over the views of the last shape_window_s, once the camera
    # has moved flat_motion_m along the line of sight, is warmth in the floor, not a
    # person; one whose top row meets the floor is held back until then.
    flat_max_height_m: float = 0.06
    flat_motion_m: float = 1.0
    shape_window_s: float = 15.0
    # A compact warm region (its box no longer than raised_aspect_max times its
    # width) nearer than its floor contact says, by its size against a face's or a
    # hand's (part_size_m, its longest warm extent), is a part raised on debris: a
    # hand on a pile, a face over a slab's edge. It is placed at the range its size
    # gives, on the floor below it; higher than max_raised_m above the floor it is
    # no one lying (a warm pipe, a radiator's top).
    part_size_m: float = 0.18
    max_raised_m: float = 0.9
    raised_aspect_max: float = 3.0
    # ... and is bare skin: at least half its warm pixels this warm (clothing reads
    # 26-31 °C, a face 33-35 °C, a hand 28-34 °C in a room).
    raised_skin_c: float = 31.0
    # With a geometry (a rover's frames), warm pixels less than this above ambient
    # are a body's heat through thin cover (a blanket, dust: 5-7 K where bare
    # clothing shows 10 K and skin 15): they find and place a person but do not count
    # as seen for its visible share (its urgency).
    bare_min_contrast_k: float = 8.0
    # In a stream of frames the ambient level may rise at most this fast (K/s): a
    # person filling most of the view (closer than about 1 m) lifts the frame's
    # median to body temperature, the room does not warm that fast. It falls at once.
    ambient_rise_k_per_s: float = 0.5
    # The tracked ambient is started afresh after a gap in the frames this long.
    ambient_reset_s: float = 5.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{f.name} = {value!r}: must be a number")
            if not math.isfinite(value):
                raise ValueError(f"{f.name} = {value}: must be a finite number")
        positive = [f.name for f in fields(self) if f.name not in ("min_body_c", "max_skin_c")]
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} = {getattr(self, name)}: must be > 0")
        if not -20.0 <= self.min_body_c < self.max_skin_c <= 60.0:
            raise ValueError(
                f"min_body_c = {self.min_body_c}, max_skin_c = {self.max_skin_c}: "
                "need -20 <= min_body_c < max_skin_c <= 60"
            )
        if not self.min_area_m2 < self.part_max_area_m2 < self.max_area_m2:
            raise ValueError(
                f"min_area_m2 = {self.min_area_m2}, part_max_area_m2 = {self.part_max_area_m2}, "
                f"max_area_m2 = {self.max_area_m2}: need min < part_max < max"
            )
        if self.min_contrast_k > self.min_peak_contrast_k:
            raise ValueError(
                f"min_contrast_k = {self.min_contrast_k} > min_peak_contrast_k = "
                f"{self.min_peak_contrast_k}: a find's peak is one of its warm pixels"
            )
        for name in (
            "min_floor_share",
            "photo_body_share",
            "photo_merge_gap_share",
            "photo_min_cut_share",
        ):
            if getattr(self, name) > 1.0:
                raise ValueError(f"{name} = {getattr(self, name)}: a share, must be <= 1")
        if not isinstance(self.min_blob_px, int):
            raise ValueError(f"min_blob_px = {self.min_blob_px}: must be a whole number")
        if self.fade_min_span_s > self.fade_window_s:
            raise ValueError(
                f"fade_min_span_s = {self.fade_min_span_s} > fade_window_s = "
                f"{self.fade_window_s}: the span is measured inside the window"
            )
