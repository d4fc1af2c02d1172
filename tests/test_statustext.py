"""STATUSTEXT as a stock QGroundControl reads it: one chunk when it fits, word
boundaries, no empty trailing chunk, a severity QGC speaks only for real news.

``qgc_reassemble`` follows QGC's StatusTextHandler: an unchunked text (id 0) is
complete; chunks with one id are appended in chunk_seq order, a missing one shown
as " ... ", and a chunk shorter than 50 bytes completes the text; an empty chunk
is shown as " ... " too. QGC's message list is HTML, where runs of spaces show as
one.
"""

from __future__ import annotations

import random
import re
from typing import Any

import pytest

from fusion.types import TrackState, Urgency, VictimReport
from mavlink_io import statustext
from mavlink_io.codec import Codec


def report(**kw: object) -> VictimReport:
    base: dict[str, object] = dict(
        victim_id=7,
        robot_sysid=2,
        state=TrackState.CONFIRMED,
        urgency=Urgency.CRITICAL,
        visibility_pct=8.0,
        north_m=12.34,
        east_m=4.5,
        down_m=0.1,
        cov_ne_m2=((0.04, 0.01), (0.01, 0.09)),
        observations=7,
        first_seen_unix_s=1.7e9,
        last_seen_unix_s=1.7e9 + 5,
    )
    base.update(kw)
    return VictimReport(**base)  # type: ignore[arg-type]


def qgc_reassemble(msgs: list[Any]) -> list[str]:
    """The texts QGC's message list shows for these STATUSTEXTs from one component."""
    shown: list[str] = []
    pending: tuple[int, list[str]] | None = None

    def complete() -> None:
        nonlocal pending
        assert pending is not None
        shown.append("".join(c if c else " ... " for c in pending[1]))
        pending = None

    tx, rx = Codec(2, 191), Codec(255, 190)
    for msg in rx.feed(b"".join(tx.encode(m) for m in msgs)):
        text = msg.text if isinstance(msg.text, str) else msg.text.decode()
        if pending is not None and pending[0] != msg.id:
            pending[1].append("")
            complete()
        if msg.id == 0:
            pending = (0, [text])
        elif pending is None:
            pending = (msg.id, [text])
        else:
            chunks = pending[1]
            chunks += [""] * (msg.chunk_seq - len(chunks))
            chunks.append(text)
        if msg.id == 0 or len(text) < statustext.TEXT_BYTES:
            complete()
    return [re.sub(" +", " ", s) for s in shown]  # HTML shows runs of spaces as one


def test_announcement_names_robot_what_urgency_where_in_one_chunk() -> None:
    text = statustext.victim_text(report())
    assert text == "R2 CRITICAL victim 7, 12.3 m N 4.5 m E of start"
    (msg,) = statustext.statustext_msgs(text, statustext.victim_severity(report(), True))
    assert msg.id == 0 and msg.severity == statustext.MAV_SEVERITY_CRITICAL
    south_west = statustext.victim_text(report(north_m=-3.0, east_m=-0.04))
    assert south_west == "R2 CRITICAL victim 7, 3.0 m S 0.0 m W of start"
    rescued = statustext.victim_text(report(state=TrackState.RESCUED))
    assert rescued.startswith("R2 victim 7 RESCUED, ")


def test_spoken_only_for_news() -> None:
    spoken = statustext.victim_severity
    assert spoken(report(), True) == 2
    assert spoken(report(urgency=Urgency.MEDIUM), True) == 5  # NOTICE: QGC speaks it
    assert spoken(report(urgency=Urgency.LIGHT), True) == 5
    assert spoken(report(urgency=Urgency.LIGHT), True, announce_severity=6) == 6  # silenced
    assert spoken(report(), True, announce_severity=6) == 2  # CRITICAL is always spoken
    assert spoken(report(urgency=Urgency.MEDIUM), False) == 6  # INFO: listed, silent
    assert spoken(report(state=TrackState.FALSE_ALARM), True) == 6


@pytest.mark.parametrize("length", [50, 100, 150])
def test_text_filling_whole_chunks_has_no_empty_trailing_chunk(length: int) -> None:
    words = ("victim " * 40)[: length - 1] + "X"
    assert len(words) == length
    msgs = statustext.statustext_msgs(words, 5, statustext.ChunkIds())
    assert all(len(m.text) > 0 for m in msgs)
    assert len(msgs[-1].text) < 50 or (length == 50 and msgs[0].id == 0)
    assert qgc_reassemble(msgs) == [re.sub(" +", " ", words)]
    assert " ... " not in qgc_reassemble(msgs)[0]


def test_long_texts_split_between_words_and_reassemble_in_qgc() -> None:
    rng = random.Random(17)
    vocabulary = ["R2", "CRITICAL", "victim", "12.3", "m", "N", "of", "start,", "camera", "x" * 12]
    ids = statustext.ChunkIds()
    for _ in range(300):
        text = " ".join(rng.choice(vocabulary) for _ in range(rng.randint(1, 60)))
        msgs = statustext.statustext_msgs(text, 4, ids)
        assert qgc_reassemble(msgs) == [text]
        if len(msgs) > 1:
            assert len({m.id for m in msgs}) == 1 and msgs[0].id != 0
            assert [m.chunk_seq for m in msgs] == list(range(len(msgs)))
            assert all(len(m.text) == 50 for m in msgs[:-1]) and 0 < len(msgs[-1].text) < 50
            for m in msgs[:-1]:  # each chunk ends between words
                assert m.text.endswith(" ")
        else:
            assert msgs[0].id == 0


def test_a_word_longer_than_a_chunk_is_cut_and_nothing_is_lost() -> None:
    for length in (50, 51, 99, 100, 101):
        msgs = statustext.statustext_msgs("Z" * length, 4, statustext.ChunkIds())
        (shown,) = qgc_reassemble(msgs)
        assert shown.replace(" ", "") == "Z" * length
        assert " ... " not in shown


def test_a_victim_seen_warm_only_says_so_in_one_chunk() -> None:
    from fusion.types import Cue

    text = statustext.victim_text(report(cues=Cue.WARM))
    assert text == "R2 CRITICAL victim 7, warm only, 12.3 m N 4.5 m E"
    far = statustext.victim_text(report(cues=Cue.WARM, north_m=-123.4, east_m=-45.6))
    assert far == "R2 CRITICAL victim 7, warm only, 123.4m S 45.6m W"
    for t in (text, far):
        assert len(t) <= statustext.TEXT_BYTES
        (msg,) = statustext.statustext_msgs(t, statustext.MAV_SEVERITY_CRITICAL)
        assert msg.id == 0  # one unchunked STATUSTEXT
    # When nothing fits (an ID of a later epoch), all of it is said, in two chunks.
    big = statustext.victim_text(report(cues=Cue.WARM, victim_id=16777217))
    assert big == "R2 CRITICAL victim 16777217, warm only, 12.3 m N 4.5 m E"
    msgs = statustext.statustext_msgs(big, statustext.MAV_SEVERITY_CRITICAL)
    assert qgc_reassemble(msgs) == [big]
    # Seen by the colour camera too (or not known): the usual line.
    both = statustext.victim_text(report(cues=Cue.WARM | Cue.COLOUR_PART))
    assert both == "R2 CRITICAL victim 7, 12.3 m N 4.5 m E of start"
    assert statustext.victim_text(report()) == both
