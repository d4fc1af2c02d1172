"""Evidence pictures on the companion (companion/reporting/pictures.py): which view is kept,
how it is cut and encoded, when a better one replaces it, and the sender's rate,
order and acknowledgements."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.config import PicturesConfig
from companion.reporting.pictures import (
    PictureChooser,
    PictureSender,
    chunk_wire_bytes,
    match,
    resume,
)
from companion.sources.thermal import ThermalFrame
from companion.storage.store import Store, StoredPicture
from companion.vision.thermal_picture import SCALE_BAR_PX
from fusion.registry import Victim
from fusion.types import Detection, Observation, Sensor, TrackState, Urgency
from mavlink_io import picture

BOX = (260, 180, 120, 90)  # x, y, w, h of the victim in a 640x480 frame


def _victim(vid: int = 3, state: TrackState = TrackState.CONFIRMED, north: float = 5.0) -> Victim:
    return Victim(
        victim_id=vid, state=state, urgency=Urgency.MEDIUM, visibility_pct=30.0,
        north_m=north, east_m=1.0, cov_ne_m2=((0.09, 0.0), (0.0, 0.09)), observations=9,
        first_seen_unix_s=100.0, last_seen_unix_s=110.0, log_odds=3.0, merged_into=None,
    )  # fmt: skip


def _located(
    score: float = 0.8, visibility: float = 40.0, north: float = 5.1
) -> tuple[Detection, Observation]:
    x, y, w, h = BOX
    det = Detection(0.0, x + w / 2, y + h, BOX, w * h * 0.5, score)
    obs = Observation(110.0, north, 1.0, ((0.04, 0.0), (0.0, 0.04)), visibility, score, 4.0)
    return det, obs


def _frame(sharp: bool, seed: int = 1) -> np.ndarray:
    """A textured scene: sharp, or blurred as by motion."""
    rng = np.random.default_rng(seed)
    img = (rng.random((480, 640, 3)) * 255).astype(np.uint8)
    img = cv2.resize(cv2.resize(img, (160, 120)), (640, 480), interpolation=cv2.INTER_NEAREST)
    return img if sharp else cv2.GaussianBlur(img, (31, 31), 10)


def test_match_needs_a_confirmed_victim_inside_the_gate() -> None:
    loc = [_located()]
    assert [v.victim_id for v, _, _ in match([_victim()], loc)] == [3]
    assert match([_victim(state=TrackState.TENTATIVE)], loc) == []
    assert match([_victim(north=9.0)], loc) == []  # 4 m away: another person
    # Two victims, one detection: the nearer one gets it.
    got = match([_victim(1, north=5.6), _victim(2, north=5.05)], loc)
    assert [v.victim_id for v, _, _ in got] == [2]


def test_the_kept_picture_is_a_small_jpeg_of_the_victim() -> None:
    cfg = PicturesConfig(max_bytes=6000, width_px=240)
    chooser = PictureChooser(cfg)
    (c,) = chooser.consider(_frame(True), [_located()], [_victim()], 110.0)
    assert c.victim_id == 3 and c.score > 0
    assert 500 < len(c.jpeg) <= 6000
    img = cv2.imdecode(np.frombuffer(c.jpeg, np.uint8), cv2.IMREAD_COLOR)
    # The box (120 px) with half its size of context each side, scaled to 240 px.
    assert img.shape[1] == 240 and img.shape[0] == 180
    # A tight budget lowers quality and then the scale; it still fits.
    (small,) = PictureChooser(PicturesConfig(max_bytes=800)).consider(
        _frame(True), [_located()], [_victim()], 110.0
    )
    assert len(small.jpeg) <= 800


def test_only_a_clearly_better_view_replaces_and_not_too_often() -> None:
    cfg = PicturesConfig(min_gain=0.25, min_interval_s=10.0)
    chooser = PictureChooser(cfg)
    (first,) = chooser.consider(_frame(False), [_located()], [_victim()], 110.0)
    chooser.keep(first)
    # The same blurred view again, later: not better, not resent.
    assert chooser.consider(_frame(False), [_located()], [_victim()], 130.0) == []
    # A sharp view, too soon: wait.
    assert chooser.consider(_frame(True), [_located()], [_victim()], 115.0) == []
    (better,) = chooser.consider(_frame(True), [_located()], [_victim()], 125.0)
    assert better.score > first.score * 1.25
    chooser.keep(better)
    # Slightly better only (higher detection score, same view): kept as it is.
    assert chooser.consider(_frame(True), [_located(score=0.85)], [_victim()], 140.0) == []


def test_kept_pictures_survive_a_restart(tmp_path: Path) -> None:
    store = Store(tmp_path / "s.sqlite")
    chooser = PictureChooser(PicturesConfig())
    (c,) = chooser.consider(_frame(True), [_located()], [_victim()], 110.0)
    store.put_picture(StoredPicture(3, 41, c.score, c.taken_unix_s, c.jpeg))
    store.close()
    store = Store(tmp_path / "s.sqlite")
    (kept,) = store.pictures()
    assert (kept.picture_id, kept.jpeg, kept.delivered) == (41, c.jpeg, False)
    store.picture_delivered(3, 41)
    assert store.pictures()[0].delivered
    # The restarted chooser knows it: the same view is not chosen again.
    again = PictureChooser(PicturesConfig(), store.pictures())
    assert again.consider(_frame(True), [_located()], [_victim()], 500.0) == []
    store.close()


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _jpeg(size: int) -> bytes:
    return b"\xff\xd8" + bytes(size - 4) + b"\xff\xd9"


def test_sender_keeps_to_its_rate_and_finishes_on_stored() -> None:
    clock = _Clock()
    sent: list[picture.Chunk] = []
    done: list[tuple[int, int, int]] = []
    sender = PictureSender(
        PicturesConfig(rate_bytes_s=1000.0),
        sent.append,
        lambda *a: done.append(a),
        clock=clock,
    )
    sender.offer(StoredPicture(3, 10, 1.0, 0.0, _jpeg(6000)))
    for _ in range(100):  # 10 s, polled every 0.1 s
        before = len(sent)
        sender.poll()
        assert len(sent) - before <= 1  # never two chunks at once: a report waits for one
        clock.t += 0.1
    wire = sum(chunk_wire_bytes(len(c.data), False) for c in sent)
    assert wire <= 1000.0 * 10.0 + 2 * chunk_wire_bytes(86, False)
    assert wire >= 1000.0 * 9.0  # and it uses what it may
    assert len({c.index for c in sent}) == len(sent) == picture.chunk_count(6000)  # one round
    assert sent[-1].ack_request and not any(c.ack_request for c in sent[:-1])
    m = picture.Ack(10, picture.RESULT_STORED, bytes(32))
    sender.on_ack(m)
    assert done == [(3, 10, picture.RESULT_STORED)]
    assert sender.pending == 0 and sender.seconds_until_due() is None


def test_a_newer_picture_replaces_the_one_being_sent() -> None:
    clock = _Clock()
    sent: list[picture.Chunk] = []
    sender = PictureSender(
        PicturesConfig(rate_bytes_s=100_000.0), sent.append, lambda *a: None, clock=clock
    )
    sender.offer(StoredPicture(3, 10, 1.0, 0.0, _jpeg(3000)))
    sender.offer(StoredPicture(4, 11, 1.0, 0.0, _jpeg(300)))
    sender.poll()
    assert {c.picture_id for c in sent} == {10}  # the oldest first, at most a burst
    sender.offer(StoredPicture(3, 12, 2.0, 0.0, _jpeg(500)))
    clock.t += 1.0
    sent.clear()
    sender.poll()
    assert sent and {c.picture_id for c in sent} == {12}
    assert sender.counters.replaced == 1


@pytest.mark.parametrize("signed", [False, True])
def test_chunk_wire_bytes_is_what_the_tunnel_frame_takes(signed: bool) -> None:
    from mavlink_io import dialect, tunnel
    from mavlink_io.codec import Codec
    from mavlink_io.signing import Signing

    codec = Codec(1, 191, Signing(b"k" * 32, 0) if signed else None)
    jpeg = b"\xff\xd8" + np.random.default_rng(3).bytes(86 * 11 + 36) + b"\xff\xd9"
    chunks = picture.split(1, 1, jpeg)  # JPEG data is dense: no zeros to trim
    msg = dialect.load()
    for chunk in (chunks[0], chunks[-1]):
        sizes = set()
        # The signing timestamp comes from the clock. When the inner frame's signature
        # ends in a zero byte, MAVLink trims it from the TUNNEL's payload: the budget is
        # exact otherwise, and never too small.
        for timestamp in range(1_000, 1_300) if signed else (None,):
            if timestamp is not None:
                codec.mav.signing.timestamp = timestamp
            frame = codec.encode(tunnel.wrap(codec, chunk.to_msg(msg)))
            assert len(frame) <= chunk_wire_bytes(len(chunk.data), signed)
            sizes.add(len(frame))
        assert max(sizes) == chunk_wire_bytes(len(chunk.data), signed)


# -- the thermal view ------------------------------------------------------------------

T_BOX = (60, 50, 40, 24)  # x, y, w, h of a warm body in a 160x120 thermal frame


def _thermal(sharp: bool, t_unix_s: float = 110.0, seed: int = 3) -> ThermalFrame:
    """Floor at about 19 °C with a little texture and a body at 31-34 °C; blurred as
    a Lepton's view is when the rover shakes."""
    rng = np.random.default_rng(seed)
    temps = (19.0 + rng.random((120, 160)) * 0.6).astype(np.float32)
    x, y, w, h = T_BOX
    temps[y : y + h, x : x + w] = 31.0 + rng.random((h, w)).astype(np.float32) * 3.0
    if not sharp:
        temps = cv2.GaussianBlur(temps, (9, 9), 3)
    return ThermalFrame(temps, 1.0, t_unix_s, 1)


def _warm_located(score: float = 0.8) -> tuple[Detection, Observation]:
    x, y, w, h = T_BOX
    det = Detection(
        0.0, x + w / 2, y + h / 2, T_BOX, w * h, score, cues=("warm",), source="thermal"
    )
    obs = Observation(110.0, 5.1, 1.0, ((0.04, 0.0), (0.0, 0.04)), 40.0, score, 4.0)
    return det, obs


def test_a_warm_victim_gets_a_false_colour_thermal_picture_with_its_scale() -> None:
    cfg = PicturesConfig(max_bytes=6000, width_px=240)
    chooser = PictureChooser(cfg)
    (c,) = chooser.consider_thermal(_thermal(True), [_warm_located()], [_victim()])
    assert c.kind is Sensor.THERMAL and c.victim_id == 3 and c.taken_unix_s == 110.0
    assert 500 < len(c.jpeg) <= 6000
    img = cv2.imdecode(np.frombuffer(c.jpeg, np.uint8), cv2.IMREAD_COLOR)
    # The box (40 px) with 24 px of context each side, in whole sensor pixels (x3),
    # and the temperature scale bar beside it.
    assert img.shape[1] == 88 * 3 + SCALE_BAR_PX and img.shape[0] == 72 * 3
    b, r = img[..., 0].astype(int), img[..., 2].astype(int)
    body = (slice(24 * 3 + 6, 48 * 3 - 6), slice(24 * 3 + 6, 64 * 3 - 6))
    floor = (slice(72 * 3 - 20, 72 * 3 - 4), slice(4, 40))
    assert r[body].mean() > 150 and r[floor].mean() < 80  # inferno: warm bright, cold dark
    assert abs(r - b).mean() > 20  # false colour, not grey
    bar = img[:, -SCALE_BAR_PX:]
    assert bar[30:-20, 8:20, 2].mean() > 60  # the colour ramp is drawn
    # The colour picture of the same victim is chosen on its own: both are kept.
    (colour,) = chooser.consider(_frame(True), [_located()], [_victim()], 110.0)
    assert colour.kind is Sensor.COLOUR
    chooser.keep(c)
    chooser.keep(colour)
    # A blurred thermal view later is no better; a sharper one after a blurred one is.
    assert chooser.consider_thermal(_thermal(False, 130.0), [_warm_located()], [_victim()]) == []
    blurred_first = PictureChooser(cfg)
    (first,) = blurred_first.consider_thermal(_thermal(False), [_warm_located()], [_victim()])
    blurred_first.keep(first)
    (better,) = blurred_first.consider_thermal(
        _thermal(True, 125.0), [_warm_located()], [_victim()]
    )
    assert better.score > first.score * 1.25


def test_both_kinds_are_stored_resumed_and_sent_without_replacing_each_other(
    tmp_path: Path,
) -> None:
    store = Store(tmp_path / "s.sqlite")
    store.put_picture(StoredPicture(3, 41, 1.0, 100.0, _jpeg(400)))
    store.put_picture(StoredPicture(3, 42, 0.5, 101.0, _jpeg(300), kind=Sensor.THERMAL))
    store.close()
    store = Store(tmp_path / "s.sqlite")
    kept = store.pictures()
    assert [(p.picture_id, p.kind) for p in kept] == [(41, Sensor.COLOUR), (42, Sensor.THERMAL)]
    store.picture_delivered(3, 42)
    assert [p.delivered for p in store.pictures()] == [False, True]
    # Restarted: the chooser knows the thermal view too, and only the undelivered
    # colour picture is offered again.
    sent: list[picture.Chunk] = []
    chooser, sender = resume(
        PicturesConfig(rate_bytes_s=100_000.0), store, sent.append, signed=False
    )
    assert chooser.consider_thermal(_thermal(True, 105.0), [_warm_located()], [_victim()]) == []
    assert sender.pending == 1
    store.close()
    clock = _Clock()
    sent.clear()
    sender = PictureSender(
        PicturesConfig(rate_bytes_s=100_000.0), sent.append, lambda *a: None, clock=clock
    )
    sender.offer(StoredPicture(3, 50, 1.0, 0.0, _jpeg(300)))
    sender.offer(StoredPicture(3, 51, 1.0, 0.0, _jpeg(200), kind=Sensor.THERMAL))
    assert sender.pending == 2  # one of each kind: neither replaces the other
    for _ in range(20):
        sender.poll()
        for pid in {c.picture_id for c in sent if c.ack_request}:
            sender.on_ack(picture.Ack(pid, picture.RESULT_STORED, bytes(32)))
        clock.t += 0.5
    kinds = {c.picture_id: c.kind for c in sent}
    assert kinds == {50: Sensor.COLOUR, 51: Sensor.THERMAL}
    assert sender.counters.delivered == 2 and sender.counters.replaced == 0
