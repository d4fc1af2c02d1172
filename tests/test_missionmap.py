"""The mission map's labels: readable where victims and true victims crowd together."""

from __future__ import annotations

from companion.missionmap import place_labels


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> int:
    return max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))


def test_crowded_labels_overlap_no_marker_and_no_other_label_and_stay_inside() -> None:
    # A reported victim beside its true one, pairs near the map's right edge (as the
    # demo's map had them: "T1 LIGHT" was hidden under V2's marker).
    markers = [(165, 645), (175, 650), (320, 335), (335, 330), (178, 105), (170, 146)]
    texts = [
        "T1 LIGHT",
        "V2 LIGHT 100%",
        "T2 MEDIUM",
        "V3 LIGHT 81%",
        "T3 CRITICAL",
        "V1 MEDIUM 16%",
    ]
    area = (0, 0, 370, 900)
    placed = place_labels(list(zip(texts, markers, strict=True)), markers, area)
    assert [p[0] for p in placed] == texts
    boxes = [box for _text, _origin, box in placed]
    for i, box in enumerate(boxes):
        assert area[0] <= box[0] < box[2] <= area[2] and area[1] <= box[1] < box[3] <= area[3]
        for x, y in markers:
            assert _overlap(box, (x - 9, y - 9, x + 9, y + 9)) == 0, (texts[i], (x, y))
        for j in range(i):
            assert _overlap(box, boxes[j]) == 0, (texts[i], texts[j])
