"""The ``people`` backend's settings: the models' input specs, an adult's proportions,
and ``PeopleParams`` (what each threshold is, and what measured it)."""

from __future__ import annotations

from dataclasses import dataclass, field

from companion.config import PoseLandmarks
from companion.vision import ssd
from companion.vision.floorpoint import FloorParams

POSE_SPEC = ssd.SsdSpec(224, (8, 16, 32, 32, 32), 4, 0.5)
PALM_SPEC = ssd.SsdSpec(192, (8, 16, 16, 16), 7, 0.5)
FACE_SPEC = ssd.SsdSpec(192, (4,), 6, 0.5, interpolated_scale=False)

LANDMARK_PX = 256
HAND_PX = 224  # the hand landmark model's input
HAND_CROP_SCALE = 2.6  # MediaPipe's palm-to-hand crop: 2.6 palm boxes,
HAND_CROP_SHIFT = 0.5  # shifted half a box towards the fingers

# Proportions of an adult (share of standing height): for a body's own extent in a
# photo, and for the whole body behind a lone face or hand.
BODY_WIDTH_SHARE = 0.26  # 0.45 m of 1.7 m
FACE_HEIGHT_SHARE = 0.13  # chin to hairline, as the face detector boxes it
HAND_LENGTH_SHARE = 0.11


@dataclass(frozen=True)
class PeopleParams:
    person_min_score: float = 0.5  # BlazePose person detector
    landmark_min_flag: float = 0.5  # landmark model's "a person is in this crop"
    face_min_score: float = 0.75  # a face that stands alone (supporting: person_min_score)
    # A palm that stands alone (no body around it) is a hand when the hand landmark
    # model, on the crop around it, flags a hand (``hand_min_flag``). The palm
    # detector alone scores 0.5-0.86 on the simulator's exposed hands and on its
    # skin-coloured planks and wedges alike; the hand flag reads 0.00-0.03 on every
    # plank and 0.84-0.98 on the hands seen near (scenario suite, 2026-11-27). Before,
    # a lone palm needed a score of 0.8 and no check: no hand-only victim was found,
    # and lowering the score alone found 1-3 of 7 with 1-4 more false victims.
    palm_min_score: float = 0.5
    hand_min_flag: float = 0.5
    max_hand_checks: int = 3  # hand landmark crops per frame (~5 ms each on one core)
    part_support_score: float = 0.5  # a face or palm that supports a body
    mask_threshold: float = 0.5
    # A body's visible share is at most the share of its main joints whose heatmaps
    # peak at ``seen_min_logit`` or more (seenparts.py: the mask fills in covered
    # parts, the heatmaps do not), and that cap is never below ``seen_share_floor``:
    # the heatmaps alone make a body MEDIUM at most, never CRITICAL (a skeleton the
    # model fits badly has every joint weak on a body it sees whole); only a small
    # visible area, of a mask or a lone part, does. None: the mask alone.
    seen_min_logit: float | None = -0.4
    seen_share_floor: float = 0.25
    # Which BlazePose landmark model: "full" (~14 ms a body on one core here) or
    # "lite" (~10 ms), as MediaPipe's model_complexity 1 and 0. Same outputs. On the
    # real burial benchmark (2026-11-28) full finds more buried people (at 50 / 5 %
    # visible 20 / 12 of 24, lite 19 / 9) and reads more of them right (80 % covered:
    # 16 of 16, lite 14 of 16); docs/VISION.md "Which landmark model".
    landmarks: PoseLandmarks = "full"
    max_bodies: int = 4  # landmark crops per frame (each ~14 ms on one core, lite ~10)
    # Extra detector passes, ~10 ms each. The person detector sees the whole frame at
    # 224 px and is trained on mostly upright people: a body lying across the view is
    # found more often in the frame turned by 90 degrees (clockwise, anticlockwise),
    # and a body far along the floor (from a low rover camera, a thin strip near the
    # horizon) only in a zoomed tile of that band of the frame. ``extra_passes``: how
    # many of those run per frame, taking turns (a live camera sees a body on many
    # frames); a large number runs all of them on every frame, as for a single photo.
    extra_passes: int = 1
    # The face (~5 ms) and palm (~12 ms) detectors look for the small exposed parts of
    # a buried person. Live they take turns, one per frame, as the extra passes do (a
    # hand in view for a second is still searched five times at 10 frames/s); False
    # runs both on every frame, as for a single photo. After a frame with a hand, the
    # palm detector runs on the next frame too (a rover passing an exposed hand sees
    # it for a second or so: every frame of it counts towards a victim).
    parts_take_turns: bool = True
    far_tiles: bool = True  # tiles of the far floor band (needs the frame's geometry)
    # Without a geometry (a photo) the far band is unknown: a 2:1 tile of this share of
    # the frame's width at its centre zooms a small or distant body by 1/share.
    centre_tile_share: float = 0.75
    far_band_mpp: float = 0.0045  # floor farther than this many metres per pixel
    tile_min_px: int = 160  # a tile's height at least; its width is twice its height
    floor: FloorParams = field(default_factory=FloorParams)  # where a body lies (floorpoint.py)
    silhouette_fill: float = 0.75  # body silhouette / length x width rectangle
    # The models see better on the enhanced frame only when the scene is dark (on
    # well-lit real frames enhancement costs recall: bench/real_images.py).
    enhance_below_luma: float = 0.25
    lone_person_weight: float = 0.75  # a person detection no other cue supports
    min_part_mask_share: float = 0.2  # a lone part's box covered by the person mask for "mask"
    attached_body_share: float = 6.0  # person mask around a part this many boxes: a body
    same_body_overlap: float = 0.6  # two passes' bodies overlapping this much: one body
