"""The ``classic`` backend's parameters (companion.vision.classic)."""

from __future__ import annotations

from dataclasses import dataclass, field

from companion.vision.cues import ColourParams


@dataclass(frozen=True)
class ClassicParams:
    work_width_px: int = 320
    row_step_m: float = 0.012  # floor a working row spans near the camera (grid.py)
    max_row_step: int = 4
    colour: ColourParams = field(default_factory=ColourParams)
    skin_area_m2: tuple[float, float] = (0.004, 0.30)  # fingertips+ .. bare torso
    skin_extent_m: tuple[float, float] = (0.06, 0.7)  # longest side: a hand .. a bare arm
    max_row_m: float = 0.1  # a seed where one working row spans more floor is too far
    skin_half_width_m: float = 0.012  # thickest point: a palm is ~0.08 m wide; text strokes
    min_skin_solidity: float = 0.6  # hands, faces, cut limbs are compact; glyphs are not
    part_area_max_m2: float = 0.8  # a clothing region larger than this is not one garment
    body_area_max_m2: float = 1.0  # a whole lying adult is ~0.6 m^2
    body_extent_max_m: float = 2.2  # ... and at most ~2 m long
    part_gap_m: float = 0.12  # clothing this close to a body's parts belongs to it
    seed_gap_m: float = 1.0  # parts of one body are closer than this on the floor
    photo_width_m: float = 4.0  # without geometry: floor the frame is taken to span
    # A body cut by the left, right or bottom frame edge, or so near the bottom edge
    # that its unseen rest could lie below it, has an unknown visible share (and a
    # centroid pulled to the edge): drop it, the views before were whole.
    drop_cut_bodies: bool = True
    body_reach_m: float = 0.85  # half a body: how far the unseen rest could lie
