"""Evidence pictures in chunks (mavlink_io/picture.py): the sizes that fit TUNNEL,
reassembly under loss, reordering, duplicates and corruption, and the sender's
rounds, acknowledgements and polls."""

from __future__ import annotations

import random

import pytest

from mavlink_io import dialect, picture, tunnel
from mavlink_io.codec import Codec
from mavlink_io.picture import (
    CHUNK_BYTES,
    MAX_PICTURE_BYTES,
    RESULT_PARTIAL,
    RESULT_STORED,
    Ack,
    BadChunk,
    Chunk,
    Reassembly,
    Transfer,
)
from mavlink_io.signing import Signing


def _jpeg(size: int, seed: int = 1) -> bytes:
    body = random.Random(seed).randbytes(size - 4)
    return b"\xff\xd8" + body + b"\xff\xd9"


def test_a_signed_full_chunk_is_exactly_one_tunnel() -> None:
    m = dialect.load()
    chunk = picture.split(7, 3, _jpeg(500))[0]
    assert len(chunk.data) == CHUNK_BYTES
    signed = Codec(1, 191, Signing(b"k" * 32, 0))
    frame = signed.encode(chunk.to_msg(m))
    assert len(frame) == tunnel.TUNNEL_PAYLOAD_BYTES  # fits, with nothing to spare
    env = tunnel.wrap(signed, chunk.to_msg(m))
    inner = tunnel.unpack_tunnel(env, Codec(245, 190, Signing(b"k" * 32, 0)))
    assert inner is not None
    assert Chunk.from_msg(inner) == chunk


def test_split_and_join_round_trip_through_the_codec() -> None:
    m = dialect.load()
    data = _jpeg(1000)
    enc, dec = Codec(1, 191), Codec(245, 190)
    chunks = picture.split(9, 4, data)
    assert len(chunks) == picture.chunk_count(1000) == 12
    assert len(chunks[-1].data) == 1000 - 11 * CHUNK_BYTES
    r = Reassembly.starting(chunks[0])
    for c in chunks:
        (msg,) = dec.feed(enc.encode(c.to_msg(m)))
        assert r.add(Chunk.from_msg(msg))
    assert r.complete
    assert r.jpeg() == data


def test_reassembly_with_loss_reorder_and_duplicates() -> None:
    rng = random.Random(5)
    data = _jpeg(5000)
    chunks = picture.split(11, 2, data)
    r = Reassembly.starting(chunks[0])
    arrivals = [c for c in chunks for _ in range(2) if rng.random() > 0.3]  # lost and repeated
    rng.shuffle(arrivals)
    fresh = sum(r.add(c) for c in arrivals)
    assert fresh == len(r.received) < len(chunks)  # duplicates are not counted twice
    assert not r.complete
    with pytest.raises(BadChunk, match="chunks"):
        r.jpeg()
    for c in chunks:
        r.add(c)
    assert r.jpeg() == data


def test_inconsistent_and_corrupt_chunks_are_refused() -> None:
    data = _jpeg(300)
    chunks = picture.split(12, 2, data)
    r = Reassembly.starting(chunks[0])
    other = picture.split(12, 2, _jpeg(300, seed=2))[1]  # same ID, another picture
    with pytest.raises(BadChunk, match="crc32"):
        r.add(other)
    with pytest.raises(BadChunk, match="victim_id"):
        r.add(picture.split(12, 3, data)[1])
    # Chunks that agree on the CRC but carry other bytes: caught when joined.
    bad = Chunk(12, 2, chunks[1].crc32, 300, 1, bytes(len(chunks[1].data)))
    for c in [chunks[0], bad, *chunks[2:]]:
        r.add(c)
    with pytest.raises(BadChunk, match="CRC-32"):
        r.jpeg()
    # A whole picture that is not a JPEG.
    junk = b"not a jpeg at all" * 10
    r2 = Reassembly.starting(picture.split(13, 2, junk)[0])
    for c in picture.split(13, 2, junk):
        r2.add(c)
    with pytest.raises(BadChunk, match="not a JPEG"):
        r2.jpeg()


class _Fields:
    """A decoded message's attributes, as a hostile robot could set them."""

    def __init__(self, **kw: object) -> None:
        base = dict(picture_id=1, victim_id=1, crc32=0, size=100, chunk_index=0, flags=0,
                    length=86, data=[0] * 86)  # fmt: skip
        base.update(kw)
        self.__dict__.update(base)


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"picture_id": 0}, "picture_id"),
        ({"victim_id": 0}, "victim_id"),
        ({"size": 0}, "size"),
        ({"size": MAX_PICTURE_BYTES + 1}, "size"),
        ({"chunk_index": 2}, "chunk_index"),
        ({"length": 0}, "length"),
        ({"length": 87}, "length"),
        ({"length": 14}, "should be 86"),  # not the last chunk: must be full
        ({"chunk_index": 1, "length": 86}, "should be 14"),  # the last: 100 - 86
        ({"flags": 0x80}, "flags"),
    ],
)
def test_every_field_is_checked(fields: dict[str, int], words: str) -> None:
    with pytest.raises(BadChunk, match=words):
        Chunk.from_msg(_Fields(**fields))


def test_bitmap_round_trip() -> None:
    marked = {0, 7, 8, 100, 255}
    assert picture.from_bitmap(bytes(picture.to_bitmap(marked)), 256) == frozenset(marked)
    assert picture.from_bitmap(bytes(picture.to_bitmap(marked)), 101) == frozenset({0, 7, 8, 100})


def _run(loss: float, seed: int, size: int = 6000) -> tuple[Transfer, int, float]:
    """A transfer over a channel that loses ``loss`` of the chunks and of the acks,
    one chunk every 0.1 s and acks 0.3 s later; returns it, chunks sent, seconds."""
    rng = random.Random(seed)
    data = _jpeg(size, seed)
    t = Transfer(21, 5, data, initial_wait_s=1.0, max_wait_s=4.0)
    r: Reassembly | None = None
    stored = False
    acks: list[tuple[float, Ack]] = []
    now = 0.0
    while not t.done and now < 600.0:
        for due, ack in [a for a in acks if a[0] <= now]:
            acks.remove((due, ack))
            t.on_ack(ack)
        chunk = t.next_chunk(now)
        if chunk is not None and rng.random() >= loss:
            r = r or Reassembly.starting(chunk)
            r.add(chunk)
            if r.complete and not stored:
                assert r.jpeg() == data
                stored = True
            if stored or chunk.ack_request:
                result = RESULT_STORED if stored else RESULT_PARTIAL
                if rng.random() >= loss:
                    bitmap = bytes(picture.to_bitmap(r.received))
                    acks.append((now + 0.3, Ack(21, result, bitmap)))
        now += 0.1
    return t, t.chunks_sent, now


def test_transfer_without_loss_sends_each_chunk_once() -> None:
    t, sent, _ = _run(0.0, 1)
    assert t.result == RESULT_STORED
    assert sent == len(t.chunks) and t.rounds == 1


@pytest.mark.parametrize("seed", range(5))
def test_transfer_at_ten_percent_loss_finishes_with_little_overhead(seed: int) -> None:
    t, sent, seconds = _run(0.10, seed)
    assert t.result == RESULT_STORED
    # About 1/(1 - loss) chunks per chunk, plus a poll or two for lost acks.
    assert sent <= len(t.chunks) * 1.35 + 4, (sent, len(t.chunks))
    assert seconds < len(t.chunks) * 0.1 * 1.35 + 10


def test_transfer_at_heavy_loss_still_finishes() -> None:
    t, _, _ = _run(0.5, 3, size=2000)
    assert t.result == RESULT_STORED


def test_a_lost_ack_costs_one_chunk_not_a_round() -> None:
    t = Transfer(3, 1, _jpeg(400), initial_wait_s=1.0, max_wait_s=4.0)
    first = [t.next_chunk(0.0) for _ in range(len(t.chunks))]
    assert [c.ack_request for c in first if c] == [False] * 4 + [True]
    assert t.next_chunk(0.5) is None  # waiting for the answer
    poll = t.next_chunk(1.0)
    assert poll is not None and poll.ack_request and poll.index == 4
    assert t.next_chunk(2.0) is None  # the wait doubled
    assert t.seconds_until_due(2.0) == pytest.approx(1.0)
    t.on_ack(Ack(3, RESULT_PARTIAL, bytes(picture.to_bitmap({0, 1, 3}))))
    again = [t.next_chunk(2.1), t.next_chunk(2.2)]
    assert [(c.index, c.ack_request) for c in again if c] == [(2, False), (4, True)]
    t.on_ack(Ack(99, RESULT_STORED, bytes(32)))  # another picture's: ignored
    assert not t.done
    t.on_ack(Ack(3, RESULT_STORED, bytes(32)))
    assert t.done and t.next_chunk(10.0) is None and t.seconds_until_due(10.0) is None


def test_a_thermal_picture_says_its_kind_and_still_fits_one_tunnel() -> None:
    from fusion.types import Sensor

    m = dialect.load()
    data = _jpeg(700, seed=4)
    signed = Codec(1, 191, Signing(b"k" * 32, 0))
    hq = Codec(245, 190, Signing(b"k" * 32, 0))
    chunks = picture.split(21, 5, data, Sensor.THERMAL)
    assert len(signed.encode(chunks[0].to_msg(m))) == tunnel.TUNNEL_PAYLOAD_BYTES
    r: Reassembly | None = None
    for c in chunks:
        inner = tunnel.unpack_tunnel(tunnel.wrap(signed, c.asking().to_msg(m)), hq)
        assert inner is not None
        got = Chunk.from_msg(inner)
        assert got.kind is Sensor.THERMAL and got.ack_request
        r = r or Reassembly.starting(got)
        r.add(got)
    assert r is not None and r.kind is Sensor.THERMAL and r.jpeg() == data
    # A picture sent before the flag existed (flags 0) is the colour camera's.
    (plain,) = hq.feed(Codec(1, 191).encode(picture.split(22, 5, data)[0].to_msg(m)))
    assert Chunk.from_msg(plain).kind is Sensor.COLOUR
    # One picture ID cannot be both kinds.
    with pytest.raises(BadChunk, match="kind"):
        r.add(picture.split(21, 5, data)[1])
    # The sender keeps the kind in every round, the asking chunk included.
    t = Transfer(23, 5, data, kind=Sensor.THERMAL)
    sent = [c for c in iter(lambda: t.next_chunk(0.0), None)]
    assert sent and all(c.kind is Sensor.THERMAL for c in sent) and sent[-1].ack_request
