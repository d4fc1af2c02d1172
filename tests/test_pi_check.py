"""make pi-check's comparer (tools/pi_check.py): what it lets through and what it fails on.

No emulation here: the comparer is given detect and replay outputs written as the
commands write them, and one real person model's multiply-accumulates are counted."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest

from tools import pi_check
from tools.pi_check import Found, Victim, compare_detect, compare_dirs, compare_replay


def _found(box: tuple[float, float, float, float], urgency: str = "LIGHT") -> Found:
    return Found(box, urgency, 0.9, 80.0, frozenset({"person"}))


def _victim(vid: int, north_m: float, east_m: float, urgency: str = "MEDIUM") -> Victim:
    return Victim(vid, "CONFIRMED", urgency, north_m, east_m, 30.0)


def _replay(*victims: Victim, frames: int = 100) -> pi_check.Replay:
    return pi_check.Replay({"frames": frames, "poses": 797}, victims)


def test_boxes_a_few_pixels_apart_agree_and_further_apart_differ() -> None:
    host = {"a.jpg": [_found((10, 20, 100, 200)), _found((300, 20, 50, 80))]}
    near = {"a.jpg": [_found((302, 21, 49, 80)), _found((13, 20, 100, 201))]}
    result = compare_detect(host, near, box_px=4)
    assert result.ok, result.differences
    assert result.figures["largest box corner difference, px"] == 3.0

    far = {"a.jpg": [_found((10, 20, 100, 200)), _found((300, 20, 56, 80))]}
    result = compare_detect(host, far, box_px=4)
    assert len(result.differences) == 1
    assert result.differences == [
        "detect a.jpg: box [300, 20, 50, 80] on the host, [300, 20, 56, 80] on aarch64"
    ]


def test_another_number_of_people_another_urgency_or_picture_differ() -> None:
    host = {"a.jpg": [_found((10, 20, 100, 200))], "b.jpg": []}
    pi = {
        "a.jpg": [_found((10, 20, 100, 200), "MEDIUM"), _found((400, 0, 10, 10))],
        "c.jpg": [],
    }
    diffs = compare_detect(host, pi).differences
    assert "detect a.jpg: 1 people on the host, 2 on aarch64" in diffs
    assert "detect a.jpg: LIGHT on the host, MEDIUM on aarch64" in diffs
    assert "detect b.jpg: on the host only" in diffs
    assert "detect c.jpg: on aarch64 only" in diffs


def test_other_cues_are_a_note_not_a_failure() -> None:
    host = {"a.jpg": [_found((10, 20, 100, 200))]}
    pi = {"a.jpg": [Found((10, 20, 100, 200), "LIGHT", 0.8, 78.0, frozenset({"person", "hand"}))]}
    result = compare_detect(host, pi)
    assert result.ok
    assert result.notes == [
        "detect a.jpg: cues ['person'] on the host, ['hand', 'person'] on aarch64"
    ]
    assert result.figures["largest score difference"] == pytest.approx(0.1)


def test_victims_matched_by_place_not_by_number() -> None:
    host = _replay(_victim(1, 3.0, 1.3), _victim(2, 8.87, 3.65, "CRITICAL"))
    pi = _replay(_victim(1, 8.86, 3.66, "CRITICAL"), _victim(2, 3.02, 1.3))
    result = compare_replay(host, pi, position_m=0.05)
    assert result.ok, result.differences
    assert len(result.notes) == 2  # numbered the other way round
    assert result.figures["largest victim position difference, m"] == pytest.approx(0.02)


def test_a_victim_moved_missing_or_of_another_urgency_differs() -> None:
    host = _replay(_victim(1, 3.0, 1.3), _victim(2, 8.87, 3.65, "CRITICAL"))
    moved = _replay(_victim(1, 3.0, 1.4), _victim(2, 8.87, 3.65, "MEDIUM"))
    diffs = compare_replay(host, moved, position_m=0.05).differences
    assert sorted(diffs) == [
        "replay victim #1 (aarch64 #1): at N 3.000 E 1.300 m on the host, "
        "N 3.000 E 1.400 m on aarch64 (0.100 m apart)",
        "replay victim #2 (aarch64 #2): CONFIRMED CRITICAL on the host, "
        "CONFIRMED MEDIUM on aarch64",
    ]

    missing = _replay(_victim(1, 3.0, 1.3), frames=99)
    diffs = compare_replay(host, missing).differences
    assert "replay frames: 100 on the host, 99 on aarch64" in diffs
    assert "replay: 2 victims on the host, 1 on aarch64" in diffs


def _write_side(root: Path, boxes: list[list[int]], north_m: float) -> Path:
    (root / "replay").mkdir(parents=True)
    rows = [
        {"image": f"/somewhere/frames/{i}.jpg", "ms": 5.0, "detections": [_row(box)]}
        for i, box in enumerate(boxes)
    ]
    (root / "detect.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    victim = {
        "victim_id": 1,
        "state": "CONFIRMED",
        "urgency": "LIGHT",
        "visibility_pct": 90.0,
        "north_m": north_m,
        "east_m": 1.0,
    }
    (root / "replay" / "victims.json").write_text(
        json.dumps({"frames": 10, "poses": 50, "victims": [victim]})
    )
    return root


def _row(box: list[int]) -> dict[str, object]:
    return {
        "box": box,
        "score": 0.9,
        "cues": ["person"],
        "visibility_pct": 80.0,
        "urgency": "LIGHT",
    }


def test_the_command_compares_two_folders_and_says_why_it_fails(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    host = _write_side(tmp_path / "host", [[1, 2, 30, 40], [5, 5, 10, 10]], 2.0)
    same = _write_side(tmp_path / "same", [[2, 2, 30, 40], [5, 5, 10, 10]], 2.01)
    assert pi_check.main(["compare", str(host), str(same)]) == 0
    assert json.loads((same / "comparison.json").read_text())["ok"] is True

    other = _write_side(tmp_path / "other", [[1, 2, 30, 40], [5, 5, 10, 10]], 2.5)
    assert pi_check.main(["compare", str(host), str(other)]) == 1
    out = capsys.readouterr().out
    assert "DIFFERS: replay victim #1 (aarch64 #1): at N 2.000 E 1.000 m on the host" in out
    assert "1 differences beyond the tolerances" in out
    assert compare_dirs(host, other, position_m=1.0).ok


def test_unreadable_inputs_are_named_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    host = _write_side(tmp_path / "host", [[1, 2, 30, 40]], 2.0)
    bad = _write_side(tmp_path / "bad", [[1, 2, 30, 40]], 2.0)
    (bad / "detect.jsonl").write_text('{"image": "a.jpg", "detections": [{"box": [1, 2]}]}\n')
    assert pi_check.main(["compare", str(host), str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pi-check: {bad / 'detect.jsonl'}:1: not a detect --json line")
    assert len(err.strip().splitlines()) == 1

    (bad / "detect.jsonl").unlink()
    assert pi_check.main(["compare", str(host), str(bad)]) == 2
    assert "detect.jsonl: cannot be read" in capsys.readouterr().err


def test_ops_per_frame_weighs_each_model_by_its_runs(tmp_path: Path) -> None:
    macs = {"a.tflite": 100_000_000, "b.tflite": 30_000_000}
    report = pi_check.ops_report(
        tmp_path, Counter({"a.tflite": 20, "b.tflite": 5}), 10, lambda p: macs[p.name]
    )
    assert report["mmac_per_frame"] == 215.0  # 2 x 100 + 0.5 x 30
    assert report["models"] == {
        "a.tflite": {"mmac_per_run": 100.0, "runs_per_frame": 2.0},
        "b.tflite": {"mmac_per_run": 30.0, "runs_per_frame": 0.5},
    }


def test_a_real_models_multiply_accumulates_from_its_layer_shapes() -> None:
    from companion.vision.models import default_model_dir

    path = default_model_dir() / "face_detection_full_range.tflite"
    if not path.exists():
        pytest.skip(f"no model at {path} (rescue-companion models fetch)")
    # The 192x192 BlazeFace full-range: 49 convolutions and 40 depthwise ones, about
    # 0.1 G multiply-accumulates (its first convolution alone, 3x3x3 -> 32 channels
    # at 96x96, is 2.65 M).
    assert 80e6 < pi_check.model_macs(path) < 130e6
