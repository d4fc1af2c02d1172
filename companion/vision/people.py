"""The ``people`` backend: pretrained MediaPipe person models, fused into one
detection per body.

Models (companion/vision/models.py; all Apache-2.0, run on one CPU thread):

- BlazePose person detector (224x224, letterboxed frame): finds a person by the
  head and upper body, and gives the hip centre and a body-scale point;
- BlazePose landmarks, full (or lite; 256x256, an oriented crop around each person): 33
  body points (all of them, visible or not) and a mask of the body's visible
  pixels; its pose flag says whether a person is really in the crop;
- selfie segmentation (144x256, the whole frame): person pixels; it also paints
  some non-people (a red car), so it only ever measures a body another cue found,
  and runs only on frames that have one without landmarks or a lone part;
- palm detector (192x192) and full-range face detector (192x192): the small parts
  that stay visible under rubble, alone or as support for a body;
- hand landmarks (224x224, the crop MediaPipe's hand tracker takes around a palm):
  its hand flag says whether a lone palm is a hand (the palm detector alone also
  fires on skin-coloured planks).

Fusion, per frame:

1. Each person detection is a body. Its region is the landmark model's crop; its
   visible pixels are the landmark mask or the segmentation inside that region.
2. A face or palm inside a body's region supports that body (a cue). One that
   belongs to no body is a body of its own: a lone exposed part (a palm only when
   the hand landmark model sees a hand in the crop around it).
3. Cues are listed on the detection: person, landmarks, mask, face, hand.

Visible area is measured in frame pixels; ``visibility.assess`` divides it by the
area a whole lying adult would cover at the body's floor point (the camera
geometry), or, without a geometry (a photo), by the body's own extent from its
landmarks (``Detection.expected_area_px``). The landmark mask fills in a covered
body; a person detector's body is therefore capped at the share of its main joints
whose heatmaps see them (``seenparts.py``; ``Detection.seen_share_max``), at least
a quarter: the heatmaps alone make a body MEDIUM, never CRITICAL. Not on a dark
frame, where they are weak on uncovered people too.

Where the body lies: ``floorpoint.py``.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from companion.vision import models, seenparts, ssd
from companion.vision.base import FrameGeometry
from companion.vision.enhance import Enhancer
from companion.vision.floorpoint import (
    ANKLES,
    HIPS,
    KNEES,
    N_BODY_POINTS,
    SHOULDERS,
    floor_pixel,
)
from companion.vision.people_bodies import Body, View, add_body, bbox
from companion.vision.people_params import (
    BODY_WIDTH_SHARE,
    FACE_HEIGHT_SHARE,
    FACE_SPEC,
    HAND_CROP_SCALE,
    HAND_CROP_SHIFT,
    HAND_LENGTH_SHARE,
    HAND_PX,
    LANDMARK_PX,
    PALM_SPEC,
    POSE_SPEC,
    PeopleParams,
)
from companion.vision.tflite import Model, RotatedRect, letterbox, to_range
from fusion.types import Detection


def _mean_luma(image_bgr: np.ndarray) -> float:
    """Mean luma in [0, 1] on a 1/8 subsample."""
    small = image_bgr[::8, ::8]
    grey = cv2.cvtColor(np.ascontiguousarray(small), cv2.COLOR_BGR2GRAY)
    return float(grey.mean()) / 255.0


def _upright_angle(low: np.ndarray, high: np.ndarray) -> float:
    """The turn of a RotatedRect that puts ``high`` straight above ``low`` in its crop
    (MediaPipe's rotation with a target angle of 90 degrees)."""
    return math.pi / 2 - math.atan2(-(high[1] - low[1]), high[0] - low[0])


def _rect_from_keypoints(kp: np.ndarray, scale: float = 1.25) -> RotatedRect:
    (x0, y0), (x1, y1) = kp[0], kp[1]
    size = 2.0 * math.hypot(x1 - x0, y1 - y0) * scale
    return RotatedRect(float(x0), float(y0), max(size, 8.0), _upright_angle(kp[0], kp[1]))


class PeopleDetector:
    """Person models fused into one detection per body. One instance per thread."""

    name = "people"

    def __init__(
        self,
        params: PeopleParams | None = None,
        enhancer: Enhancer | None = None,
        min_score: float = 0.5,
        model_dir: Path | None = None,
        threads: int = 1,
    ) -> None:
        self.params = params or PeopleParams()
        self.enhancer = enhancer
        self.min_score = min_score

        def load(name: str) -> Model:
            return Model(models.model_path(name, model_dir), threads)

        self._pose = load("pose_detection.tflite")
        self._landmarks = load(f"pose_landmark_{self.params.landmarks}.tflite")
        self._segment = load("selfie_segmentation_landscape.tflite")
        self._palm = load("palm_detection_lite.tflite")
        self._face = load("face_detection_full_range.tflite")
        self._hand = load("hand_landmark_lite.tflite")
        self._frame = 0  # extra passes run, for their turns
        self._parts_turn = 0  # frames searched for parts, for the face/palm turns
        self._hand_seen = False  # the last frame had a lone hand: look again, out of turn
        self._anchors = {
            "pose": ssd.anchors(POSE_SPEC),
            "palm": ssd.anchors(PALM_SPEC),
            "face": ssd.anchors(FACE_SPEC),
        }

    # -- models ---------------------------------------------------------------

    def _ssd(
        self, model: Model, spec: ssd.SsdSpec, key: str, rgb: np.ndarray, lo: float
    ) -> list[tuple[ssd.SsdDetection, np.ndarray, np.ndarray]]:
        """Detections with their box (x0, y0, x1, y1) and keypoints in frame pixels."""
        square, lb = letterbox(rgb, spec.input_px)
        raw_boxes, raw_scores = model(to_range(square, lo, 1.0))
        out = []
        for d in ssd.decode(spec, self._anchors[key], raw_boxes, raw_scores):
            box = lb.to_image(np.array(d.box).reshape(2, 2)).reshape(-1)
            out.append((d, box, lb.to_image(d.keypoints)))
        return out

    def _passes(self, geometry: FrameGeometry | None, w: int, h: int) -> list[View]:
        """The views this frame is searched in: the whole frame, then extra passes."""
        p = self.params
        extras: list[View] = [
            View(cv2.ROTATE_90_CLOCKWISE, None),
            View(cv2.ROTATE_90_COUNTERCLOCKWISE, None),
        ]
        if p.far_tiles and geometry is not None:
            extras += [View(None, t) for t in self._far_tiles(geometry, w, h)]
        elif 0.0 < p.centre_tile_share < 1.0:
            tw = round(w * p.centre_tile_share)
            th = min(h, tw // 2)
            x0, y0 = (w - tw) // 2, (h - th) // 2
            extras.append(View(None, (x0, y0, x0 + tw, y0 + th)))
        if p.extra_passes >= len(extras):
            return [View(None, None), *extras]
        chosen = []
        for _ in range(max(0, p.extra_passes)):
            chosen.append(extras[self._frame % len(extras)])
            self._frame += 1
        return [View(None, None), *chosen]

    def _far_tiles(
        self, geometry: FrameGeometry, w: int, h: int
    ) -> list[tuple[int, int, int, int]]:
        """Overlapping tiles (x0, y0, x1, y1), twice as wide as high, over the band of
        rows whose floor lies farther than ``far_band_mpp`` (where a lying body is a
        thin strip the whole-frame pass cannot resolve)."""
        p = self.params
        vs = list(range(4, h, 8))
        rows = [
            v
            for v, m in zip(vs, geometry.metres_per_px_column(w / 2, vs), strict=True)
            if m is not None and m >= p.far_band_mpp
        ]
        if not rows:
            return []
        bottom = min(h, max(rows) + 8)
        height = min(h, max(p.tile_min_px, 2 * (bottom - min(rows))))
        top = max(0, bottom - height)  # the band, and room above it for a body's height
        width = min(w, 2 * height)
        n = max(1, math.ceil((w - width) / (0.5 * width)) + 1)
        step = (w - width) / (n - 1) if n > 1 else 0.0
        return [(round(i * step), top, round(i * step) + width, top + height) for i in range(n)]

    def _persons(
        self, rgb: np.ndarray, view: View
    ) -> list[tuple[ssd.SsdDetection, np.ndarray, np.ndarray]]:
        """Person detections (box and keypoints in frame pixels) in one view: the frame
        or a tile of it, as it is or turned by 90 degrees (``cv2.ROTATE_*``)."""
        x0, y0 = 0, 0
        image = rgb
        if view.tile is not None:
            x0, y0, x1, y1 = view.tile
            image = np.ascontiguousarray(rgb[y0:y1, x0:x1])
        turn = view.turn
        if turn is not None:
            image = cv2.rotate(image, turn)
        found = [
            x
            for x in self._ssd(self._pose, POSE_SPEC, "pose", image, -1.0)
            if x[0].score >= self.params.person_min_score
        ]
        h, w = image.shape[:2] if turn is None else image.shape[1::-1]
        offset = np.array([x0, y0], np.float64)

        def back(xy: np.ndarray) -> np.ndarray:
            xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
            if turn == cv2.ROTATE_90_CLOCKWISE:  # (x', y') = (h - 1 - y, x)
                xy = np.column_stack([xy[:, 1], h - 1 - xy[:, 0]])
            elif turn == cv2.ROTATE_90_COUNTERCLOCKWISE:
                xy = np.column_stack([w - 1 - xy[:, 1], xy[:, 0]])
            return xy + offset

        out = []
        for d, box, kp in found:
            corners = back(box.reshape(2, 2))
            lo, hi = corners.min(axis=0), corners.max(axis=0)
            out.append((d, np.concatenate([lo, hi]), back(kp)))
        return out

    def _segmentation(self, rgb: np.ndarray) -> np.ndarray:
        h, w = self._segment.input_hw
        small = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
        prob = self._segment(to_range(small, 0.0, 1.0))[0][..., 0]
        return cv2.resize(prob, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_LINEAR)

    def _body(
        self,
        rgb: np.ndarray,
        seg: Callable[[], np.ndarray],
        score: float,
        kp: np.ndarray,
        box: np.ndarray,
        judge_seen: bool = True,
    ) -> Body:
        p = self.params
        hw = rgb.shape[:2]
        rect = _rect_from_keypoints(kp)
        out = self._landmarks(to_range(rect.crop(rgb, LANDMARK_PX), 0.0, 1.0))
        flag = float(out[1].reshape(-1)[0])
        region = rect.paste(np.ones((LANDMARK_PX, LANDMARK_PX), np.uint8), hw)
        cues = {"person"}
        points = seen = share = None
        raw = out[0].reshape(-1, 5)[:N_BODY_POINTS]
        joints = rect.to_image(raw[:, :2], LANDMARK_PX)
        if flag >= p.landmark_min_flag:
            cues.add("landmarks")
            points = joints
            seen = 1.0 / (1.0 + np.exp(-np.clip(raw[:, 3], -30, 30)))
            lm_logit = out[2][..., 0]
            lm_prob = rect.paste(1.0 / (1.0 + np.exp(-np.clip(lm_logit, -30, 30))), hw)
            mask = lm_prob > p.mask_threshold
        else:
            mask = (seg() > p.mask_threshold) & (region > 0)
        if p.seen_min_logit is not None and judge_seen:
            # Also where the landmark model does not confirm a person in the crop: its
            # joints are then a guess, but its weak heatmaps still say it sees little
            # of a body there, and the segmentation's mask spreads over debris.
            evidence = seenparts.joint_evidence(out[3], N_BODY_POINTS)
            share = seenparts.seen_share(joints, evidence, (hw[1], hw[0]), p.seen_min_logit)
        if mask.any():
            cues.add("mask")
        x0, y0, x1, y1 = (float(b) for b in box)
        if points is not None:
            x0, y0 = min(x0, float(points[:, 0].min())), min(y0, float(points[:, 1].min()))
            x1, y1 = max(x1, float(points[:, 0].max())), max(y1, float(points[:, 1].max()))
        if mask.any():
            ys, xs = np.nonzero(mask)
            x0, y0 = min(x0, float(xs.min())), min(y0, float(ys.min()))
            x1, y1 = max(x1, float(xs.max() + 1)), max(y1, float(ys.max() + 1))
        combined = score if points is None else 1.0 - (1.0 - score) * (1.0 - 0.5 * flag)
        if cues == {"person"}:
            combined *= p.lone_person_weight  # the detector alone fires on empty rooms
        return Body(
            combined,
            cues,
            region,
            mask,
            points,
            kp[0],
            (x0, y0, x1, y1),
            seen=seen,
            seen_share=share,
        )

    # -- fusion ---------------------------------------------------------------

    def detect(
        self, image_bgr: np.ndarray, geometry: FrameGeometry | None, t_mono_s: float
    ) -> list[Detection]:
        p = self.params
        dark = _mean_luma(image_bgr) < p.enhance_below_luma
        if self.enhancer is not None and dark:
            image_bgr = self.enhancer(image_bgr)
        rgb = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2RGB)
        h, w = rgb.shape[:2]
        # The whole-frame segmentation only measures bodies without landmarks and lone
        # parts: run on first use (most frames need none of it: ~4 ms saved).
        seg = functools.cache(lambda: self._segmentation(rgb))
        bodies: list[Body] = []
        for view in self._passes(geometry, w, h):
            for d, box, kp in self._persons(rgb, view):
                if len(bodies) >= p.max_bodies:
                    break
                hx = int(np.clip(kp[0, 0], 0, w - 1))
                hy = int(np.clip(kp[0, 1], 0, h - 1))
                if any(b.region[hy, hx] for b in bodies):
                    continue  # the same body, seen again by a turned pass
                # On a dark frame the heatmaps are weak on uncovered people too: of 19
                # found on real frames at 12 % light, 4 read MEDIUM by their seen
                # share, none by the mask alone (2026-11-27). There the mask decides.
                body = self._body(rgb, seg, d.score, kp, box, judge_seen=not dark)
                add_body(bodies, body, p.same_body_overlap)
        parts = []
        turn = self._parts_turn
        self._parts_turn += 1
        if not p.parts_take_turns or turn % 2 == 0:
            parts += [("face", x) for x in self._ssd(self._face, FACE_SPEC, "face", rgb, -1.0)]
        if not p.parts_take_turns or turn % 2 == 1 or self._hand_seen:
            parts += [("hand", x) for x in self._ssd(self._palm, PALM_SPEC, "palm", rgb, 0.0)]
        self._hand_seen = False
        checks = 0
        for kind, (d, box, kp) in parts:
            cx = int(np.clip((box[0] + box[2]) / 2, 0, w - 1))
            cy = int(np.clip((box[1] + box[3]) / 2, 0, h - 1))
            owner = next((b for b in bodies if b.region[cy, cx]), None)
            if owner is not None:
                if d.score >= p.part_support_score:
                    owner.cues.add(kind)
                continue
            if kind == "face":
                if d.score < p.face_min_score:
                    continue
            else:
                if d.score < p.palm_min_score or checks >= p.max_hand_checks:
                    continue
                checks += 1
                if self._hand_flag(rgb, box, kp) < p.hand_min_flag:
                    continue
                self._hand_seen = True
            bodies.append(self._part(kind, d.score, box, seg, w, h))
        out = []
        for b in bodies:
            det = self._detection(b, geometry, t_mono_s, w, h)
            if det is not None and det.score >= self.min_score:
                out.append(det)
        return out

    def _hand_flag(self, rgb: np.ndarray, box: np.ndarray, kp: np.ndarray) -> float:
        """The hand landmark model's "a hand is in this crop" (0-1) for a palm box and
        its keypoints in frame pixels. The crop is the one MediaPipe's hand tracker
        takes: turned so that the wrist (keypoint 0) lies below the middle finger's
        knuckle (keypoint 2), 2.6 times the palm box, shifted half a box towards the
        fingers."""
        w, h = float(box[2] - box[0]), float(box[3] - box[1])
        angle = _upright_angle(kp[0], kp[2])
        cx = (box[0] + box[2]) / 2 + HAND_CROP_SHIFT * h * math.sin(angle)
        cy = (box[1] + box[3]) / 2 - HAND_CROP_SHIFT * h * math.cos(angle)
        rect = RotatedRect(float(cx), float(cy), max(HAND_CROP_SCALE * max(w, h), 8.0), angle)
        out = self._hand(to_range(rect.crop(rgb, HAND_PX), 0.0, 1.0))
        return float(out[1].reshape(-1)[0])

    def _part(
        self,
        kind: str,
        score: float,
        box: np.ndarray,
        seg: Callable[[], np.ndarray],
        w: int,
        h: int,
    ) -> Body:
        x0, y0 = max(0.0, float(box[0])), max(0.0, float(box[1]))
        x1, y1 = min(float(w), float(box[2])), min(float(h), float(box[3]))
        region = np.zeros((h, w), np.uint8)
        region[int(y0) : math.ceil(y1), int(x0) : math.ceil(x1)] = 1
        mask = (seg() > self.params.mask_threshold) & (region > 0)
        cues = {kind}
        box_area = max(1.0, (x1 - x0) * (y1 - y0))
        if mask.sum() >= self.params.min_part_mask_share * box_area:
            cues.add("mask")
            body = self._attached_body(seg(), mask, box_area)
            if body is not None:
                # The part belongs to a body the person detector missed (too near, cut
                # by the frame): the body is what is visible, not the part alone.
                bx0, by0, bx1, by1 = bbox(body)
                return Body(
                    score, cues, body.astype(np.uint8), body, None,
                    np.array([(bx0 + bx1) / 2, (by0 + by1) / 2]), (bx0, by0, bx1, by1),
                )  # fmt: skip
        else:
            mask = region > 0  # the part's box is what is seen of it
        extent = max(x1 - x0, y1 - y0)
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        return Body(score, cues, region, mask, None, centre, (x0, y0, x1, y1), kind, extent)

    def _attached_body(
        self, seg: np.ndarray, part_mask: np.ndarray, box_area: float
    ) -> np.ndarray | None:
        """The person-mask region connected to a part, when it is much larger than the
        part (an arm and more, not a hand alone); else None."""
        person = (seg > self.params.mask_threshold).astype(np.uint8)
        _n, labels = cv2.connectedComponents(person, connectivity=8)
        ids = np.unique(labels[part_mask])
        ids = ids[ids > 0]
        if len(ids) == 0:
            return None
        body = np.isin(labels, ids)
        if body.sum() < self.params.attached_body_share * box_area:
            return None
        return body

    def _own_extent_area(self, b: Body) -> float:
        """A whole body's pixels from the body's own extent (images without geometry)."""
        p = self.params
        if b.points is not None:
            pts = b.points
            head = pts[0]
            mid_sh = pts[list(SHOULDERS)].mean(axis=0)
            mid_hip = pts[list(HIPS)].mean(axis=0)
            knees = pts[list(KNEES)].mean(axis=0)
            ankles = pts[list(ANKLES)].mean(axis=0)
            chain = [head, mid_sh, mid_hip, knees, ankles]
            length = sum(float(np.hypot(*(a - c))) for a, c in itertools.pairwise(chain))
            length *= 1.12  # crown above the nose, soles below the ankles
        elif b.part == "face":
            length = b.part_extent_px / FACE_HEIGHT_SHARE
        elif b.part == "hand":
            length = b.part_extent_px / HAND_LENGTH_SHARE
        else:
            x0, y0, x1, y1 = b.box
            length = max(x1 - x0, y1 - y0)
        return max(1.0, length * length * BODY_WIDTH_SHARE * p.silhouette_fill)

    def _detection(
        self, b: Body, geometry: FrameGeometry | None, t_mono_s: float, w: int, h: int
    ) -> Detection | None:
        x0, y0 = max(0.0, b.box[0]), max(0.0, b.box[1])
        x1, y1 = min(float(w), b.box[2]), min(float(h), b.box[3])
        if x1 - x0 < 1.0 or y1 - y0 < 1.0:
            return None
        u, v, heading, whole_uv = floor_pixel(b, geometry, self.params.floor, w, h)
        # No pixel of mask: a person fills about half of its box (as dnn/hog assume).
        visible = float(b.mask.sum()) if b.mask.any() else 0.5 * (x1 - x0) * (y1 - y0)
        seen = None if b.seen_share is None else max(b.seen_share, self.params.seen_share_floor)
        return Detection(
            t_mono_s=t_mono_s,
            u_px=u,
            v_px=v,
            bbox_xywh_px=(
                int(x0),
                int(y0),
                max(1, round(x1 - x0)),
                max(1, round(y1 - y0)),
            ),
            visible_area_px=visible,
            score=float(min(1.0, max(0.0, b.score))),
            source=self.name,
            cues=tuple(sorted(b.cues)),
            expected_area_px=self._own_extent_area(b),
            body_heading_rad=heading,
            seen_share_max=seen,
            whole_uv_px=whole_uv,
        )
