"""Fuzz rescue-hq's receive path and the dialect decoder with valid-CRC hostile messages.

Seeded and bounded: FUZZ_MESSAGES datagrams (default 1500, a few seconds) from
seed FUZZ_SEED (default 16); ``make fuzz`` runs 40000 with a fresh seed and prints
it. A failure names the seed, so it can be replayed exactly.

What must hold: the decoder returns every valid frame and never raises; every
decoded message is either turned into HQ values or refused with ``BadMessage``;
the real HQ process survives, still acknowledges a good report, stops with exit 0
and starts again on the same registry (nothing poisonous was stored).
"""

from __future__ import annotations

import os
import random
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hqproc import ACCEPTED, ACK_TIMEOUT_S, DUPLICATE, REPO, HqProcess, ack_for, hq_starter
from mavfuzz import GPS_GLOBAL_ORIGIN_ID, FrameFuzzer

from hq import wire
from hq.simrobot import SimRobot
from mavlink_io import dialect, picture
from mavlink_io.codec import Codec
from mavlink_io.dialect import RESCUE_PICTURE_CHUNK_ID, RESCUE_STATUS_ID, RESCUE_VICTIM_REPORT_ID

SEED = int(os.environ.get("FUZZ_SEED", "16"))
MESSAGES = int(os.environ.get("FUZZ_MESSAGES", "1500"))
_PACE_EVERY = 50  # datagrams sent before a short pause (the HQ's UDP buffer is finite)
_PACE_S = 0.02
_BACKLOG_S = 5.0 + MESSAGES / 200  # datagrams still queued in the HQ when the flood ends


@pytest.fixture
def start_hq(tmp_path: Path) -> Iterator[Callable[..., HqProcess]]:
    yield from hq_starter(tmp_path)


def _to_hq_values(codec: Codec, msg: object) -> None:
    """What the HQ does with a decoded message; only BadMessage may come out."""
    msg_id = msg.get_msgId()  # type: ignore[attr-defined]
    if msg.get_type() == "TUNNEL":  # type: ignore[attr-defined]
        inner = wire.unwrap_tunnel(codec, msg)
        if inner is None:
            return
        msg, msg_id = inner, inner.get_msgId()
    try:
        if msg_id == RESCUE_VICTIM_REPORT_ID:
            wire.incoming_report(msg, time.time())
        elif msg_id == RESCUE_STATUS_ID:
            wire.status_from_msg(msg)
        elif msg_id == GPS_GLOBAL_ORIGIN_ID:
            wire.origin_from_msg(msg)
        elif msg_id == RESCUE_PICTURE_CHUNK_ID:
            picture.Chunk.from_msg(msg)
    except (wire.BadMessage, picture.BadChunk):
        pass


def _acked_while_resending(robot: SimRobot, msg: object) -> int:
    """The ack result, resending like a robot does; the HQ may still work off the flood."""
    deadline = time.monotonic() + _BACKLOG_S
    while True:
        robot.send(msg)
        try:
            return int(ack_for(robot, msg.report_seq).result)  # type: ignore[attr-defined]
        except TimeoutError:
            if time.monotonic() > deadline:
                raise


def test_decoder_finds_every_valid_frame_and_never_raises() -> None:
    module = dialect.load()
    fuzz = FrameFuzzer(module, SEED)
    rng = random.Random(SEED)
    codec = Codec(245, 190, None, module)
    frames = [fuzz.next_frame() for _ in range(MESSAGES)]
    # A stream: frames with garbage between them (no start markers in it, so the
    # garbage cannot start a false frame that hides a real one).
    stream = b"".join(
        f + bytes(rng.choice(range(0xFD)) for _ in range(rng.randint(0, 12))) for f in frames
    )
    got = []
    for at in range(0, len(stream), 997):  # reads that cut frames anywhere
        got += codec.feed(stream[at : at + 997])
    assert [bytes(msg.get_msgbuf()) for msg in got] == frames, f"seed {SEED}"
    for msg in got:
        _to_hq_values(codec, msg)
    # Bit flips anywhere: still never raises, and a clean frame after them is found.
    for _ in range(MESSAGES // 10):
        f = bytearray(rng.choice(frames))
        for _ in range(rng.randint(1, 4)):
            f[rng.randrange(len(f))] ^= 1 << rng.randrange(8)
        out = codec.feed(bytes(f))
        codec.reset()
        for msg in out:
            _to_hq_values(codec, msg)
    clean = frames[0]
    assert [bytes(m.get_msgbuf()) for m in codec.feed(bytes(5) + clean)] == [clean]


def test_hq_survives_fuzz_and_still_acknowledges(start_hq, tmp_path: Path) -> None:
    hq = start_hq()
    fuzz = FrameFuzzer(dialect.load(), SEED)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    try:
        for n in range(MESSAGES):
            sock.sendto(fuzz.datagram(), hq.address)
            if n % _PACE_EVERY == 0:
                time.sleep(_PACE_S)
                assert hq.proc.poll() is None, f"seed {SEED}: rescue-hq died: {hq.stderr[-5:]}"
    finally:
        sock.close()
    with SimRobot(200, hq.address) as robot:  # a sysid the fuzzer rarely uses
        good = robot.report_msg(robot.victim(1, 1.0, 1.0))
        assert _acked_while_resending(robot, good) == ACCEPTED, f"seed {SEED}"
        jpeg = b"\xff\xd8" + bytes(range(256)) * 2 + b"\xff\xd9"
        chunks = picture.split(77, 1, jpeg)
        for c in chunks[:-1]:
            robot.send(c.to_msg(robot.codec.module))
        robot.send(chunks[-1].asking().to_msg(robot.codec.module))
        ack = robot.wait_for("RESCUE_PICTURE_ACK", ACK_TIMEOUT_S, picture_id=77).msg
        assert ack.result == picture.RESULT_STORED, f"seed {SEED}"
    assert hq.stop() == 0, f"seed {SEED}: {hq.stderr[-5:]}"
    assert not any("Traceback" in line for line in hq.stderr), f"seed {SEED}"
    # Whatever was stored must not poison the next start or the tools.
    hq2 = start_hq(db=hq.db)
    with SimRobot(200, hq2.address) as robot:
        robot.send(good)
        assert ack_for(robot, good.report_seq).result == DUPLICATE
    assert hq2.stop() == 0
    for command in (["list"], ["export", "--out", str(tmp_path / "out")]):
        result = subprocess.run(
            [sys.executable, "-m", "hq.cli", *command, "--db", str(hq.db)],
            cwd=REPO, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
