"""Evidence pictures: each confirmed victim's best view, chosen and sent to rescue-hq.

``PictureChooser`` (processing thread) looks at every frame's located detections:
the one that belongs to a confirmed victim (the nearest inside the chi-square 99 %
gate of the victim's and the observation's covariances) is scored

    score = detection score x visible share (at least 1 %) x s / (s + SHARPNESS_HALF)

with s the variance of the Laplacian of the crop (sharp, well-lit views score
high; motion blur and darkness low). A view becomes the victim's picture when the
victim has none, or when it scores ``min_gain`` more than the kept one and
``min_interval_s`` has passed: then (only then: the score is cheap, encoding is not)
it is cropped around the victim's box with half the box of context on each side,
boxes drawn, scaled to ``width_px`` and encoded as a JPEG of at most ``max_bytes``
(lower quality first, then a smaller scale). The ledger (companion/storage/ledger.py)
commits it with the frame's state and calls ``keep`` after the commit.

A victim the thermal camera sees gets a second picture, its thermal view, chosen
the same way among the thermal frames (``consider_thermal``: the sharpness of the
crop's temperatures scaled to its colour range): the crop in false colour
(companion.vision.thermal_picture, as ``detect --annotate`` draws it), enlarged to
``width_px`` with whole sensor pixels, the box drawn, its temperature scale beside
it. Each kind (fusion.types.Sensor) is kept and replaced on its own.

``PictureSender`` (reporter thread) sends the kept pictures that the HQ does not
have, one at a time, oldest first (a newer picture of the victim, of the same kind,
being sent replaces it), as mavlink_io.picture transfers. A token bucket bounds the bytes a
second (``rate_bytes_s``, the frames as they leave on the radio: a chunk in TUNNEL
is 132 bytes, 158 signed); the reporter only calls ``poll`` after the reports due
went, so pictures use what is left. The processing thread hands pictures over with
``offer`` (the one lock); acknowledgements come from the link threads through the
reporter's queue to ``on_ack``; ``on_done`` (reporter thread) records delivery.

``resume`` makes both at start from what the store kept of the last run.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from companion.config import PicturesConfig
from companion.sources.thermal import ThermalFrame
from companion.storage.store import Store, StoredPicture, StoreError
from companion.vision.thermal_picture import colour_range_c, thermal_picture
from fusion.registry import Victim
from fusion.types import Detection, Observation, Sensor, TrackState, Urgency
from mavlink_io import picture

log = logging.getLogger(__name__)

SHARPNESS_HALF = 100.0  # Laplacian variance at which the sharpness term is 0.5
GATE_D2 = 9.21  # chi-square, 2 degrees of freedom, 99 %: the observation is the victim's
_CONTEXT = 0.5  # context around the box, in box sizes on each side
_MIN_CONTEXT_PX = 24
_QUALITIES = (80, 65, 50, 38, 28, 20)  # JPEG quality tried in turn
_SHRINK = 0.8  # then the scale, by this factor at a time
_MIN_WIDTH_PX = 32
_BGR = {
    Urgency.CRITICAL: (40, 40, 230),
    Urgency.MEDIUM: (0, 165, 255),
    Urgency.LIGHT: (60, 200, 60),
}
_OTHER_BGR = (255, 255, 0)
# A chunk's bytes on the radio inside TUNNEL: the envelope's MAVLink 2 header and CRC
# (12), TUNNEL's own fields (5), the inner frame's header and CRC (12), the chunk's
# fields before the data (17); each frame signed adds 13.
_TUNNEL_OVERHEAD = 12 + 5 + 12 + 17
_SIGNATURE = 13


def chunk_wire_bytes(data_bytes: int, signed: bool) -> int:
    """The bytes one chunk takes on the radio, in a TUNNEL."""
    return _TUNNEL_OVERHEAD + data_bytes + (2 * _SIGNATURE if signed else 0)


def sharpness(gray: np.ndarray) -> float:
    """Variance of the Laplacian (focus measure): blur and darkness make it small."""
    return float(cv2.Laplacian(gray, cv2.CV_64F).var())


def view_score(detection_score: float, visibility_pct: float, sharp: float) -> float:
    visible = max(visibility_pct, 1.0) / 100.0
    return detection_score * visible * sharp / (sharp + SHARPNESS_HALF)


def crop_box(
    bbox_xywh: tuple[int, int, int, int], width_px: int, height_px: int
) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the box with context, inside the image."""
    x, y, w, h = bbox_xywh
    mx = max(_MIN_CONTEXT_PX, round(_CONTEXT * w))
    my = max(_MIN_CONTEXT_PX, round(_CONTEXT * h))
    x0, y0 = max(0, x - mx), max(0, y - my)
    x1, y1 = min(width_px, x + w + mx), min(height_px, y + h + my)
    return x0, y0, max(x0 + 1, x1), max(y0 + 1, y1)


def render(
    image: np.ndarray,
    target: Detection,
    others: Sequence[Detection],
    victim: Victim,
    width_px: int,
    max_bytes: int,
) -> bytes:
    """The JPEG of the victim's view: cropped, boxes drawn, at most ``max_bytes``.
    ValueError when even the smallest scale at the lowest quality is too big."""
    bgr = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    h, w = bgr.shape[:2]
    x0, y0, x1, y1 = crop_box(target.bbox_xywh_px, w, h)
    crop = bgr[y0:y1, x0:x1].copy()
    for det in others:
        bx, by, bw, bh = det.bbox_xywh_px
        cv2.rectangle(crop, (bx - x0, by - y0), (bx + bw - x0, by + bh - y0), _OTHER_BGR, 1)
    bx, by, bw, bh = target.bbox_xywh_px
    colour = _BGR[victim.urgency]
    cv2.rectangle(crop, (bx - x0, by - y0), (bx + bw - x0, by + bh - y0), colour, 2)
    scale = min(1.0, width_px / crop.shape[1]) if crop.shape[1] > width_px else 1.0
    return _encode(crop, scale, f"V{victim.victim_id} {victim.urgency.name}", colour, max_bytes)


def render_thermal(
    temps_c: np.ndarray,
    target: Detection,
    others: Sequence[Detection],
    victim: Victim,
    width_px: int,
    max_bytes: int,
) -> bytes:
    """The JPEG of the victim's thermal view: the crop in false colour, enlarged to at
    least ``width_px`` in whole sensor pixels, boxes drawn, the temperature scale on
    the right; at most ``max_bytes`` (smaller when it must; ValueError when even the
    smallest does not fit)."""
    h, w = temps_c.shape
    x0, y0, x1, y1 = crop_box(target.bbox_xywh_px, w, h)
    colour = _BGR[victim.urgency]
    boxes = [
        ((d.bbox_xywh_px[0] - x0, d.bbox_xywh_px[1] - y0, *d.bbox_xywh_px[2:]), "", _OTHER_BGR)
        for d in others
    ]
    bx, by, bw, bh = target.bbox_xywh_px
    peak = float(temps_c[by : by + bh, bx : bx + bw].max()) if bw > 0 and bh > 0 else float("nan")
    label = f"{peak:.1f}C" if math.isfinite(peak) else ""
    boxes.append(((bx - x0, by - y0, bw, bh), label, colour))
    view = thermal_picture(temps_c[y0:y1, x0:x1], boxes, min_width_px=width_px)
    label = f"V{victim.victim_id} {victim.urgency.name} warm"
    return _encode(view, 1.0, label, colour, max_bytes)


def _encode(
    view: np.ndarray, scale: float, label: str, colour: tuple[int, int, int], max_bytes: int
) -> bytes:
    """The JPEG of ``view`` with ``label``, at ``scale`` or smaller, of at most ``max_bytes``."""
    while True:
        size = (max(1, round(view.shape[1] * scale)), max(1, round(view.shape[0] * scale)))
        small = cv2.resize(view, size, interpolation=cv2.INTER_AREA) if scale != 1.0 else view
        small = small.copy()
        cv2.putText(small, label, (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3)
        cv2.putText(small, label, (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1)
        for quality in _QUALITIES:
            ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
            if ok and len(buf) <= max_bytes:
                return bytes(buf)
        if size[0] <= _MIN_WIDTH_PX:
            raise ValueError(f"no JPEG of {label} fits {max_bytes} bytes")
        scale *= _SHRINK


@dataclass(frozen=True)
class Candidate:
    """A new picture for a victim, to be committed (its picture_id is given then)."""

    victim_id: int
    score: float
    taken_unix_s: float
    jpeg: bytes
    kind: Sensor = Sensor.COLOUR


def _d2(victim: Victim, obs: Observation) -> float:
    """Squared Mahalanobis distance of the observation from the victim."""
    (a, b), (_, d) = victim.cov_ne_m2
    (oa, ob), (_, od) = obs.cov_ne_m2
    s = np.array([[a + oa, b + ob], [b + ob, d + od]])  # S = P_victim + R_obs
    r = np.array([obs.north_m - victim.north_m, obs.east_m - victim.east_m])
    return float(r @ np.linalg.solve(s, r))  # rᵀ S⁻¹ r


def match(
    victims: Sequence[Victim], located: Sequence[tuple[Detection, Observation]]
) -> list[tuple[Victim, Detection, Observation]]:
    """Each confirmed victim with the located detection that is its view (nearest in
    the gate; one detection per victim and one victim per detection)."""
    pairs = sorted(
        (d2, i, j)
        for i, v in enumerate(victims)
        if v.state == TrackState.CONFIRMED
        for j, (_, obs) in enumerate(located)
        if (d2 := _d2(v, obs)) < GATE_D2
    )
    used_v: set[int] = set()
    used_d: set[int] = set()
    out = []
    for _, i, j in pairs:
        if i in used_v or j in used_d:
            continue
        used_v.add(i)
        used_d.add(j)
        out.append((victims[i], located[j][0], located[j][1]))
    return out


class PictureChooser:
    """Keeps each victim's best view of each kind. Owned by the processing thread."""

    def __init__(self, cfg: PicturesConfig, kept: Sequence[StoredPicture] = ()) -> None:
        self.cfg = cfg
        self._kept = {(p.victim_id, p.kind): (p.score, p.taken_unix_s) for p in kept}
        self.rendered = 0
        self.too_big = 0

    def consider(
        self,
        image: np.ndarray,
        located: Sequence[tuple[Detection, Observation]],
        victims: Sequence[Victim],
        now_unix_s: float,
    ) -> list[Candidate]:
        """New colour pictures this frame gives (not yet kept: call ``keep`` after the commit)."""

        def crop_grey(region: np.ndarray) -> np.ndarray:
            return region if region.ndim == 2 else cv2.cvtColor(region, cv2.COLOR_BGR2GRAY)

        return self._choose(image, located, victims, now_unix_s, Sensor.COLOUR, crop_grey, render)

    def consider_thermal(
        self,
        frame: ThermalFrame,
        located: Sequence[tuple[Detection, Observation]],
        victims: Sequence[Victim],
    ) -> list[Candidate]:
        """New thermal pictures this thermal frame gives (call ``keep`` after the commit)."""
        lo, hi = colour_range_c(frame.temps_c)

        def crop_grey(region: np.ndarray) -> np.ndarray:
            # The temperatures on the picture's colour scale: sharpness in its grey levels.
            return np.clip((region - lo) * (255.0 / (hi - lo)), 0.0, 255.0).astype(np.uint8)

        return self._choose(
            frame.temps_c,
            located,
            victims,
            frame.t_unix_s,
            Sensor.THERMAL,
            crop_grey,
            render_thermal,
        )

    def _choose(
        self,
        image: np.ndarray,
        located: Sequence[tuple[Detection, Observation]],
        victims: Sequence[Victim],
        now_unix_s: float,
        kind: Sensor,
        crop_grey: Callable[[np.ndarray], np.ndarray],
        draw: Callable[[np.ndarray, Detection, Sequence[Detection], Victim, int, int], bytes],
    ) -> list[Candidate]:
        out = []
        detections = [d for d, _ in located]
        for victim, det, obs in match(victims, located):
            kept = self._kept.get((victim.victim_id, kind))
            if kept is not None and now_unix_s - kept[1] < self.cfg.min_interval_s:
                continue
            x0, y0, x1, y1 = crop_box(det.bbox_xywh_px, image.shape[1], image.shape[0])
            score = view_score(
                det.score, obs.visibility_pct, sharpness(crop_grey(image[y0:y1, x0:x1]))
            )
            if not math.isfinite(score) or score <= 0.0:
                continue
            if kept is not None and score <= kept[0] * (1.0 + self.cfg.min_gain):
                continue
            others = [d for d in detections if d is not det]
            try:
                jpeg = draw(image, det, others, victim, self.cfg.width_px, self.cfg.max_bytes)
            except ValueError as exc:
                self.too_big += 1
                log.debug("%s", exc)
                continue
            self.rendered += 1
            out.append(Candidate(victim.victim_id, score, now_unix_s, jpeg, kind))
        return out

    def keep(self, c: Candidate) -> None:
        self._kept[(c.victim_id, c.kind)] = (c.score, c.taken_unix_s)


@dataclass
class SenderCounters:
    offered: int = 0
    delivered: int = 0  # the HQ said STORED
    rejected: int = 0  # the HQ said REJECTED
    replaced: int = 0  # a newer picture of the victim came while sending
    chunks: int = 0
    bytes: int = 0  # on the radio, as chunk_wire_bytes counts them


class PictureSender:
    """Sends kept pictures at a bounded rate until the HQ has them. ``poll``,
    ``on_ack`` and ``seconds_until_due`` on the reporter thread; ``offer`` anywhere."""

    def __init__(
        self,
        cfg: PicturesConfig,
        send: Callable[[picture.Chunk], None],
        on_done: Callable[[int, int, int], None],
        *,
        signed: bool = False,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.rate_bytes_s = cfg.rate_bytes_s
        self._send = send
        self._on_done = on_done
        self._signed = signed
        self._clock = clock
        self._lock = threading.Lock()
        self._waiting: dict[tuple[int, Sensor], StoredPicture] = {}  # by victim and kind
        self._current: picture.Transfer | None = None
        self._started_s = 0.0  # when the current transfer began
        # Never two chunks at once (the bucket holds less than two): a report waits
        # behind at most one chunk in a radio's buffer (23 ms at 57,600 baud); what a
        # late poll earned beyond one chunk is kept, so the rate is still met.
        self._capacity = 2.0 * chunk_wire_bytes(picture.CHUNK_BYTES, signed) - 1.0
        self._tokens = self._capacity
        self._last_s = clock()
        self.counters = SenderCounters()

    @property
    def pending(self) -> int:
        with self._lock:
            return len(self._waiting) + (1 if self._current is not None else 0)

    def offer(self, p: StoredPicture) -> None:
        """Send ``p`` (replacing a waiting or unfinished older picture of its victim
        and kind)."""
        with self._lock:
            held = self._waiting.get((p.victim_id, p.kind))
            if held is None or held.picture_id < p.picture_id:
                self._waiting[(p.victim_id, p.kind)] = p
                self.counters.offered += 1

    def on_ack(self, ack: picture.Ack) -> None:
        t = self._current
        if t is None or ack.picture_id != t.picture_id:
            return
        t.on_ack(ack)
        if t.done:
            self._finish(t)

    def _finish(self, t: picture.Transfer) -> None:
        self._current = None
        if t.result == picture.RESULT_STORED:
            self.counters.delivered += 1
            log.info(
                "%s picture %d of victim %d delivered in %.1f s (%d bytes, %d chunks sent for %d)",
                t.kind,
                t.picture_id,
                t.victim_id,
                self._clock() - self._started_s,
                t.size,
                t.chunks_sent,
                len(t.chunks),
            )
        else:
            self.counters.rejected += 1
            log.warning("picture %d of victim %d REJECTED by the HQ", t.picture_id, t.victim_id)
        self._on_done(t.victim_id, t.picture_id, t.result or 0)

    def _next_transfer(self) -> picture.Transfer | None:
        with self._lock:
            cur = self._current
            if cur is not None:
                newer = self._waiting.get((cur.victim_id, cur.kind))
                if newer is None or newer.picture_id <= cur.picture_id:
                    return cur
                self.counters.replaced += 1
            elif not self._waiting:
                return None
            else:
                newer = min(self._waiting.values(), key=lambda p: p.picture_id)
            del self._waiting[(newer.victim_id, newer.kind)]
        self._current = picture.Transfer(
            newer.picture_id, newer.victim_id, newer.jpeg, kind=newer.kind
        )
        self._started_s = self._clock()
        return self._current

    def _refill(self, now: float) -> None:
        self._tokens = min(self._capacity, self._tokens + (now - self._last_s) * self.rate_bytes_s)
        self._last_s = now

    def poll(self) -> None:
        """Send the chunks the rate allows now."""
        now = self._clock()
        self._refill(now)
        while (t := self._next_transfer()) is not None:
            cost = chunk_wire_bytes(picture.CHUNK_BYTES, self._signed)
            if self._tokens < cost:
                return
            chunk = t.next_chunk(now)
            if chunk is None:
                return
            self._tokens -= chunk_wire_bytes(len(chunk.data), self._signed)
            self.counters.chunks += 1
            self.counters.bytes += chunk_wire_bytes(len(chunk.data), self._signed)
            self._send(chunk)

    def seconds_until_due(self) -> float | None:
        """When ``poll`` may send next (None: nothing to send)."""
        t = self._next_transfer()
        if t is None:
            return None
        now = self._clock()
        due = t.seconds_until_due(now)
        if due is None:
            return None
        self._refill(now)
        lack = chunk_wire_bytes(picture.CHUNK_BYTES, self._signed) - self._tokens
        return max(due, lack / self.rate_bytes_s if lack > 0 else 0.0)


def resume(
    cfg: PicturesConfig, store: Store, send: Callable[[picture.Chunk], None], *, signed: bool
) -> tuple[PictureChooser, PictureSender]:
    """The evidence pictures: those kept before a restart are known (not chosen
    again unless clearly better), and those the HQ does not have are sent. The
    sender records each delivery in ``store``."""
    kept: list[StoredPicture] = []
    try:
        kept = store.pictures()
    except StoreError as exc:
        log.warning("evidence pictures of the last run unusable, starting without: %s", exc)

    def done(victim_id: int, picture_id: int, _result: int) -> None:
        """Reporter thread: the HQ has the picture (or refused it): never resend it."""
        try:
            store.picture_delivered(victim_id, picture_id)
        except StoreError as exc:  # sent again after a restart; the HQ says STORED at once
            log.warning("delivery of picture %d not saved: %s", picture_id, exc)

    sender = PictureSender(cfg, send, done, signed=signed)
    for p in kept:
        if cfg.enabled and not p.delivered:
            sender.offer(p)
    return PictureChooser(cfg, kept), sender
